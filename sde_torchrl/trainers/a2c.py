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
from torch import nn
from torchrl.objectives import A2CLoss

from sde_torchrl.trainers.objective import loss_objective

#: What ``A2CLoss`` reads of the rollout (not the SDE noise ``ξ``: the likelihood does not read it).
ROLLOUT_KEYS = ("observation", "action", "action_sample", "advantage", "value_target")


def make_a2c_loss(policy: nn.Module, critic: nn.Module, *, ent_coef: float, vf_coef: float) -> A2CLoss:
    """TorchRL's ``A2CLoss`` with SB3's A2C terms: squared-error critic loss weighted by
    ``vf_coef``, entropy bonus weighted by ``ent_coef`` (none at 0). The loss calls ``policy``
    and ``critic`` themselves (``functional=False``), as :func:`~sde_torchrl.trainers.ppo.make_ppo_loss`.

    Examples:
        >>> from torchrl.modules import MLP, ValueOperator
        >>> from sde_torchrl import MLPActor
        >>> from sde_torchrl.modules.gaussian import make_gaussian_actor
        >>> policy = make_gaussian_actor(MLPActor(3, 1, [8], activation="tanh"), 1)
        >>> critic = ValueOperator(MLP(in_features=3, out_features=1, num_cells=[8]), in_keys=["observation"])
        >>> type(make_a2c_loss(policy, critic, ent_coef=0.0, vf_coef=0.4)).__name__
        'A2CLoss'
    """
    return A2CLoss(policy, critic, entropy_bonus=ent_coef > 0, entropy_coeff=ent_coef, critic_coeff=vf_coef,
                   loss_critic_type="l2", functional=False)


class A2CUpdate:
    """One A2C update of a rollout (with ``advantage`` and ``value_target`` written).

    Args:
        loss: the A2C loss (:func:`make_a2c_loss`).
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
        objective = self.objective(flat)
        self.optimizer.zero_grad()
        objective.backward()
        norm = torch.nn.utils.clip_grad_norm_(self.parameters, self.max_grad_norm)
        self.optimizer.step()
        return float(norm)


__all__ = ["A2CUpdate", "ROLLOUT_KEYS", "make_a2c_loss"]
