"""The ``optimizer`` group's schemas: the step rule on the policy gradient (SGD, which is eq. 1
without momentum; Adam; RMSprop) and the learning rate's schedule over updates.

Examples:
    >>> SGDOptimizerConf().momentum, AdamOptimizerConf().eps
    (0.0, 1e-08)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, List

from sde_torchrl.config.schemas.frozen import Frozen
from sde_torchrl.utils.checks import ArgumentError, finite, fraction, one_of
from sde_torchrl.utils.options import LR_SCHEDULES

# ``typing`` generics, not ``list[float]``: OmegaConf reads these annotations at runtime.
# ruff: noqa: UP006, UP035


@dataclass
class SGDOptimizerConf(Frozen, schema="optimizer/sgd"):
    """``optimizer=sgd|momentum``: ``torch.optim.SGD`` on the policy gradient, with ``α = lr``.
    Without momentum it is the paper's plain ascent ``θ ← θ + α g`` (eq. 1); with momentum ``β``
    torch's heavy ball ``v ← β v + g``, ``θ ← θ + α v`` (steps ``1 / (1 - β)`` times longer once
    the gradients agree).

    Attributes:
        momentum: ``β`` in ``[0, 1)``; 0 is eq. 1.
        nesterov: Nesterov's variant (needs ``momentum > 0``).
        lr_schedule: the rate over updates: ``constant``, ``linear`` or ``cosine`` decay
            (:func:`sde_torchrl.trainers.optim.lr_factor`).
        final_lr_fraction: the factor on ``lr`` that a decay heads for, in ``[0, 1]``.
        sigma_lr_factor: the exploration scale's parameters step at ``sigma_lr_factor × lr``
            (:func:`~sde_torchrl.trainers.optim.exploration_parameters`; episodic jobs only), ``> 0``.

    Examples:
        >>> SGDOptimizerConf(momentum=0.9).lr_schedule
        'constant'
    """

    _target_: str = "torch.optim.SGD"
    momentum: float = 0.0
    nesterov: bool = False
    lr_schedule: str = "constant"
    final_lr_fraction: float = 0.0
    sigma_lr_factor: float = 1.0

    def moments(self) -> int:
        """Numbers the optimiser keeps per parameter (the memory estimate's): the momentum's."""
        return int(bool(self.momentum))

    def __post_init__(self) -> None:
        fraction("optimizer.momentum", self.momentum, below_one=True)
        if self.nesterov and self.momentum == 0:
            raise ArgumentError("optimizer.nesterov", True, "false unless optimizer.momentum > 0")
        _check_schedule(self)


@dataclass
class AdamOptimizerConf(Frozen, schema="optimizer/adam"):
    """``optimizer=adam``: ``torch.optim.Adam`` on the policy gradient, with ``α = lr``: a step
    of about ``α`` per parameter whatever the gradient's scale (sums or means of rewards alike).

    Attributes:
        betas: the decay rates of the first and second moment estimates, each in ``[0, 1)``.
        eps: added to the root of the second moment, ``> 0``.
        lr_schedule: the rate over updates: ``constant``, ``linear`` or ``cosine`` decay.
        final_lr_fraction: the factor on ``lr`` that a decay heads for, in ``[0, 1]``.
        sigma_lr_factor: the exploration scale's parameters step at ``sigma_lr_factor × lr``
            (:func:`~sde_torchrl.trainers.optim.exploration_parameters`; episodic jobs only), ``> 0``.

    Examples:
        >>> AdamOptimizerConf().betas
        [0.9, 0.999]
    """

    _target_: str = "torch.optim.Adam"
    betas: List[float] = field(default_factory=lambda: [0.9, 0.999])
    eps: float = 1e-8
    lr_schedule: str = "constant"
    final_lr_fraction: float = 0.0
    sigma_lr_factor: float = 1.0

    def moments(self) -> int:
        """Numbers the optimiser keeps per parameter: its two moment estimates."""
        return 2

    def __post_init__(self) -> None:
        if len(self.betas) != 2:
            raise ArgumentError("optimizer.betas", list(self.betas), "two numbers in [0, 1)")
        for beta in self.betas:
            fraction("optimizer.betas", beta, below_one=True)
        finite("optimizer.eps", self.eps, minimum=0, strict=True)
        _check_schedule(self)


@dataclass
class RMSpropOptimizerConf(Frozen, schema="optimizer/rmsprop"):
    """``optimizer=rmsprop``: ``torch.optim.RMSprop`` with ``α = lr`` (torch's defaults; SB3's
    A2C takes it with ``eps=1e-5``).

    Attributes:
        alpha: the decay rate of the squared-gradient average, in ``[0, 1)``.
        eps: added to its root, ``> 0``.
        lr_schedule: the rate over updates: ``constant``, ``linear`` or ``cosine`` decay.
        final_lr_fraction: the factor on ``lr`` that a decay heads for, in ``[0, 1]``.
        sigma_lr_factor: the exploration scale's parameters step at ``sigma_lr_factor × lr``
            (:func:`~sde_torchrl.trainers.optim.exploration_parameters`; episodic jobs only), ``> 0``.

    Examples:
        >>> RMSpropOptimizerConf().alpha
        0.99
    """

    _target_: str = "torch.optim.RMSprop"
    alpha: float = 0.99
    eps: float = 1e-8
    lr_schedule: str = "constant"
    final_lr_fraction: float = 0.0
    sigma_lr_factor: float = 1.0

    def moments(self) -> int:
        """Numbers the optimiser keeps per parameter: its average of squares."""
        return 1

    def __post_init__(self) -> None:
        fraction("optimizer.alpha", self.alpha, below_one=True)
        finite("optimizer.eps", self.eps, minimum=0, strict=True)
        _check_schedule(self)


def _check_schedule(conf: Any) -> None:
    one_of("optimizer.lr_schedule", conf.lr_schedule, LR_SCHEDULES)
    fraction("optimizer.final_lr_fraction", conf.final_lr_fraction)
    finite("optimizer.sigma_lr_factor", conf.sigma_lr_factor, minimum=0, strict=True)

