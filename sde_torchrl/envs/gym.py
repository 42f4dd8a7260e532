"""Any gymnasium continuous-control env, batched ``[runs, episodes]`` for episodic training.

``env=gym env.id=Pendulum-v1`` trains on any registered gymnasium env with a continuous
(``Box``) action space. Each batch element is a TorchRL ``GymEnv``; :class:`GymRunsEnv` steps
them side by side with per-run seeds and a fixed horizon, and :func:`make_gym_env` adds the
transforms that matter for SDE, whose exploration ``Θ̂ x`` scales with the features ``|x|``:
a fixed observation normalisation and a constant feature.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import Compose, EnvBase, InitTracker, ObservationNorm, StepCounter, Transform, TransformedEnv
from torchrl.envs.libs.gym import GymEnv

from sde_torchrl.envs.gym_checks import check_env_output, check_spaces, check_time_limit
from sde_torchrl.envs.vector import first_reset
from sde_torchrl.utils.checks import positive_int
from sde_torchrl.utils.options import NORMALIZATIONS
from sde_torchrl.utils.rng import RunStreams

log = logging.getLogger(__name__)

#: Key of the explorer's features when ``constant_feature`` is set.
FEATURES_KEY = "sde_features"
#: Making the envs of a batch takes longer than this (about 3 ms each): their count is logged,
#: then again every :data:`MAKE_PROGRESS_S`.
MAKE_PROGRESS_S = 10.0


class GymRunsEnv(EnvBase):
    """``runs × episodes`` copies of a gymnasium env as one TorchRL env of batch ``[runs, episodes]``.

    Per-run randomness: every reset reseeds each episode's env with a seed drawn from its run's
    stream (:class:`~sde_torchrl.utils.rng.RunStreams`, like :class:`~sde_torchrl.envs.MinimizeEnv`),
    so run ``r`` of a batched job sees the start states a single job with ``first_run=r`` sees,
    and a checkpoint of the streams resumes the env exactly: each env is reset once when it is
    made (:func:`~sde_torchrl.envs.vector.first_reset`), so that an episode depends on its seed
    and actions alone, not on the env's past (a PyBullet env's first reset is unlike its later ones).

    Fixed horizon: the episodic estimators want ``T`` steps per episode. An episode that ends
    earlier (the task terminates, or gymnasium's time limit truncates it) is held in an absorbing
    state until step ``T``: observation frozen, reward 0, the env not stepped.

    Args:
        env_id: a registered gymnasium id (``"Pendulum-v1"``; ``"module:Env-v0"`` imports
            ``module`` first).
        episodes: episodes per run, simulated side by side.
        runs: independent runs (the leading batch dimension).
        first_run: global index of the first run (seeding shards of a sweep).
        stream: ``"env"`` (training) or ``"eval_env"`` (evaluation).
        seed: job seed (``None``: 0; :meth:`set_seed` changes it).
        gym_kwargs: passed to ``gymnasium.make`` through ``GymEnv``.
        reset_options: passed to every ``reset`` (``options=``), e.g. Pendulum's start range
            ``{"x_init": 0.3, "y_init": 0.3}``.
        device: where the observations, rewards and flags are put (the gymnasium envs, and the
            state kept between steps, stay on the CPU).

    Raises:
        ArgumentError: for an env whose action or observation space SDE cannot use (a discrete
            action space, a ``Dict`` observation: see :func:`~sde_torchrl.envs.gym_checks.check_spaces`).
        EnvOutputError: (when reset or stepped) an env returned a non-finite observation or reward
            after a finite action (:func:`~sde_torchrl.envs.gym_checks.check_env_output`).

    Examples:
        >>> env = GymRunsEnv("Pendulum-v1", episodes=2, runs=1)
        >>> env.rollout(3)["next", "reward"].shape
        torch.Size([1, 2, 3, 1])
    """

    def __init__(
        self, env_id: str, episodes: int = 10, runs: int = 1, *, first_run: int = 0,
        stream: str = "env", seed: int | None = None, gym_kwargs: dict[str, Any] | None = None,
        reset_options: dict[str, Any] | None = None, device: torch.device | str = "cpu",
    ) -> None:
        positive_int("episodes", episodes)
        positive_int("runs", runs)
        batch = torch.Size((runs, episodes))
        super().__init__(batch_size=batch, device=device)
        self.env_id, self.runs, self.first_run, self.stream = env_id, runs, first_run, stream
        self.reset_options = dict(reset_options) if reset_options else None
        use = "evaluation" if stream == "eval_env" else "training"
        self.envs = make_envs(env_id, runs * episodes, gym_kwargs or {}, f"{runs} runs × {episodes} {use} episodes")
        proto = self.envs[0]
        check_spaces(env_id, proto._env.action_space, proto._env.observation_space)
        first_reset((env._env for env in self.envs), self.reset_options)
        self.max_episode_steps = getattr(proto._env.spec, "max_episode_steps", None)
        self.observation_spec = proto.observation_spec.expand(batch).clone().to(self.device)
        self.action_spec = proto.action_spec.expand(*batch, *proto.action_spec.shape).clone().to(self.device)
        self.reward_spec = proto.reward_spec.expand(*batch, *proto.reward_spec.shape).clone().to(self.device)
        # the gymnasium envs step on the CPU: their state is kept there, the outputs go to the device
        self._absorbed = torch.zeros(*batch, 1, dtype=torch.bool)
        self._steps = [0] * (runs * episodes)  # steps of each env's episode so far, for messages
        self._last_obs = proto.observation_spec["observation"].expand(*batch, *proto.observation_spec[
            "observation"].shape).zero()
        self._streams: RunStreams | None = None
        self.set_seed(0 if seed is None else seed)

    def _set_seed(self, seed: int | None) -> None:
        self._streams = RunStreams(0 if seed is None else int(seed), self.runs, self.stream, self.first_run)

    def episode_seeds(self) -> torch.Tensor:
        """One 48-bit seed per ``(run, episode)`` from the runs' streams, ``[runs, episodes]``."""
        halves = (self._streams.uniform((*self.batch_size, 2)) * 2**24).long().clamp(max=2**24 - 1)
        return halves[..., 0] * 2**24 + halves[..., 1]

    def _reset(self, tensordict: TensorDictBase | None, **kwargs) -> TensorDictBase:
        seeds = self.episode_seeds().flatten()  # drawn for all: streams stay data-independent
        mask = torch.ones(len(self.envs), dtype=torch.bool)
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(len(self.envs), -1).any(-1).cpu()
        obs = self._last_obs.reshape(len(self.envs), -1).clone()
        for i in mask.nonzero().flatten().tolist():
            obs[i] = self.envs[i]._reset(seed=int(seeds[i]), options=self.reset_options)["observation"]
            self._steps[i] = 0
            check_env_output(self.env_id, f"the reset of {self._episode(i)} (seed {int(seeds[i])})", obs[i])
        self._absorbed.view(-1)[mask] = False
        self._last_obs = obs.reshape(self._last_obs.shape)
        return TensorDict({"observation": self._last_obs.clone()}, batch_size=self.batch_size, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get("action").reshape(len(self.envs), -1).cpu()
        obs = self._last_obs.reshape(len(self.envs), -1).clone()
        reward = torch.zeros(len(self.envs), 1)
        absorbed = self._absorbed.view(-1)
        for i, env in enumerate(self.envs):
            if absorbed[i]:
                continue  # episode over: frozen observation, no reward
            out = env._step(TensorDict({"action": actions[i]}, batch_size=[]))
            obs[i], reward[i] = out["observation"], out["reward"]
            self._steps[i] += 1
            check_env_output(self.env_id, f"step {self._steps[i]} of {self._episode(i)}", obs[i], reward[i], actions[i])
            absorbed[i] = bool(out["done"].any())
        self._last_obs = obs.reshape(self._last_obs.shape)
        done = torch.zeros(*self.batch_size, 1, dtype=torch.bool)  # the horizon is StepCounter's
        return TensorDict({
            "observation": self._last_obs.clone(),
            "reward": reward.reshape(*self.batch_size, 1),
            "done": done, "terminated": done.clone(), "truncated": done.clone(),
        }, batch_size=self.batch_size, device=self.device)

    def _episode(self, i: int) -> str:
        """The ``i``-th env of the flattened batch, in words: its run (global index) and episode."""
        run, episode = divmod(i, self.batch_size[1])
        return f"run {self.first_run + run} episode {episode}"

    def close(self, *, raise_if_closed: bool = True) -> None:
        for env in self.envs:
            env.close()
        super().close(raise_if_closed=raise_if_closed)


def make_envs(env_id: str, count: int, gym_kwargs: dict[str, Any], what: str) -> list[GymEnv]:
    """``count`` TorchRL ``GymEnv`` of ``env_id``, logging how many are made when that takes a while
    (after :data:`MAKE_PROGRESS_S`, then as often: tens of thousands take minutes).

    Examples:
        >>> len(make_envs("Pendulum-v1", 2, {}, "1 run × 2 training episodes"))
        2
    """
    envs: list[GymEnv] = []
    start = time.monotonic()
    due = start + MAKE_PROGRESS_S
    for _ in range(count):
        envs.append(GymEnv(env_id, **gym_kwargs))
        now = time.monotonic()
        if now >= due and len(envs) < count:
            log.info("making %d %s envs (%s): %d made after %.0f s", count, env_id, what, len(envs), now - start)
            due = now + MAKE_PROGRESS_S
    return envs


class ConstantFeature(Transform):
    """Writes ``sde_features = [observation, 1]``: exploration features with a constant.

    SDE's exploration ``Θ̂ x`` vanishes at ``x = 0``; the constant adds a state-independent
    part (one more column of ``Θ̂``, drawn per episode like the rest).

    Examples:
        >>> env = TransformedEnv(GymRunsEnv("Pendulum-v1", episodes=2), ConstantFeature())
        >>> env.reset()["sde_features"].shape
        torch.Size([1, 2, 4])
    """

    def __init__(self, in_key: str = "observation", out_key: str = FEATURES_KEY) -> None:
        super().__init__(in_keys=[in_key], out_keys=[out_key])

    def _apply_transform(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.cat([obs, torch.ones_like(obs[..., :1])], dim=-1)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        spec = observation_spec[self.in_keys[0]]
        observation_spec[self.out_keys[0]] = Unbounded(
            shape=(*spec.shape[:-1], spec.shape[-1] + 1), dtype=spec.dtype, device=spec.device)
        return observation_spec


def observation_norm(env: GymRunsEnv, kind: str, steps: int = 1000) -> ObservationNorm:
    """A fixed ``ObservationNorm`` for ``env``'s observations.

    Args:
        env: the batched env (its spec gives the bounds).
        kind: ``"bounds"`` (map a bounded space to ``[-1, 1]``) or ``"stats"`` (standardise with
            the mean and standard deviation of ``steps`` uniformly random steps, seeded).
        steps: random steps for ``"stats"``.

    Returns:
        The transform (``(x - loc) / scale``).
    """
    if kind == "bounds":
        spec = env.observation_spec["observation"]
        low, high = spec.space.low.reshape(-1, spec.shape[-1])[0], spec.space.high.reshape(-1, spec.shape[-1])[0]
        if not bool(torch.isfinite(low).all() and torch.isfinite(high).all()):
            raise ValueError(f"{env.env_id} has unbounded observations; use env.normalize_obs=stats")
        loc, scale = (high + low) / 2, ((high - low) / 2).clamp_min(1e-6)
    elif kind == "stats":
        loc, scale = random_observation_stats(env.envs[0], steps)
    else:
        raise ValueError(f"unknown normalize_obs {kind!r}; expected one of {NORMALIZATIONS} or None")
    return ObservationNorm(loc=loc, scale=scale, in_keys=["observation"], standard_normal=True)


def random_observation_stats(env: GymEnv, steps: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and standard deviation of the observations of ``steps`` uniformly random steps.

    Uses its own seeded generators (not the job's streams), so every job and run, training
    and evaluation, gets the same statistics.
    """
    gym_env = env._env
    rng = np.random.default_rng(seed)
    space = gym_env.action_space
    env_id = gym_env.spec.id if gym_env.spec is not None else type(gym_env).__name__
    obs, _ = gym_env.reset(seed=seed)
    check_env_output(env_id, "the first reset of env.normalize_obs=stats's statistics", obs)
    seen = [np.asarray(obs, dtype=np.float64)]
    for step in range(1, steps):
        action = rng.uniform(space.low, space.high).astype(space.dtype)
        obs, reward, terminated, truncated, _ = gym_env.step(action)
        check_env_output(env_id, f"random step {step} of env.normalize_obs=stats's statistics", obs, reward, action)
        if terminated or truncated:
            obs, _ = gym_env.reset(seed=int(rng.integers(2**31)))
            check_env_output(env_id, f"the reset after random step {step} of env.normalize_obs=stats's statistics", obs)
        seen.append(np.asarray(obs, dtype=np.float64))
    data = np.stack(seen)
    return (torch.as_tensor(data.mean(0), dtype=torch.float32),
            torch.as_tensor(data.std(0), dtype=torch.float32).clamp_min(1e-6))


def make_gym_env(
    id: str, episode_length: int = 200, *, episodes: int = 10, runs: int = 1, first_run: int = 0,
    stream: str = "env", normalize_obs: str | None = None, norm_init_steps: int = 1000,
    constant_feature: bool = False, gym_kwargs: dict[str, Any] | None = None,
    reset_options: dict[str, Any] | None = None, seed: int | None = None, device: torch.device | str = "cpu",
) -> TransformedEnv:
    """A gymnasium env for episodic training: batch ``[runs, episodes]``, ``episode_length`` steps.

    Args:
        id: gymnasium id, e.g. ``"Pendulum-v1"``.
        episode_length: ``T``; at most the env's own time limit.
        episodes: episodes per run and update.
        runs: independent runs.
        first_run: global index of the first run.
        stream: ``"env"`` or ``"eval_env"``.
        normalize_obs: ``None``; ``"bounds"`` maps a bounded observation space to ``[-1, 1]``;
            ``"stats"`` standardises with the mean and standard deviation of ``norm_init_steps``
            steps of uniformly random actions (seeded, the same for every job and run). Both are
            fixed TorchRL ``ObservationNorm`` transforms: no running statistics to checkpoint,
            and training and evaluation see the same features.
        norm_init_steps: random steps for ``"stats"``.
        constant_feature: add ``sde_features = [observation, 1]`` for the explorer, so that the
            exploration does not vanish where the observation is near 0.
        gym_kwargs: passed to ``gymnasium.make``.
        reset_options: passed to every reset (``options=``), e.g. a start-state range.
        seed: job seed (``None``: 0).
        device: where the observations, rewards and flags are put (gymnasium steps on the CPU).

    Returns:
        ``GymRunsEnv`` with ``[ObservationNorm,] [ConstantFeature,] StepCounter, InitTracker``.

    Raises:
        ArgumentError: for unusable spaces (see :class:`GymRunsEnv`), or an ``episode_length``
            beyond the env's time limit (the message gives the override that raises it).

    Examples:
        >>> env = make_gym_env("Pendulum-v1", 50, episodes=3, runs=2, normalize_obs="bounds")
        >>> env.rollout(50, break_when_any_done=False).batch_size
        torch.Size([2, 3, 50])
    """
    positive_int("episode_length", episode_length)
    base = GymRunsEnv(id, episodes, runs, first_run=first_run, stream=stream, seed=seed,
                      gym_kwargs=dict(gym_kwargs or {}), reset_options=reset_options, device=device)
    check_time_limit(id, episode_length, base.max_episode_steps)
    transforms: list[Transform] = []
    if normalize_obs is not None:
        transforms.append(observation_norm(base, normalize_obs, norm_init_steps))
    if constant_feature:
        transforms.append(ConstantFeature())
    transforms += [StepCounter(episode_length), InitTracker()]
    env = TransformedEnv(base, Compose(*transforms).to(base.device))  # ObservationNorm's loc and scale
    env.episode_length = episode_length
    return env
