"""The step rule of a training job: plain ascent (eq. 1), momentum or Adam, and the learning rate
over updates.

The estimators write ``loss_objective`` so that its gradient is minus the policy gradient ``g``
of each run; any ``torch.optim`` optimiser then ascends. ``SGD(lr=α)`` without momentum is the
paper's ``θ ← θ + α g`` (eq. 1). Momentum and a decreasing learning rate are the remedies the
paper names for runs that find a good policy and leave it again (section 5). Each of these
optimisers acts element by element, so runs stacked along the parameters' leading dimension
stay independent: run ``r`` of a batched job steps exactly as a job of that run alone.

The learning rate of update ``k`` is a pure function of ``k`` (:func:`lr_factor`), set before
each step (:class:`LearningRateSchedule`): a resumed job steps with the rates an uninterrupted
one does without any scheduler state to checkpoint.

The exploration scale's parameters (SDE's ``p`` with ``σ̂ = expln(p)``, eq. 23; PGPE's ``σ``) may
step at a rate of their own, ``sigma_lr_factor × α`` (:func:`exploration_parameters`): with Adam
every parameter travels at most ``Σ_k α_k`` over a job, which bounds how far ``σ̂`` can shrink.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

from sde_torchrl.utils.checks import ArgumentError, fraction, one_of, positive_int
from sde_torchrl.utils.options import LR_SCHEDULES

if TYPE_CHECKING:  # torch is imported when an optimiser is made: the config schemas read this module
    import torch

#: Config keys of the ``optimizer`` group that describe the rates, not the optimiser.
SCHEDULE_KEYS = ("lr_schedule", "final_lr_fraction", "sigma_lr_factor")
#: ``_target_`` values the ``optimizer`` group may name.
OPTIMIZER_TARGETS = ("torch.optim.SGD", "torch.optim.Adam", "torch.optim.RMSprop")
#: The optimisers with a fused CPU kernel (``fused=True``): the same update rule in one pass.
FUSED_TARGETS = ("torch.optim.SGD", "torch.optim.Adam")


def lr_factor(schedule: str, update: int, updates: int, final_fraction: float) -> float:
    """The factor on the base learning rate at update ``update`` (0-based) of ``updates``.

    ``constant``: 1. ``linear``: from 1 down to ``final_fraction``, reached one update after the
    last (so the last step is not wasted at ``final_fraction=0``). ``cosine``: half a cosine from 1
    down to ``final_fraction``, on the same grid.

    Args:
        schedule: one of :data:`LR_SCHEDULES`.
        update: the update about to be taken, ``0 <= update < updates``.
        updates: the job's number of updates.
        final_fraction: the factor the decay heads for, in ``[0, 1]``.

    Returns:
        The factor.

    Examples:
        >>> [lr_factor("linear", k, 4, 0.0) for k in range(4)]
        [1.0, 0.75, 0.5, 0.25]
        >>> round(lr_factor("cosine", 2, 4, 0.2), 6)
        0.6
        >>> lr_factor("constant", 3, 4, 0.0)
        1.0
    """
    progress = update / updates
    if schedule == "linear":
        return 1.0 - (1.0 - final_fraction) * progress
    if schedule == "cosine":
        return final_fraction + (1.0 - final_fraction) * 0.5 * (1.0 + math.cos(math.pi * progress))
    return 1.0


def exploration_parameters(policy: torch.nn.Module) -> list[torch.nn.Parameter]:
    """The learnable parameters of the exploration scale: those held directly by every submodule
    that reports an exploration scale (``exploration_scale()``: SDE's ``p`` and the Gaussian part's
    parameter, the Gaussian baseline's ``log σ``, PGPE's ``σ``), none of the actor's.

    Args:
        policy: the policy module (actor and explorer).

    Returns:
        The parameters, in module order (empty where the scale is fixed).

    Examples:
        >>> import torch
        >>> from sde_torchrl.modules.gaussian import GaussianScale
        >>> policy = torch.nn.Sequential(torch.nn.Linear(3, 2), GaussianScale(2))
        >>> [tuple(p.shape) for p in exploration_parameters(policy)]
        [(2,)]
        >>> exploration_parameters(torch.nn.Sequential(torch.nn.Linear(3, 2), GaussianScale(2, learn_sigma=False)))
        []
    """
    return [parameter for module in policy.modules() if callable(getattr(module, "exploration_scale", None))
            for parameter in module.parameters(recurse=False) if parameter.requires_grad]


class LearningRateSchedule:
    """Sets every parameter group's learning rate for update ``k``: its base rate times
    :func:`lr_factor`.

    Args:
        optimizer: the job's optimiser; its groups' current rates are the base rates.
        schedule: one of :data:`LR_SCHEDULES`.
        updates: the job's number of updates.
        final_fraction: the factor at the end of the decay, in ``[0, 1]``.

    Raises:
        ArgumentError: for a schedule, update count or fraction that is not allowed.

    Examples:
        >>> import torch
        >>> theta = torch.nn.Parameter(torch.zeros(2))
        >>> optimizer = torch.optim.SGD([theta], lr=0.1)
        >>> schedule = LearningRateSchedule(optimizer, "linear", updates=10, final_fraction=0.0)
        >>> schedule.apply(5)
        >>> optimizer.param_groups[0]["lr"]
        0.05
    """

    def __init__(self, optimizer: torch.optim.Optimizer, schedule: str, updates: int,
                 final_fraction: float = 0.0) -> None:
        self.schedule = one_of("lr_schedule", schedule, LR_SCHEDULES)
        self.updates = positive_int("updates", updates)
        self.final_fraction = fraction("final_lr_fraction", final_fraction)
        self.optimizer = optimizer
        self.base_lrs = [group["lr"] for group in optimizer.param_groups]

    def apply(self, update: int) -> None:
        """Sets the rates for update ``update`` (0-based)."""
        factor = lr_factor(self.schedule, update, self.updates, self.final_fraction)
        for group, base in zip(self.optimizer.param_groups, self.base_lrs, strict=True):
            group["lr"] = base * factor


def make_optimizer(parameters: Iterable[torch.nn.Parameter], lr: float, options: Mapping[str, Any],
                   updates: int, *, fused: bool = False, scale_parameters: Iterable[torch.nn.Parameter] | None = None,
                   ) -> tuple[torch.optim.Optimizer, LearningRateSchedule | None]:
    """The optimiser and learning-rate schedule that an ``optimizer`` config group describes.

    Args:
        parameters: the policy's parameters (stacked over runs or not).
        lr: ``α``, the base learning rate.
        options: the group's entries: ``_target_`` (one of :data:`OPTIMIZER_TARGETS`), the
            optimiser's own keyword arguments, and :data:`SCHEDULE_KEYS`.
        updates: the job's number of updates (the schedule's length).
        fused: step with torch's fused kernel where the optimiser has one (:data:`FUSED_TARGETS`;
            others step as they are): the same rule in one pass over the parameters, with results
            that may differ from the default kernel's in the last bits.
        scale_parameters: those of ``parameters`` that set the exploration scale
            (:func:`exploration_parameters`): a parameter group of their own, with the rate
            ``sigma_lr_factor × lr`` (the schedule keeps the ratio). ``None``: the caller has no
            such split, and ``sigma_lr_factor`` must be 1.

    Returns:
        The optimiser, and the schedule (``None`` for a constant rate).

    Raises:
        ArgumentError: for an optimiser class or schedule that is not allowed, or a
            ``sigma_lr_factor`` other than 1 without ``scale_parameters``.

    Examples:
        >>> import torch
        >>> theta = torch.nn.Parameter(torch.zeros(2))
        >>> optimizer, schedule = make_optimizer([theta], 0.01, {"_target_": "torch.optim.Adam",
        ...     "betas": [0.9, 0.999], "lr_schedule": "cosine", "final_lr_fraction": 0.1}, updates=100)
        >>> type(optimizer).__name__, schedule.schedule
        ('Adam', 'cosine')
        >>> make_optimizer([theta], 0.01, {"_target_": "torch.optim.Adam"}, 100, fused=True)[0].defaults["fused"]
        True
        >>> sigma = torch.nn.Parameter(torch.zeros(2))
        >>> optimizer, _ = make_optimizer([theta, sigma], 0.01, {"sigma_lr_factor": 10}, 100, scale_parameters=[sigma])
        >>> [group["lr"] for group in optimizer.param_groups]
        [0.01, 0.1]
    """
    options = dict(options)
    target = options.pop("_target_", "torch.optim.SGD")
    module, name = one_of("optimizer._target_", target, OPTIMIZER_TARGETS).rsplit(".", 1)
    schedule = options.pop("lr_schedule", "constant")
    final_fraction = options.pop("final_lr_fraction", 0.0)
    groups = _parameter_groups(list(parameters), lr, options.pop("sigma_lr_factor", 1.0), scale_parameters)
    if "betas" in options:
        options["betas"] = tuple(options["betas"])
    if fused and target in FUSED_TARGETS:
        options["fused"] = True
    optimizer = getattr(importlib.import_module(module), name)(groups, lr=lr, **options)
    if one_of("optimizer.lr_schedule", schedule, LR_SCHEDULES) == "constant":
        return optimizer, None
    return optimizer, LearningRateSchedule(optimizer, schedule, updates, final_fraction)


def _parameter_groups(parameters: list[torch.nn.Parameter], lr: float, sigma_lr_factor: float,
                      scale_parameters: Iterable[torch.nn.Parameter] | None) -> list[dict[str, Any]]:
    """``parameters`` as optimiser groups: one, or the others and the exploration scale's at
    ``sigma_lr_factor × lr``."""
    if scale_parameters is None:
        if sigma_lr_factor != 1:
            raise ArgumentError("optimizer.sigma_lr_factor", sigma_lr_factor,
                                "1 for this job: a rate of its own for the exploration scale is an option of the "
                                "episodic estimators' jobs (no algorithm=ppo, a2c or sac)")
        return [{"params": parameters}]
    scale_ids = {id(p) for p in scale_parameters}
    scale = [p for p in parameters if id(p) in scale_ids]
    others = [p for p in parameters if id(p) not in scale_ids]
    if sigma_lr_factor == 1 or not scale:
        return [{"params": parameters}]
    return [{"params": others}, {"params": scale, "lr": lr * sigma_lr_factor}]
