"""A2C's update of a rollout: one gradient step on the whole rollout through TorchRL's ``A2CLoss``.

As Stable-Baselines3's ``A2C.train``: the policy-gradient term ``-mean(A · log π(a|s))``, the
critic's squared error weighted by ``vf_coef`` and the entropy bonus weighted by ``ent_coef``,
summed, one optimiser step with the gradient's norm clipped to ``max_grad_norm``; the advantages
standardised over the rollout only with ``normalize_advantage`` (SB3's default: not). The SDE
policy enters as for PPO: ``A2CLoss`` rebuilds its distribution from the stored observation and
scores the stored action (eq. 20).
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase
from torchrl.objectives import A2CLoss

from sde_torchrl.objectives.actor_critic import ROLLOUT_KEYS
from sde_torchrl.trainers.objective import clipped_step, loss_objective


class A2CUpdate:
    """One A2C update of a rollout (with ``advantage`` and ``value_target`` written).

    Args:
        loss: the A2C loss (:func:`~sde_torchrl.objectives.actor_critic.make_a2c_loss`).
        optimizer: over ``loss.parameters()``.
        max_grad_norm: bound on the gradient's norm (``None``: not clipped).
        normalize_advantage: standardise the advantages over the rollout first.
        compile: compile the loss's forward and backward (:func:`~sde_torchrl.trainers.objective.loss_objective`).

    Returns (when called with the rollout and the update's index):
        The gradient norm before clipping.

    Examples:
        See :func:`sde_torchrl.config.build_onpolicy.build_onpolicy_trainer`.
    """

    #: What the update reads of a rollout.
    in_keys = ROLLOUT_KEYS

    def __init__(self, loss: A2CLoss, optimizer: torch.optim.Optimizer, *, max_grad_norm: float | None,
                 normalize_advantage: bool = False, compile: bool = False) -> None:
        self.loss, self.optimizer, self.normalize_advantage = loss, optimizer, normalize_advantage
        self.objective = loss_objective(loss, compile=compile)
        self.max_grad_norm = math.inf if max_grad_norm is None else max_grad_norm
        self.parameters = [p for group in optimizer.param_groups for p in group["params"]]

    def __call__(self, batch: TensorDictBase, update: int) -> float:
        flat = batch.reshape(-1).select(*ROLLOUT_KEYS, strict=False)
        if self.normalize_advantage:
            advantage = flat.get("advantage")
            flat.set("advantage", (advantage - advantage.mean()) / (advantage.std() + 1e-8))
        return float(clipped_step(self.objective(flat), self.optimizer, self.parameters, self.max_grad_norm))


__all__ = ["A2CUpdate"]
