"""Gymnasium envs side by side for continuing on-policy training (PPO, A2C), resumable by replay.

:class:`GymVectorEnv` steps ``n`` gymnasium envs as one TorchRL env of batch ``[n]``. Unlike
:class:`~sde_torchrl.envs.gym.GymRunsEnv` (whole episodes of a fixed length for the episodic
estimators), an episode here ends where the env ends it (terminated, or truncated by its time
limit or at ``episode_length`` steps) and the caller resets the done envs alone, as TorchRL's
``step_and_maybe_reset`` does; rollouts then run through episode boundaries, as SB3's do. A
simulator's state mid-episode cannot in general be saved, so a job resumes the envs by replaying
each episode's seed and actions (:meth:`GymVectorEnv.restore_replay`).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import gymnasium
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from sde_torchrl.envs.gym_checks import check_env_output, check_spaces, check_time_limit
from sde_torchrl.utils.checks import positive_int
from sde_torchrl.utils.native_output import native_stdout_silenced
from sde_torchrl.utils.rng import RunStreams


class ReplayMismatchError(RuntimeError):
    """Replaying an env's episode did not reproduce its recorded observation."""


class GymVectorEnv(EnvBase):
    """``n_envs`` copies of a gymnasium env as one TorchRL env of batch ``[n_envs]``.

    Two choices follow Stable-Baselines3: the env steps with the action clipped to its bounds
    while the batch keeps the sampled one (pybullet's locomotion envs charge their costs on the
    action they are given), and each episode starts from a seed, drawn from the job's ``env``
    stream (:class:`~sde_torchrl.utils.rng.RunStreams`) at every reset. With ``time_feature`` the
    observation ends with ``1 - t / episode_length`` (sb3-contrib's ``TimeFeatureWrapper``).
    It takes TorchRL's partial steps: a step whose ``"_step"`` mask is off for an env leaves that
    env as it is, so ``rollout(..., break_when_all_done=True)`` steps each env to its episode's
    end and no further (an evaluation's episodes).

    Args:
        env_id: a gymnasium id (``"Pendulum-v1"``; ``"module:Env-v0"`` imports ``module`` first).
        n_envs: envs stepped side by side.
        episode_length: an episode is truncated after this many steps (at most the env's own
            time limit).
        stream: the job's random stream for the episode seeds (``"env"`` or ``"eval_env"``).
        seed: job seed (:meth:`set_seed` changes it).
        gym_kwargs: passed to ``gymnasium.make``.
        reset_options: passed to every ``reset`` (``options=``).
        time_feature: append ``1 - t / episode_length`` to the observation, ``t`` the steps since
            the reset (needs an ``episode_length`` or a time limit).

    Raises:
        ArgumentError: for spaces SDE cannot use, or an ``episode_length`` beyond the env's time limit.
        EnvOutputError: (when reset or stepped) an env returned a non-finite observation or reward
            after a finite action (:func:`~sde_torchrl.envs.gym_checks.check_env_output`).

    Examples:
        >>> env = GymVectorEnv("Pendulum-v1", n_envs=3, episode_length=5)
        >>> td = env.rollout(12, break_when_any_done=False)
        >>> td.batch_size, int(td["next", "truncated"].sum())
        (torch.Size([3, 12]), 6)
        >>> once = GymVectorEnv("Pendulum-v1", n_envs=2, episode_length=5).rollout(
        ...     12, break_when_any_done=False, break_when_all_done=True)
        >>> once.batch_size, int(once["next", "truncated"][:, -1].sum())
        (torch.Size([2, 5]), 2)
        >>> timed = GymVectorEnv("Pendulum-v1", n_envs=1, episode_length=4, time_feature=True)
        >>> timed.rollout(3)["next", "observation"][0, :, -1].tolist()
        [0.75, 0.5, 0.25]
    """

    def __init__(
        self, env_id: str, n_envs: int = 1, episode_length: int | None = None, *, stream: str = "env",
        seed: int = 0, gym_kwargs: dict[str, Any] | None = None, reset_options: dict[str, Any] | None = None,
        time_feature: bool = False,
    ) -> None:
        positive_int("n_envs", n_envs)
        super().__init__(batch_size=torch.Size([n_envs]))
        self.env_id, self.stream, self.gym_kwargs = env_id, stream, dict(gym_kwargs or {})
        self.reset_options = dict(reset_options) if reset_options else None
        self.envs = [gymnasium.make(env_id, **self.gym_kwargs) for _ in range(n_envs)]
        proto = self.envs[0]
        check_spaces(env_id, proto.action_space, proto.observation_space)
        limit = getattr(proto.spec, "max_episode_steps", None)
        self.episode_length = episode_length if episode_length is not None else limit
        if self.episode_length is not None:
            check_time_limit(env_id, self.episode_length, limit)
        if time_feature and self.episode_length is None:
            raise ValueError(f"{env_id}: time_feature needs an episode_length (the env has no time limit)")
        first_reset(self.envs, self.reset_options)
        self.time_feature = time_feature
        self.low, self.high = proto.action_space.low, proto.action_space.high
        obs_dim, act_dim = proto.observation_space.shape[0] + int(time_feature), proto.action_space.shape[0]
        self.observation_spec = Composite(observation=Unbounded((n_envs, obs_dim), dtype=torch.float32),
                                          shape=(n_envs,))
        self.action_spec = Bounded(torch.as_tensor(self.low, dtype=torch.float32).expand(n_envs, act_dim),
                                   torch.as_tensor(self.high, dtype=torch.float32).expand(n_envs, act_dim),
                                   (n_envs, act_dim), dtype=torch.float32)
        self.reward_spec = Unbounded((n_envs, 1), dtype=torch.float32)
        self.done_spec = Composite({key: Categorical(2, (n_envs, 1), dtype=torch.bool)
                                    for key in ("done", "terminated", "truncated")}, shape=(n_envs,))
        self._seeds = [0] * n_envs
        self._actions: list[list[np.ndarray]] = [[] for _ in range(n_envs)]
        self._last_obs = np.zeros((n_envs, obs_dim), dtype=np.float32)
        self._streams: RunStreams | None = None
        self.set_seed(seed)

    def _set_seed(self, seed: int | None) -> None:
        self._streams = RunStreams(0 if seed is None else int(seed), 1, self.stream)

    def _episode_seeds(self) -> list[int]:
        """One 48-bit seed per env, drawn for all of them at every reset (the stream's use does
        not depend on which envs are done)."""
        halves = (self._streams.uniform((1, self.batch_size[0], 2))[0] * 2**24).long().clamp(max=2**24 - 1)
        return (halves[:, 0] * 2**24 + halves[:, 1]).tolist()

    def _reset(self, tensordict: TensorDictBase | None, **kwargs: Any) -> TensorDictBase:
        mask = None
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(len(self.envs), -1).any(-1).tolist()
        return TensorDict({"observation": torch.as_tensor(self.reset_arrays(mask))}, batch_size=self.batch_size)

    def reset_arrays(self, mask: list[bool] | None = None) -> np.ndarray:
        """Resets the envs where ``mask`` is true (``None``: all), each with a fresh episode seed,
        and returns every env's observation, ``[n_envs, obs_dim]`` (a copy): what a reset writes.

        The seeds are drawn for every env at every reset, whichever are reset.
        """
        seeds = self._episode_seeds()
        for i, reset in enumerate([True] * len(self.envs) if mask is None else mask):
            if reset:
                self._last_obs[i] = self._observe(i, self._start(i, seeds[i]))
        return self._last_obs.copy()

    def _observe(self, i: int, obs: np.ndarray) -> np.ndarray:
        """Env ``i``'s observation, with the time feature if asked."""
        if not self.time_feature:
            return obs
        return np.append(obs, np.float32(1.0 - len(self._actions[i]) / self.episode_length))

    def _start(self, i: int, seed: int) -> np.ndarray:
        self._seeds[i], self._actions[i] = seed, []
        obs, _ = self.envs[i].reset(seed=seed, options=self.reset_options)
        check_env_output(self.env_id, f"the reset of env {i} (seed {seed})", obs)
        return obs

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        stepping = tensordict.get("_step", None)  # a rollout that stops each env at its episode's end
        active = None if stepping is None else stepping.reshape(len(self.envs)).nonzero().flatten().tolist()
        obs, reward, terminated, truncated = self.step_arrays(tensordict.get("action").detach().cpu().numpy(), active)
        return TensorDict({
            "observation": torch.as_tensor(obs), "reward": torch.as_tensor(reward),
            "done": torch.as_tensor(terminated | truncated), "terminated": torch.as_tensor(terminated),
            "truncated": torch.as_tensor(truncated),
        }, batch_size=self.batch_size)

    def step_arrays(self, actions: np.ndarray, active: list[int] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Steps the envs (those in ``active``; ``None``: all) with ``actions`` clipped to the
        bounds: what a step writes, as arrays ``(observation [n, obs_dim] (a copy), reward
        [n, 1], terminated [n, 1], truncated [n, 1])``; an env not stepped keeps its
        observation, with reward 0 and both flags false.

        Examples:
            >>> env = GymVectorEnv("Pendulum-v1", n_envs=2)
            >>> _ = env.reset()
            >>> [a.shape for a in env.step_arrays(np.zeros((2, 1), dtype=np.float32))]
            [(2, 3), (2, 1), (2, 1), (2, 1)]
        """
        actions = np.clip(actions, self.low, self.high)
        n = len(self.envs)
        reward = np.zeros((n, 1), dtype=np.float32)
        terminated, truncated = np.zeros((n, 1), dtype=bool), np.zeros((n, 1), dtype=bool)
        stepped = range(n) if active is None else active
        for i in stepped:
            obs, reward[i], terminated[i], truncated[i], _ = self.envs[i].step(actions[i])
            self._actions[i].append(actions[i])
            self._last_obs[i] = self._observe(i, obs)
            if self.episode_length is not None and len(self._actions[i]) >= self.episode_length:
                truncated[i] = True
        if not (np.isfinite(self._last_obs).all() and np.isfinite(reward).all()):  # one test per step; names the env
            for i in stepped:
                check_env_output(self.env_id, f"step {len(self._actions[i])} of env {i}'s episode "
                                 f"(seed {self._seeds[i]})", self._last_obs[i], reward[i], actions[i])
        return self._last_obs.copy(), reward, terminated, truncated

    def replay_state(self) -> dict[str, Any]:
        """What puts fresh envs where these are: per env, the seed of its episode, the actions
        stepped since its reset and the observation they led to (tensors and plain data).

        Examples:
            >>> env = GymVectorEnv("Pendulum-v1", n_envs=2)
            >>> _ = env.rollout(4)
            >>> state = env.replay_state()
            >>> [len(actions) for actions in state["actions"]]
            [4, 4]
        """
        act_dim = self.action_spec.shape[-1]
        return {"seeds": list(self._seeds),
                "actions": [torch.as_tensor(np.asarray(a, dtype=np.float32).reshape(-1, act_dim))
                            for a in self._actions],
                "observation": torch.as_tensor(self._last_obs.copy())}

    def restore_replay(self, state: dict[str, Any]) -> None:
        """Resets each env with its recorded seed and steps it with its recorded actions.

        :meth:`replay_state` holds, per env, its episode's seed and the actions stepped since;
        this resets fresh envs with those seeds, steps them again and checks that they arrive at
        the recorded observations, bit for bit. That holds for envs whose ``reset(seed=...)``
        fixes their whole state (the classic-control envs and the PyBullet locomotion envs); an
        env for which it does not is refused on resume, by name, instead of resumed to other
        numbers. It also needs each env reset once when it is made (:func:`first_reset`): a
        PyBullet env's first reset is unlike its later ones.

        Raises:
            ReplayMismatchError: an env did not arrive at its recorded observation, bit for bit.

        Examples:
            >>> env = GymVectorEnv("Pendulum-v1", n_envs=2)
            >>> _ = env.rollout(4)
            >>> again = GymVectorEnv("Pendulum-v1", n_envs=2)
            >>> again.restore_replay(env.replay_state())
            >>> bool((again.replay_state()["observation"] == env.replay_state()["observation"]).all())
            True
        """
        for i, (seed, actions) in enumerate(zip(state["seeds"], state["actions"], strict=True)):
            obs = self._start(i, int(seed))
            for action in actions.numpy():
                obs = self.envs[i].step(action)[0]
                self._actions[i].append(action)
            self._last_obs[i] = self._observe(i, obs)
        if not np.array_equal(self._last_obs, state["observation"].numpy()):
            bad = int(np.flatnonzero((self._last_obs != state["observation"].numpy()).any(-1))[0])
            raise ReplayMismatchError(
                f"{self.env_id}: replaying env {bad}'s episode (seed {state['seeds'][bad]}, "
                f"{len(state['actions'][bad])} steps) did not reproduce its observation: this env's "
                "reset(seed) does not fix its state, so the job cannot resume bit for bit")

    def close(self, *, raise_if_closed: bool = True) -> None:
        for env in self.envs:
            env.close()
        super().close(raise_if_closed=raise_if_closed)


#: The seed of the reset that :func:`first_reset` gives every env before its first episode.
FIRST_RESET_SEED = 0


def first_reset(envs: Iterable[gymnasium.Env], options: dict[str, Any] | None = None) -> None:
    """Resets newly made envs once each (seed :data:`FIRST_RESET_SEED`), so that no episode
    starts from an env's first reset; what a simulator prints as it connects there is dropped.

    A PyBullet locomotion env connects its simulator and builds its world at its first reset,
    and completes it only after computing the robot's state: the floor joins the parts whose
    mean position gives the potential that the first step's progress reward is measured from. So
    an env's first episode gets another first reward than any later episode with the same seed
    and actions, though the same observations. Later resets restore the world saved at the first
    one and are alike whatever came before: after this reset, an episode depends on its seed and
    actions alone, not on the env's past, and a resumed job's fresh envs continue where an
    uninterrupted job's envs were. For an env whose ``reset(seed=...)`` sets its whole state (the
    classic-control envs) this reset changes nothing: every episode starts with such a reset.

    Examples:
        >>> env = gymnasium.make("Pendulum-v1")
        >>> first_reset([env])
        >>> env.step(env.action_space.low)[0].shape
        (3,)
    """
    with native_stdout_silenced():
        for env in envs:
            env.reset(seed=FIRST_RESET_SEED, options=options)


__all__ = ["FIRST_RESET_SEED", "GymVectorEnv", "ReplayMismatchError", "first_reset"]
