"""The ``estimator`` group's schemas, one per estimator: REINFORCE, ENAC, GPOMDP and PGPE.

Each option has its own schema, which names its estimator (``_target_``) and the group option it
is (``option``) and holds the options that estimator takes; a key it does not take is refused
with the estimator named (``estimator=enac estimator.symmetric=true``: ``estimator.symmetric:
unknown key (estimator=enac's options: ...)``), and the rules across groups
(:mod:`sde_torchrl.config.schemas.train`) tell the estimators apart by their schema. The four take
the same options, those of :class:`~sde_torchrl.objectives.base.GradientEstimator` and the
authors' variance weighting, which they share through :class:`EstimatorConf`; an option of one
estimator alone goes into that estimator's schema.

Examples:
    >>> ENACEstimatorConf().option, ENACEstimatorConf()._target_.rsplit(".", 1)[-1]
    ('enac', 'ENACEstimator')
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Optional

from sde_torchrl.config.schemas.frozen import Frozen
from sde_torchrl.utils.checks import ArgumentError, is_finite_number, one_of
from sde_torchrl.utils.options import EPISODE_RETURNS

# ``typing`` generics, not ``X | None``: OmegaConf reads these annotations at runtime.
# ruff: noqa: UP007, UP045


@dataclass
class EstimatorConf(Frozen):
    """The options every estimator takes; each estimator's schema below adds its ``_target_``
    and ``option`` (this one is no group option).

    Attributes:
        option: the ``estimator`` group option whose schema this is (a class attribute, not a key).
        keeps_step_scores: the estimator keeps one score per step and parameter (GPOMDP); a
            class attribute that the memory estimate (:mod:`sde_torchrl.jobs.resources`) reads,
            as the two below.
        carries_parameter_draws: each step carries its episode's drawn parameters and their
            noise (PGPE).
        solves_in_float64: the estimator solves a regression on the scores in float64 (ENAC).
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
    _target_: str
    max_grad_norm: Optional[float] = None
    max_grad_entry: Optional[float] = None
    episode_return: str = "mean"
    variance_weighted: bool = False

    def __post_init__(self) -> None:
        for key in ("max_grad_norm", "max_grad_entry"):
            bound = getattr(self, key)
            if bound is not None and (not is_finite_number(bound) or bound <= 0):
                raise ArgumentError(f"estimator.{key}", bound, "a number > 0, or null (no bound)")
        one_of("estimator.episode_return", self.episode_return, EPISODE_RETURNS)


@dataclass
class ReinforceEstimatorConf(EstimatorConf):
    """``estimator=reinforce``: episodic REINFORCE with the optimal per-parameter baseline
    (:class:`~sde_torchrl.objectives.estimators.ReinforceEstimator`); the options are
    :class:`EstimatorConf`'s.

    Examples:
        >>> ReinforceEstimatorConf().option
        'reinforce'
    """

    option: ClassVar[str] = "reinforce"
    _target_: str = "sde_torchrl.objectives.estimators.ReinforceEstimator"


@dataclass
class ENACEstimatorConf(EstimatorConf):
    """``estimator=enac``: the Episodic Natural Actor-Critic, least squares on ``[ψ, 1]``
    (:class:`~sde_torchrl.objectives.estimators.ENACEstimator`); the options are
    :class:`EstimatorConf`'s.

    Examples:
        >>> ENACEstimatorConf(variance_weighted=True).variance_weighted
        True
    """

    option: ClassVar[str] = "enac"
    solves_in_float64: ClassVar[bool] = True
    _target_: str = "sde_torchrl.objectives.estimators.ENACEstimator"


@dataclass
class GPOMDPEstimatorConf(EstimatorConf):
    """``estimator=gpomdp``: GPOMDP, each reward credited to the actions before it, with the
    time-dependent optimal baseline (:class:`~sde_torchrl.objectives.estimators.GPOMDPEstimator`);
    the options are :class:`EstimatorConf`'s (``episode_return=mean`` divides each step's reward
    by the episode's length).

    Examples:
        >>> GPOMDPEstimatorConf(episode_return="sum").episode_return
        'sum'
    """

    option: ClassVar[str] = "gpomdp"
    keeps_step_scores: ClassVar[bool] = True
    _target_: str = "sde_torchrl.objectives.estimators.GPOMDPEstimator"


@dataclass
class PGPEEstimatorConf(EstimatorConf):
    """``estimator=pgpe``: PGPE, the likelihood-ratio gradient of ``explorer=pgpe``'s parameter
    distribution with the batch's mean return as baseline
    (:class:`~sde_torchrl.objectives.pgpe.PGPEEstimator`); the options are :class:`EstimatorConf`'s,
    ``variance_weighted`` here being Sehnke et al.'s step sizes ``α_i = α σ_i²``.

    Examples:
        >>> PGPEEstimatorConf().option
        'pgpe'
    """

    option: ClassVar[str] = "pgpe"
    carries_parameter_draws: ClassVar[bool] = True
    _target_: str = "sde_torchrl.objectives.pgpe.PGPEEstimator"
