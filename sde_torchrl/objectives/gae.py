"""TorchRL's generalised advantage estimate for rollouts read by a plain critic, with less overhead per call.

:class:`RolloutGAE` is TorchRL's ``GAE`` (``A_t = Σ_l (γλ)^l δ_{t+l}``, ``δ_t = r_t + γ V(s_{t+1})
(1 - terminated_t) - V(s_t)``, episodes cut at ``done``). TorchRL's ``GAE.forward`` stacks the
rollout's and its next step's tensordicts, maps the critic module over the two with ``vmap`` and
passes the values to its functional estimator; for a rollout without NaN next observations, step
counts or ``is_init`` flags, read by a critic of one observation key, this does the same on the
tensors themselves: the critic's network mapped with ``vmap`` over the two observation tensors
stacked (the same batched products, so the same values), the same functional estimator, the same
entries written. Any other call (parameters passed, gradients on,
chunked values, the shifted or multi-agent variants) goes to ``GAE.forward``.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch.func import vmap
from torchrl.objectives.value import GAE
from torchrl.objectives.value.functional import generalized_advantage_estimate, vec_generalized_advantage_estimate


class RolloutGAE(GAE):
    """TorchRL's ``GAE``, computed on tensors for a plain rollout (the same entries and numbers).

    Takes ``GAE``'s arguments. The tensor path applies when no gradient is recorded, no
    parameters are passed, the critic is a ``TensorDictModule`` reading one observation key and
    writing the value key, and the rollout has no ``steps_to_next_obs`` or ``is_init`` entry and
    no NaN in its next observations; ``shifted``, ``average_gae``, ``auto_reset_env``, value
    chunks and a ``time_dim`` other than the last batch dimension take ``GAE.forward``.

    Examples:
        >>> from tensordict import TensorDict
        >>> from torchrl.modules import MLP, ValueOperator
        >>> critic = ValueOperator(MLP(in_features=3, out_features=1, num_cells=[8]), in_keys=["observation"])
        >>> rollout = TensorDict({"observation": torch.randn(2, 5, 3), "next": {
        ...     "observation": torch.randn(2, 5, 3), "reward": torch.randn(2, 5, 1),
        ...     "done": torch.zeros(2, 5, 1, dtype=torch.bool), "terminated": torch.zeros(2, 5, 1, dtype=torch.bool)}},
        ...     [2, 5])
        >>> with torch.no_grad():
        ...     ours = RolloutGAE(gamma=0.99, lmbda=0.95, value_network=critic)(rollout.clone())
        ...     torchrls = GAE(gamma=0.99, lmbda=0.95, value_network=critic)(rollout.clone())
        >>> all(torch.equal(ours[k], torchrls[k]) for k in ("advantage", "value_target", "state_value"))
        True
    """

    def forward(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        if kwargs or not isinstance(tensordict, TensorDictBase) or not self._plain(tensordict):
            return super().forward(tensordict, **kwargs)  # parameters passed, tensors by keyword, other settings
        keys, critic = self.tensor_keys, self.value_network
        obs_key = critic.in_keys[0]
        stacked = torch.stack([tensordict.get(obs_key), tensordict.get(("next", obs_key))])
        value, next_value = vmap(critic.module, (0,), randomness=self.vmap_randomness)(stacked).unbind(0)
        reward = tensordict.get(("next", keys.reward))
        done = tensordict.get(("next", keys.done))
        terminated = tensordict.get(("next", keys.terminated), default=done)
        estimate = vec_generalized_advantage_estimate if self.vectorized else generalized_advantage_estimate
        advantage, value_target = estimate(self.gamma, self.lmbda, value, next_value, reward, done=done,
                                           terminated=terminated, time_dim=tensordict.ndim - 1)
        tensordict.set(keys.advantage, advantage)
        tensordict.set(keys.value_target, value_target)
        tensordict.set(keys.value, value)
        tensordict.set(("next", keys.value), next_value)
        return tensordict

    def _plain(self, tensordict: TensorDictBase) -> bool:
        """Whether ``tensordict`` and the settings are those the tensor path reproduces."""
        critic, keys = self.value_network, self.tensor_keys
        settings_plain = not (torch.is_grad_enabled() or self.shifted or self.average_gae or self.auto_reset_env
                              or self.skip_existing or self.deactivate_vmap or self.value_chunk_size is not None
                              or self.num_chunks is not None)
        if not (settings_plain and _plain_critic(critic) and list(critic.out_keys) == [keys.value]
                and tensordict.batch_dims >= 1 and self._get_time_dim(None, tensordict) == tensordict.ndim - 1):
            return False
        present = tensordict.keys(True)
        if keys.steps_to_next_obs in present or "is_init" in present:
            return False
        obs, next_obs = tensordict.get(critic.in_keys[0], None), tensordict.get(("next", critic.in_keys[0]), None)
        reward = tensordict.get(("next", keys.reward), None)
        return (obs is not None and next_obs is not None and reward is not None and obs.shape == next_obs.shape
                and reward.device == self.gamma.device and not bool(next_obs.isnan().any()))


def _plain_critic(critic: object) -> bool:
    """A ``TensorDictModule`` (TorchRL's ``ValueOperator``) of one input key whose call is its
    network's: no overridden ``forward``, no hooks."""
    return (isinstance(critic, TensorDictModule) and type(critic).forward is TensorDictModule.forward
            and len(critic.in_keys) == 1 and not critic._forward_hooks and not critic._forward_pre_hooks)


__all__ = ["RolloutGAE"]
