"""SAC's loss: TorchRL's ``SACLoss`` with Stable-Baselines3's settings, and the fresh noise
matrix the SDE policy gets at every gradient step.

**Why fresh noise.** A replay buffer could hold the ``ξ`` each transition was collected with, but
the reparameterised SAC gradient needs ``a = μ(s) + (σ̂ ⊙ ξ) x(s)`` with ``ξ ~ N(0, I)``
independent of ``s``; the stored ``ξ`` steered the episode into ``s``, so it is not, and would
bias the actor's gradient and its entropy estimate. The buffer therefore holds no noise.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.objectives import SACLoss

from sde_torchrl.modules.sde import SDEParams

#: What the SAC losses read of a stored transition (no SDE noise: the module docstring says why).
TRANSITION_KEYS = ("observation", "action", ("next", "observation"), ("next", "reward"), ("next", "done"),
                   ("next", "terminated"))


def fresh_loss_noise(batch: TensorDictBase, sde: SDEParams) -> None:
    """Sets one fresh standard-normal ``[A, S]`` noise matrix on every row of a minibatch and of its
    next states, as SB3's ``actor.reset_noise()`` before each gradient step (its one
    ``exploration_mat`` serves the whole batch).

    Args:
        batch: the sampled transitions (``[B]``), modified in place.
        sde: the policy's :class:`~sde_torchrl.modules.sde.SDEParams`.

    Examples:
        >>> from tensordict import TensorDict
        >>> batch = TensorDict({"next": {}}, [4])
        >>> fresh_loss_noise(batch, SDEParams(2, 3))
        >>> batch["sde_noise"].shape, torch.equal(batch["sde_noise"][0], batch["next", "sde_noise"][3])
        (torch.Size([4, 2, 3]), True)
    """
    noise = torch.randn(sde.action_dim, sde.feature_dim).expand(*batch.shape, sde.action_dim, sde.feature_dim)
    batch.set(sde.noise_key, noise)
    batch.set(("next", sde.noise_key), noise)


def make_sac_loss(policy: nn.Module, critic: nn.Module, action_dim: int, *, gamma: float,
                  ent_coef: float | str = "auto") -> SACLoss:
    """TorchRL's ``SACLoss`` with SB3's settings: two Q-networks, squared error, target entropy
    ``-action_dim``, a learned (``"auto"``) or fixed entropy coefficient (SB3's ``auto`` starts at 1).

    Examples:
        >>> from torchrl.data import Bounded
        >>> from sde_torchrl.modules.sac_actor import make_sac_networks
        >>> policy, critic, _ = make_sac_networks(3, Bounded(-1.0, 1.0, shape=(2,)), [8])
        >>> loss = make_sac_loss(policy, critic, 2, gamma=0.98)
        >>> loss.target_entropy.item(), loss.log_alpha.item(), loss.fixed_alpha
        (-2.0, 0.0, False)
    """
    auto = ent_coef == "auto"
    loss = SACLoss(policy, critic, num_qvalue_nets=2, loss_function="l2", alpha_init=1.0 if auto else float(ent_coef),
                   fixed_alpha=not auto, target_entropy=-float(action_dim))
    loss.make_value_estimator(gamma=gamma)
    return loss


__all__ = ["TRANSITION_KEYS", "fresh_loss_noise", "make_sac_loss"]
