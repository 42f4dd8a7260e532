"""The plain-Gaussian baseline of the on-policy algorithms: i.i.d. noise with a learned,
state-independent standard deviation per action (SB3's ``DiagGaussianDistribution``, its PPO
and A2C without ``use_sde``; TorchRL's ``AddStateIndependentNormalScale``).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from tensordict.utils import NestedKey
from torch import nn
from torchrl.modules import IndependentNormal, ProbabilisticActor, TanhNormal

from sde_torchrl.utils.checks import positive_int


class GaussianScale(TensorDictModuleBase):
    """Writes ``scale = exp(log_std)`` beside the controller's mean, one ``log_std`` per action.

    Args:
        action_dim: ``A``, size of the action.
        init_param: initial ``log_std`` (SB3's ``log_std_init``; ``-2``: ``σ ≈ 0.135``).
        learn_sigma: ``log_std`` as a learnable parameter, or a fixed buffer.
        loc_key: where the controller writes its mean.
        scale_key: where the standard deviation is written.

    Examples:
        >>> from tensordict import TensorDict
        >>> scale = GaussianScale(2, init_param=0.0)
        >>> scale(TensorDict({"loc": torch.zeros(5, 2)}, [5]))["scale"].shape
        torch.Size([5, 2])
        >>> scale.exploration_scale()
        tensor([1., 1.])
    """

    def __init__(self, action_dim: int, init_param: float = -2.0, learn_sigma: bool = True,
                 loc_key: NestedKey = "loc", scale_key: NestedKey = "scale") -> None:
        super().__init__()
        value = torch.full((positive_int("action_dim", action_dim),), float(init_param))
        if learn_sigma:
            self.log_std = nn.Parameter(value)
        else:
            self.register_buffer("log_std", value)
        self.in_keys, self.out_keys = [loc_key], [scale_key]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        loc = tensordict.get(self.in_keys[0])
        tensordict.set(self.out_keys[0], self.log_std.exp().to(loc.dtype).expand_as(loc))
        return tensordict

    def exploration_scale(self) -> torch.Tensor:
        """The standard deviation per action (``metrics.csv``'s ``sigma_min`` and ``sigma_max``)."""
        return self.log_std.detach().exp()


def make_gaussian_actor(
    actor: TensorDictModuleBase, action_dim: int, *, init_param: float = -2.0, learn_sigma: bool = True,
    squash: bool = False, low: float = -1.0, high: float = 1.0,
) -> ProbabilisticActor:
    """The Gaussian policy over ``actor`` (which writes ``loc``), for TorchRL's losses.

    Args:
        actor: writes the controller's mean under ``loc``.
        action_dim: ``A``.
        init_param: initial ``log_std``.
        learn_sigma: learn ``log_std``.
        squash: tanh into ``[low, high]`` (TorchRL's ``TanhNormal``), else an unbounded normal.
        low: lower action bound for ``squash``.
        high: upper action bound for ``squash``.

    Returns:
        A ``ProbabilisticActor`` writing ``action`` and ``action_log_prob``.

    Examples:
        >>> from sde_torchrl import MLPActor
        >>> from tensordict import TensorDict
        >>> policy = make_gaussian_actor(MLPActor(3, 1, [8], activation="relu"), 1)
        >>> sorted(policy(TensorDict({"observation": torch.zeros(4, 3)}, [4])).keys())
        ['action', 'action_log_prob', 'loc', 'observation', 'scale']
    """
    scale = GaussianScale(action_dim, init_param, learn_sigma)
    if squash:
        return ProbabilisticActor(TensorDictSequential(actor, scale), in_keys=["loc", "scale"],
                                  distribution_class=TanhNormal, distribution_kwargs={"low": low, "high": high},
                                  return_log_prob=True)
    return ProbabilisticActor(TensorDictSequential(actor, scale), in_keys=["loc", "scale"],
                              distribution_class=IndependentNormal, return_log_prob=True)


__all__ = ["GaussianScale", "make_gaussian_actor"]
