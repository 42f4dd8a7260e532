"""Stable-Baselines3's ``VecNormalize`` rule as a TorchRL transform, for on-policy training.

Observations are standardised with running statistics of every observation stepped to, and
rewards divided by the running standard deviation of the discounted return, both clipped to
``[-clip, clip]`` (SB3's defaults: ``clip_obs = clip_reward = 10``, ``epsilon = 1e-8``), as
rl-baselines3-zoo's ``normalize: true`` runs its tuned PPO and A2C settings. The statistics and
each env's running return are buffers: a checkpoint of the module's state resumes them exactly.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import Transform

#: SB3 ``VecNormalize``'s ``clip_obs`` (= ``clip_reward``) and ``epsilon``.
CLIP, EPS = 10.0, 1e-8
#: A moment held as a tensor, a numpy array or a float.
Moment = torch.Tensor | np.ndarray | float


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
    b_mean, b_var, b_count = _batch_moments(batch, mean)
    return combine_moments(mean, var, count, b_mean, b_var, b_count)


def combine_moments(mean: Moment, var: Moment, count: Moment, b_mean: Moment, b_var: Moment, b_count: int
                    ) -> tuple[Moment, Moment, Moment]:
    """Chan et al.'s combination of running moments ``(mean, var, count)`` with a batch's, as
    SB3's ``RunningMeanStd.update_from_moments``: elementwise arithmetic only, the same on
    tensors, numpy arrays and floats.

    Examples:
        >>> combine_moments(0.0, 1.0, 1.0, 2.0, 0.0, 1)
        (1.0, 1.5, 2.0)
    """
    delta, total = b_mean - mean, count + b_count
    new_mean = mean + delta * b_count / total
    m2 = var * count + b_var * b_count + delta * delta * count * b_count / total
    return new_mean, m2 / total, total


def _batch_moments(batch: torch.Tensor, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, int]:
    """A batch's mean, (biased) variance and size over its leading dimensions, in ``like``'s dtype."""
    batch = batch.reshape(-1, *like.shape).to(like.dtype)
    return batch.mean(0), batch.var(0, unbiased=False), batch.shape[0]


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
        return torch.from_numpy(self._normalized(self._arrays(), obs.numpy()))

    def observe(self, obs: torch.Tensor, reward: torch.Tensor, done: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """One step of every env: updates the statistics (unless frozen) and each env's running
        return, and gives the normalised observation and scaled reward (what a step writes).

        The statistics live in CPU buffers, and the arithmetic runs on numpy views of them: the
        batch moments are torch's, the rest elementwise IEEE arithmetic, the same numbers as on
        tensors with less overhead per call on arrays this small.

        Examples:
            >>> norm = RunningNormalize(2, n_envs=3, gamma=0.99)
            >>> obs, reward = norm.observe(torch.randn(3, 2), torch.ones(3, 1), torch.zeros(3, 1, dtype=torch.bool))
            >>> obs.shape, reward.shape, round(float(norm.obs_count))
            (torch.Size([3, 2]), torch.Size([3, 1]), 3)
        """
        arrays = self._arrays()
        if self.update_stats:
            _update_in_place(arrays, "obs", obs, self._buffers["obs_mean"])
        normalized = torch.from_numpy(self._normalized(arrays, obs.numpy()))
        if not self.normalize_reward:
            return normalized, reward
        returns, given = arrays["returns"], reward.numpy()
        raw = given.astype(np.float64)
        returns *= self.gamma
        returns += raw
        if self.update_stats:
            _update_in_place(arrays, "ret", self._buffers["returns"], self._buffers["ret_mean"])
        scaled = _clip(raw / np.sqrt(arrays["ret_var"] + EPS)).astype(given.dtype)
        returns[done.numpy()] = 0.0
        return normalized, torch.from_numpy(scaled)

    @staticmethod
    def _normalized(arrays: dict[str, np.ndarray], obs: np.ndarray) -> np.ndarray:
        scaled = (obs.astype(np.float64) - arrays["obs_mean"]) / np.sqrt(arrays["obs_var"] + EPS)
        return _clip(scaled).astype(obs.dtype)

    def _arrays(self) -> dict[str, np.ndarray]:
        """numpy views of the buffers, made again when a buffer's memory is not theirs (a buffer
        replaced by ``.to()``, a copied module; ``load_state_dict`` copies into the same memory)."""
        memory = tuple(tensor.data_ptr() for tensor in self._buffers.values())
        cached = self.__dict__.get("_views")
        if cached is None or cached[0] != memory:
            cached = self.__dict__["_views"] = (memory, {name: t.numpy() for name, t in self._buffers.items()})
        return cached[1]

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        tensordict_reset.set("observation", self.normalize(tensordict_reset.get("observation")))
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        obs, reward = self.observe(next_tensordict.get("observation"), next_tensordict.get("reward"),
                                   next_tensordict.get("done"))
        next_tensordict.set("observation", obs)
        next_tensordict.set("reward", reward)
        return next_tensordict


def _update_in_place(arrays: dict[str, np.ndarray], prefix: str, batch: torch.Tensor, like: torch.Tensor) -> None:
    """:func:`running_update` of the ``prefix`` statistics by ``batch``, written into their views."""
    b_mean, b_var, b_count = _batch_moments(batch, like)
    mean, var, count = (arrays[f"{prefix}_{name}"] for name in ("mean", "var", "count"))
    mean[...], var[...], count[...] = combine_moments(mean, var, float(count), b_mean.numpy(), b_var.numpy(), b_count)


def _clip(values: np.ndarray) -> np.ndarray:
    """``values`` clipped to ``[-CLIP, CLIP]`` (``torch.clamp``'s result, NaN kept)."""
    return np.minimum(np.maximum(values, -CLIP), CLIP)


__all__ = ["RunningNormalize", "combine_moments", "running_update"]
