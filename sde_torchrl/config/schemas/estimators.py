"""The ``estimator`` group's schemas, one per estimator: REINFORCE, ENAC, GPOMDP and PGPE.

Each option has its own schema, which names its estimator (``_target_``), registers under its
option (``class MyEstimatorConf(EstimatorConf, schema="estimator/my")``, which also sets
``option``) and holds the options that estimator takes; a key it does not take is refused with
the estimator named (``estimator=enac estimator.symmetric=true``: ``estimator.symmetric: unknown
key (estimator=enac's options: ...)``). What the layers around an estimator need to know of it,
the schema declares as class attributes (:class:`EstimatorConf`'s traits): the memory estimate
and the rules across groups read those, never the estimator's name. The four share the options of
:class:`~sde_torchrl.objectives.base.GradientEstimator` and the authors' variance weighting
through :class:`EstimatorConf`; an option of one estimator alone goes into that estimator's schema.

Examples:
    >>> ENACEstimatorConf().option, ENACEstimatorConf()._target_.rsplit(".", 1)[-1]
    ('enac', 'ENACEstimator')
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Optional

from sde_torchrl.config.schemas.frozen import Frozen
from sde_torchrl.utils.checks import ArgumentError, is_finite_number, one_of
from sde_torchrl.utils.options import EPISODE_RETURNS

# ``typing`` generics, not ``X | None``: OmegaConf reads these annotations at runtime.
# ruff: noqa: UP007, UP045


@dataclass
class EstimatorConf(Frozen):
    """The options every estimator takes; each estimator's schema below adds its ``_target_``
    and registers as its option (this one is no group option).

    The traits (class attributes, not keys) are ``False`` unless a schema declares them.

    Attributes:
        option: the ``estimator`` group option whose schema this is, from its ``schema`` name.
        keeps_step_scores: the estimator keeps one score per step and parameter (GPOMDP); the
            memory estimate (:mod:`sde_torchrl.jobs.resources`) reads it, and the two below.
        carries_parameter_draws: each step carries its episode's drawn parameters and their
            noise (PGPE): the estimator scores the draws of an explorer that draws the actor's
            parameters (``explorer=pgpe``), and goes with no other.
        solves_in_float64: the estimator solves a regression on the scores in float64 (ENAC).
        regresses_on_scores: the estimator regresses the returns on the scores, which fewer
            episodes than unknowns leave rank-deficient (ENAC: a warning when built).
        baseline_from_batch: its baseline comes from the update's own episodes, so that one
            episode's gradient is exactly 0 (REINFORCE, GPOMDP: refused).
        takes_scores: the estimator takes the top-level ``scores`` (how episodes are scored);
            ``True`` by default.
        max_grad_norm: bound on each run's gradient norm; ``null``: plain ascent (eq. 1).
        max_grad_entry: the authors' rescale: a run's gradient whose largest (signed) entry
            exceeds this is scaled so that the entry equals it (1000 in their code); ``null``: off.
        episode_return: ``mean`` (the paper's text, section 2.1) or ``sum`` (the authors' code) of
            an episode's rewards; used by the estimator and every reported return.
        variance_weighted: the authors' "auto-alpha" scores: each action's log-likelihood
            weighted by its own variance ``σ_j²`` (held constant) before differentiating.

    Examples:
        >>> ReinforceEstimatorConf(max_grad_norm=100.0).max_grad_norm
        100.0
        >>> ReinforceEstimatorConf(episode_return="total")
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.ArgumentError: estimator.episode_return=total: one of sum, mean
    """

    option: ClassVar[str]
    keeps_step_scores: ClassVar[bool] = False
    carries_parameter_draws: ClassVar[bool] = False
    solves_in_float64: ClassVar[bool] = False
    regresses_on_scores: ClassVar[bool] = False
    baseline_from_batch: ClassVar[bool] = False
    takes_scores: ClassVar[bool] = True
    _target_: str
    max_grad_norm: Optional[float] = None
    max_grad_entry: Optional[float] = None
    episode_return: str = "mean"
    variance_weighted: bool = False

    def __init_subclass__(cls, schema: str | None = None, **kwargs: Any) -> None:
        super().__init_subclass__(schema=schema, **kwargs)
        if schema is not None:
            cls.option = schema.rsplit("/", 1)[-1]

    def __post_init__(self) -> None:
        for key in ("max_grad_norm", "max_grad_entry"):
            bound = getattr(self, key)
            if bound is not None and (not is_finite_number(bound) or bound <= 0):
                raise ArgumentError(f"estimator.{key}", bound, "a number > 0, or null (no bound)")
        one_of("estimator.episode_return", self.episode_return, EPISODE_RETURNS)


@dataclass
class ReinforceEstimatorConf(EstimatorConf, schema="estimator/reinforce"):
    """``estimator=reinforce``: episodic REINFORCE with the optimal per-parameter baseline
    (:class:`~sde_torchrl.objectives.estimators.ReinforceEstimator`); the options are
    :class:`EstimatorConf`'s.

    Examples:
        >>> ReinforceEstimatorConf().option
        'reinforce'
    """

    baseline_from_batch: ClassVar[bool] = True
    _target_: str = "sde_torchrl.objectives.estimators.ReinforceEstimator"


@dataclass
class ENACEstimatorConf(EstimatorConf, schema="estimator/enac"):
    """``estimator=enac``: the Episodic Natural Actor-Critic, least squares on ``[ψ, 1]``
    (:class:`~sde_torchrl.objectives.estimators.ENACEstimator`); the options are
    :class:`EstimatorConf`'s.

    Examples:
        >>> ENACEstimatorConf(variance_weighted=True).variance_weighted
        True
    """

    solves_in_float64: ClassVar[bool] = True
    regresses_on_scores: ClassVar[bool] = True
    _target_: str = "sde_torchrl.objectives.estimators.ENACEstimator"


@dataclass
class GPOMDPEstimatorConf(EstimatorConf, schema="estimator/gpomdp"):
    """``estimator=gpomdp``: GPOMDP, each reward credited to the actions before it, with the
    time-dependent optimal baseline (:class:`~sde_torchrl.objectives.estimators.GPOMDPEstimator`);
    the options are :class:`EstimatorConf`'s (``episode_return=mean`` divides each step's reward
    by the episode's length).

    Examples:
        >>> GPOMDPEstimatorConf(episode_return="sum").episode_return
        'sum'
    """

    keeps_step_scores: ClassVar[bool] = True
    baseline_from_batch: ClassVar[bool] = True
    _target_: str = "sde_torchrl.objectives.estimators.GPOMDPEstimator"


@dataclass
class PGPEEstimatorConf(EstimatorConf, schema="estimator/pgpe"):
    """``estimator=pgpe``: PGPE, the likelihood-ratio gradient of ``explorer=pgpe``'s parameter
    distribution with the batch's mean return as baseline
    (:class:`~sde_torchrl.objectives.pgpe.PGPEEstimator`); the options are :class:`EstimatorConf`'s,
    ``variance_weighted`` here being Sehnke et al.'s step sizes ``α_i = α σ_i²``.

    Examples:
        >>> PGPEEstimatorConf().option
        'pgpe'
    """

    carries_parameter_draws: ClassVar[bool] = True
    takes_scores: ClassVar[bool] = False
    _target_: str = "sde_torchrl.objectives.pgpe.PGPEEstimator"
