"""The ``estimator`` group's schema: one for the four episodic estimators, each option's YAML file
naming its estimator (``_target_``).

Examples:
    >>> EstimatorConf().episode_return
    'mean'
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from sde_torchrl.utils.checks import ArgumentError, is_finite_number, one_of
from sde_torchrl.utils.options import EPISODE_RETURNS

# ``typing`` generics, not ``X | None``: OmegaConf reads these annotations at runtime.
# ruff: noqa: UP007, UP045


@dataclass
class EstimatorConf:
    """``estimator=reinforce|enac|gpomdp|pgpe``: episodic REINFORCE with the optimal per-parameter
    baseline, the Episodic Natural Actor-Critic (least squares on ``[ψ, 1]``), GPOMDP (each
    reward credited to the actions before it, with the time-dependent optimal baseline), or PGPE
    (the likelihood-ratio gradient of ``explorer=pgpe``'s parameter distribution, with the batch's
    mean return as baseline; :class:`~sde_torchrl.objectives.pgpe.PGPEEstimator`).

    Attributes:
        max_grad_norm: bound on each run's gradient norm; ``null``: plain ascent (eq. 1).
        max_grad_entry: the authors' rescale: a run's gradient whose largest (signed) entry
            exceeds this is scaled so that the entry equals it (1000 in their code); ``null``: off.
        episode_return: ``mean`` (the paper's text, section 2.1) or ``sum`` (the authors' code) of
            an episode's rewards; used by the estimator and every reported return.
        variance_weighted: the authors' "auto-alpha" scores: each action's log-likelihood
            weighted by its own variance ``σ_j²`` (held constant) before differentiating; for
            PGPE, Sehnke et al.'s step sizes ``α_i = α σ_i²``.

    Examples:
        >>> EstimatorConf(max_grad_norm=100.0).max_grad_norm
        100.0
    """

    _target_: str = "sde_torchrl.objectives.estimators.ReinforceEstimator"
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
