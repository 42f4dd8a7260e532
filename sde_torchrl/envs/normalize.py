"""Stable-Baselines3's ``VecNormalize`` rule as a TorchRL transform, for on-policy training.

Observations are standardised with running statistics of every observation stepped to, and
rewards divided by the running standard deviation of the discounted return, both clipped to
``[-clip, clip]`` (SB3's defaults: ``clip_obs = clip_reward = 10``, ``epsilon = 1e-8``), as
rl-baselines3-zoo's ``normalize: true`` runs its tuned PPO and A2C settings. The statistics and
each env's running return are buffers: a checkpoint of the module's state resumes them exactly.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.envs import Transform

#: SB3 ``VecNormalize``'s ``clip_obs`` (= ``clip_reward``) and ``epsilon``.
CLIP, EPS = 10.0, 1e-8


def running_update(
    mean: torch.Tensor, var: torch.Tensor, count: torch.Tensor, batch: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """SB3 ``RunningMeanStd``'s parallel update of mean and variance by a batch (over its
    leading dimensions).

    Examples:
        >>> mean, var, count = running_update(torch.zeros(1), torch.ones(1), torch.tensor(1e-4),
        ...                                   torch.tensor([[1.0], [3.0]]))
        >>> round(float(mean), 3), round(float(var), 3)
        (2.0, 1.0)
    """
    batch = batch.reshape(-1, *mean.shape).to(mean.dtype)
    b_mean, b_var, b_count = batch.mean(0), batch.var(0, unbiased=False), batch.shape[0]
    delta, total = b_mean - mean, count + b_count
    new_mean = mean + delta * b_count / total
    m2 = var * count + b_var * b_count + delta.square() * count * b_count / total
    return new_mean, m2 / total, total


class RunningNormalize(Transform):
    """Observation and reward normalisation with running statistics (SB3's ``VecNormalize``).

    Args:
        obs_dim: observation size.
        n_envs: envs in the batch (one running discounted return each).
        gamma: discount of the return whose spread scales the rewards.
        normalize_reward: scale the rewards (else only the observations are normalised).

    Attributes:
        update_stats: update the statistics while stepping (``False``: frozen, for evaluation).

    Examples:
        >>> from torchrl.envs import GymEnv, TransformedEnv
        >>> norm = RunningNormalize(3, n_envs=1, gamma=0.99)
        >>> env = TransformedEnv(GymEnv("Pendulum-v1"), norm)
        >>> _ = env.rollout(5)
        >>> float(norm.obs_count) > 4
        True
        >>> frozen = norm.frozen(n_envs=2)
        >>> frozen.update_stats, frozen.normalize_reward, bool((frozen.obs_mean == norm.obs_mean).all())
        (False, False, True)
    """

    def __init__(self, obs_dim: int, n_envs: int, gamma: float, normalize_reward: bool = True) -> None:
        super().__init__(in_keys=["observation"], out_keys=["observation"])
        self.gamma, self.normalize_reward, self.update_stats = gamma, normalize_reward, True
        self.register_buffer("obs_mean", torch.zeros(obs_dim, dtype=torch.float64))
        self.register_buffer("obs_var", torch.ones(obs_dim, dtype=torch.float64))
        self.register_buffer("obs_count", torch.tensor(1e-4, dtype=torch.float64))
        self.register_buffer("ret_mean", torch.zeros((), dtype=torch.float64))
        self.register_buffer("ret_var", torch.ones((), dtype=torch.float64))
        self.register_buffer("ret_count", torch.tensor(1e-4, dtype=torch.float64))
        self.register_buffer("returns", torch.zeros(n_envs, 1, dtype=torch.float64))

    def frozen(self, n_envs: int) -> RunningNormalize:
        """A copy with these statistics that neither updates them nor scales rewards (evaluation
        reports raw returns)."""
        copy = RunningNormalize(self.obs_mean.shape[0], n_envs, self.gamma, normalize_reward=False)
        state = {k: v for k, v in self.state_dict().items() if k != "returns"}
        copy.load_state_dict(state, strict=False)
        copy.update_stats = False
        return copy

    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        """``obs`` standardised with the current statistics and clipped (what a reset writes)."""
        scaled = (obs.double() - self.obs_mean) / (self.obs_var + EPS).sqrt()
        return scaled.clamp(-CLIP, CLIP).to(obs.dtype)

    def observe(self, obs: torch.Tensor, reward: torch.Tensor, done: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """One step of every env: updates the statistics (unless frozen) and each env's running
        return, and gives the normalised observation and scaled reward (what a step writes).

        Examples:
            >>> norm = RunningNormalize(2, n_envs=3, gamma=0.99)
            >>> obs, reward = norm.observe(torch.randn(3, 2), torch.ones(3, 1), torch.zeros(3, 1, dtype=torch.bool))
            >>> obs.shape, reward.shape, round(float(norm.obs_count))
            (torch.Size([3, 2]), torch.Size([3, 1]), 3)
        """
        if self.update_stats:
            self._update(self.obs_mean, self.obs_var, self.obs_count, obs)
        normalized = self.normalize(obs)
        if not self.normalize_reward:
            return normalized, reward
        self.returns.mul_(self.gamma).add_(reward.double())
        if self.update_stats:
            self._update(self.ret_mean, self.ret_var, self.ret_count, self.returns)
        scaled = (reward.double() / (self.ret_var + EPS).sqrt()).clamp(-CLIP, CLIP).to(reward.dtype)
        self.returns.masked_fill_(done, 0.0)
        return normalized, scaled

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        tensordict_reset.set("observation", self.normalize(tensordict_reset.get("observation")))
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        obs, reward = self.observe(next_tensordict.get("observation"), next_tensordict.get("reward"),
                                   next_tensordict.get("done"))
        next_tensordict.set("observation", obs)
        next_tensordict.set("reward", reward)
        return next_tensordict

    @staticmethod
    def _update(mean: torch.Tensor, var: torch.Tensor, count: torch.Tensor, batch: torch.Tensor) -> None:
        """:func:`running_update` of the statistics' buffers in place (an assignment would go
        through ``nn.Module.__setattr__`` on every step)."""
        for buffer, value in zip((mean, var, count), running_update(mean, var, count, batch), strict=True):
            buffer.copy_(value)


__all__ = ["RunningNormalize", "running_update"]
