"""SAC's actor and critic as Stable-Baselines3 builds them, on TorchRL modules.

Both actors are tanh-squashed into the action bounds and read an MLP of ReLU layers with
``torch.nn.Linear``'s initial distribution (SB3's ``sac/policies.py``, ``Actor``):

- with SDE (SB3's ``use_sde=True``): :func:`~sde_torchrl.modules.sde_actor.make_sde_actor` over a
  :class:`~sde_torchrl.modules.actors.LatentMLPActor` whose last hidden layer gives the noise its
  features, *not* detached (SB3's SAC builds its gSDE distribution with ``learn_features=True``),
  the mean clipped to ``[-CLIP_MEAN, CLIP_MEAN]`` before the squash (SB3's ``clip_mean=2.0``);
- without (``use_sde=False``): a state-dependent Gaussian, linear mean and log-std heads on the
  last hidden layer, the log-std clamped to ``[LOG_STD_MIN, LOG_STD_MAX]``
  (:class:`GaussianHeads`), through TorchRL's ``TanhNormal``.

The critic reads ``[observation, action]``; TorchRL's ``SACLoss`` makes its two Q-networks from it
(the SAC paper's clipped double Q, Haarnoja et al. 2018, "Soft Actor-Critic Algorithms and
Applications").
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data import TensorSpec
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator

from sde_torchrl.modules.actors import LatentMLPActor
from sde_torchrl.modules.sde import SDEParams
from sde_torchrl.modules.sde_actor import action_bounds, make_sde_actor

#: SB3's SAC actor with gSDE clips its mean to this bound before the squash (``clip_mean``).
CLIP_MEAN = 2.0
#: SB3's SAC actor without gSDE clamps its log-std head to these bounds.
LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0
#: Where the SDE actor writes the exploration features.
FEATURE_KEY = "sde_features"
#: Hidden activations by name, for the critic.
ACTIVATION_CLASSES = {"relu": nn.ReLU, "tanh": nn.Tanh, "sigmoid": nn.Sigmoid}


class GaussianHeads(nn.Module):
    """SB3's SAC actor without gSDE: an MLP, then linear mean and log-std heads (log-std clamped).

    Args:
        obs_dim: observation size.
        action_dim: action size.
        hidden: hidden layer sizes (at least one).
        activation_class: the hidden layers' activation.

    Examples:
        >>> loc, scale = GaussianHeads(3, 2, [8])(torch.zeros(5, 3))
        >>> loc.shape, bool((scale > 0).all())
        (torch.Size([5, 2]), True)
    """

    def __init__(self, obs_dim: int, action_dim: int, hidden: Sequence[int],
                 activation_class: type[nn.Module] = nn.ReLU) -> None:
        super().__init__()
        self.latent = MLP(in_features=obs_dim, out_features=hidden[-1], num_cells=list(hidden[:-1]),
                          activation_class=activation_class, activate_last_layer=True)
        self.mu, self.log_std = nn.Linear(hidden[-1], action_dim), nn.Linear(hidden[-1], action_dim)

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        latent = self.latent(observation)
        return self.mu(latent), self.log_std(latent).clamp(LOG_STD_MIN, LOG_STD_MAX).exp()


def make_sac_networks(
    obs_dim: int, action_spec: TensorSpec, hidden: Sequence[int], *, sde_options: Mapping[str, Any] | None = None,
    activation: str = "relu",
) -> tuple[ProbabilisticActor, ValueOperator, SDEParams | None]:
    """SAC's actor, its critic and the actor's :class:`~sde_torchrl.modules.sde.SDEParams`.

    The critic is made first, then the actor (the order their initial values are drawn in).

    Args:
        obs_dim: observation size.
        action_spec: the env's bounded action spec (the squash's bounds).
        hidden: hidden layer sizes of actor and critic (SB3's ``net_arch``).
        sde_options: keyword arguments of ``SDEParams`` (``schedule``, ``init_param``, ...) for
            the SDE actor; ``None``: the state-dependent Gaussian (:class:`GaussianHeads`).
        activation: the hidden layers' activation (SB3's SAC: ReLU).

    Returns:
        ``(policy, critic, sde)``; ``sde`` is ``None`` for the Gaussian. The env of an SDE
        policy needs ``sde.make_tensordict_primer()``.

    Examples:
        >>> from torchrl.data import Bounded
        >>> spec = Bounded(-1.0, 1.0, shape=(2,))
        >>> policy, critic, sde = make_sac_networks(3, spec, [8, 8], sde_options={"init_param": -3.0})
        >>> sde.sigma_param.shape, critic.in_keys
        (torch.Size([2, 8]), ['observation', 'action'])
        >>> make_sac_networks(3, spec, [8])[2] is None
        True
    """
    action_dim, activation_class = action_spec.shape[-1], ACTIVATION_CLASSES[activation]
    critic = ValueOperator(MLP(in_features=obs_dim + action_dim, out_features=1, num_cells=list(hidden),
                               activation_class=activation_class), in_keys=["observation", "action"])
    if sde_options is None:
        low, high = action_bounds(action_spec)
        heads = TensorDictModule(GaussianHeads(obs_dim, action_dim, hidden, activation_class),
                                 in_keys=["observation"], out_keys=["loc", "scale"])
        policy = ProbabilisticActor(heads, in_keys=["loc", "scale"], distribution_class=TanhNormal,
                                    distribution_kwargs={"low": low, "high": high}, return_log_prob=True)
        return policy, critic, None
    latent = LatentMLPActor(obs_dim, action_dim, hidden, activation=activation, learn_features=True,
                            feature_key=FEATURE_KEY, clip_loc=CLIP_MEAN)
    sde = SDEParams(action_dim, latent.feature_dim, feature_key=FEATURE_KEY, **sde_options)
    return make_sde_actor(TensorDictSequential(latent), sde, squash=True, action_spec=action_spec), critic, sde


__all__ = ["CLIP_MEAN", "FEATURE_KEY", "GaussianHeads", "LOG_STD_MAX", "LOG_STD_MIN", "make_sac_networks"]
