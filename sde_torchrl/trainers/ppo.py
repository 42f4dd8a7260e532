"""PPO's update of a rollout: epochs of shuffled minibatches through TorchRL's ``ClipPPOLoss``.

As Stable-Baselines3's ``PPO.train``: ``n_epochs`` passes over the rollout, each in a fresh random
order cut into minibatches of ``batch_size`` (the last one shorter if the rollout does not
divide), one optimiser step per minibatch on the clipped surrogate, the critic's loss and the
entropy bonus, the gradient's norm clipped to ``max_grad_norm``; with a ``linear`` clip-range
schedule, ``ε`` of update ``k`` of ``K`` is ``clip_range · (1 − k / K)`` (SB3's ``lin_`` schedules
decay with the progress; a pure function of ``k``, nothing to checkpoint). The SDE policy is one of
TorchRL's probabilistic modules: ``ClipPPOLoss`` rebuilds its distribution from the stored
observation and scores the stored action (eq. 20), with no noise matrix needed.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase
from torchrl.objectives import ClipPPOLoss

from sde_torchrl.objectives.actor_critic import MINIBATCH_KEYS
from sde_torchrl.trainers.objective import clipped_step, loss_objective
from sde_torchrl.trainers.optim import lr_factor
from sde_torchrl.utils.checks import positive_int


class PPOUpdate:
    """One PPO update of a rollout (with ``advantage`` and ``value_target`` written).

    Args:
        loss: the PPO loss (:func:`~sde_torchrl.objectives.actor_critic.make_ppo_loss`).
        optimizer: over ``loss.parameters()``.
        n_epochs: passes over the rollout.
        batch_size: steps per minibatch.
        max_grad_norm: bound on the gradient's norm (``None``: not clipped).
        clip_range_schedule: ``"constant"`` or ``"linear"`` (to 0 over ``updates``).
        updates: the job's number of updates (for a ``linear`` schedule).
        compile: compile the loss's forward and backward (:func:`~sde_torchrl.trainers.objective.loss_objective`).

    Returns (when called with the rollout and the update's index):
        The mean gradient norm before clipping over the update's optimiser steps.

    Examples:
        See :func:`sde_torchrl.config.build_onpolicy.build_onpolicy_trainer`.
    """

    #: What the update reads of a rollout.
    in_keys = MINIBATCH_KEYS

    def __init__(self, loss: ClipPPOLoss, optimizer: torch.optim.Optimizer, *, n_epochs: int, batch_size: int,
                 max_grad_norm: float | None, clip_range_schedule: str = "constant", updates: int = 1,
                 compile: bool = False) -> None:
        self.loss, self.optimizer = loss, optimizer
        self.objective = loss_objective(loss, compile=compile)
        self.clip_range, self.clip_range_schedule, self.updates = float(loss.clip_epsilon), clip_range_schedule, updates
        self.n_epochs, self.batch_size = positive_int("n_epochs", n_epochs), positive_int("batch_size", batch_size)
        self.max_grad_norm = math.inf if max_grad_norm is None else max_grad_norm
        self.parameters = [p for group in optimizer.param_groups for p in group["params"]]

    def __call__(self, batch: TensorDictBase, update: int) -> float:
        if self.clip_range_schedule != "constant":
            factor = lr_factor(self.clip_range_schedule, update, self.updates, 0.0)
            self.loss.clip_epsilon.fill_(self.clip_range * factor)
        flat = batch.reshape(-1).select(*MINIBATCH_KEYS, strict=False).contiguous()
        norms = []
        for _ in range(self.n_epochs):
            for idx in torch.randperm(flat.numel()).split(self.batch_size):
                norms.append(clipped_step(self.objective(flat[idx]), self.optimizer, self.parameters,
                                          self.max_grad_norm))
        return float(torch.stack(norms).mean())


__all__ = ["PPOUpdate"]
