"""PPO's and A2C's losses: TorchRL's ``ClipPPOLoss`` and ``A2CLoss`` with Stable-Baselines3's terms.

The SDE policy is one of TorchRL's probabilistic modules: each loss rebuilds its distribution from
the stored observation and scores the stored action (eq. 20), with no noise matrix needed. The
updates that step on them are :class:`~sde_torchrl.trainers.ppo.PPOUpdate` and
:class:`~sde_torchrl.trainers.a2c.A2CUpdate`.

Examples:
    >>> from torchrl.modules import MLP, ValueOperator
    >>> from sde_torchrl import MLPActor
    >>> from sde_torchrl.modules.gaussian import make_gaussian_actor
    >>> policy = make_gaussian_actor(MLPActor(3, 1, [8], activation="tanh"), 1)
    >>> critic = ValueOperator(MLP(in_features=3, out_features=1, num_cells=[8]), in_keys=["observation"])
    >>> type(make_ppo_loss(policy, critic, clip_range=0.2, ent_coef=0.0, vf_coef=0.5)).__name__
    'ClipPPOLoss'
    >>> type(make_a2c_loss(policy, critic, ent_coef=0.0, vf_coef=0.4)).__name__
    'A2CLoss'
"""

from __future__ import annotations

from torch import nn
from torchrl.objectives import A2CLoss, ClipPPOLoss

#: What ``ClipPPOLoss`` reads of a minibatch: not the SDE noise ``ξ``, which the likelihood
#: (eq. 20) does not read (an ``A × S`` matrix per step, gathered ``n_epochs`` times for nothing).
MINIBATCH_KEYS = ("observation", "action", "action_sample", "action_log_prob", "advantage", "value_target",
                  "state_value")


#: What ``A2CLoss`` reads of the rollout (not the SDE noise ``ξ``: the likelihood does not read it).
ROLLOUT_KEYS = ("observation", "action", "action_sample", "advantage", "value_target")



def make_ppo_loss(policy: nn.Module, critic: nn.Module, *, clip_range: float, ent_coef: float, vf_coef: float,
                  normalize_advantage: bool = True) -> ClipPPOLoss:
    """TorchRL's ``ClipPPOLoss`` with SB3's PPO terms: clipped surrogate, squared-error critic
    loss weighted by ``vf_coef``, entropy bonus weighted by ``ent_coef`` (none at 0), advantages
    standardised per minibatch. The loss calls ``policy`` and ``critic`` themselves
    (``functional=False``): the same numbers as TorchRL's default functional copies, without
    swapping their parameters in on every call.

    """
    return ClipPPOLoss(policy, critic, clip_epsilon=clip_range, entropy_bonus=ent_coef > 0, entropy_coeff=ent_coef,
                       critic_coeff=vf_coef, loss_critic_type="l2", normalize_advantage=normalize_advantage,
                       functional=False)


def make_a2c_loss(policy: nn.Module, critic: nn.Module, *, ent_coef: float, vf_coef: float) -> A2CLoss:
    """TorchRL's ``A2CLoss`` with SB3's A2C terms: squared-error critic loss weighted by
    ``vf_coef``, entropy bonus weighted by ``ent_coef`` (none at 0). The loss calls ``policy``
    and ``critic`` themselves (``functional=False``), as :func:`make_ppo_loss`.

    """
    return A2CLoss(policy, critic, entropy_bonus=ent_coef > 0, entropy_coeff=ent_coef, critic_coeff=vf_coef,
                   loss_critic_type="l2", functional=False)


__all__ = ["MINIBATCH_KEYS", "ROLLOUT_KEYS", "make_a2c_loss", "make_ppo_loss"]
