"""The ball-catching task as a gymnasium env, ``sde_torchrl/BallCatch-v0`` (:class:`BallCatchEnv`),
and a runner of single episodes (:func:`episode_return`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from sde_torchrl.envs.ballcatch.models import scripted_action
from sde_torchrl.envs.ballcatch.task import EPISODE_STEPS, CatchEpisode
from sde_torchrl.envs.ballcatch.world import TIME_STEP, BallCatchConfig, BallCatchWorld

__all__ = ["BallCatchEnv", "episode_return", "validate_action"]


def validate_action(action: Any) -> np.ndarray:
    """Return ``action`` as a float64 array of shape ``(4,)`` (the task clips it to ``[-1, 1]``).

    Raises:
        ValueError: if the shape is not ``(4,)`` or an entry is not finite.

    Examples:
        >>> validate_action([0.5, 0.0, 2.0, -1.0]).tolist()
        [0.5, 0.0, 2.0, -1.0]
    """
    arr = np.asarray(action, dtype=np.float64)
    if arr.shape != (4,):
        raise ValueError(f"action must have shape (4,), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"action contains non-finite values: {arr.tolist()}")
    return arr


class BallCatchEnv(gym.Env):
    """Gymnasium env of the paper's ball-catching task (registered as ``sde_torchrl/BallCatch-v0``).

    Observation: ball centre xyz, float32 ``(3,)``. Action: ``Box(-1, 1, (4,))`` scaled by
    the config's ``max_torques`` (shoulder, elbow, wrist, all fingers). Reward: ``-3`` once the
    ball has touched the ground, else ``-clip(ball-palm distance, 0.5, 3)`` (the task rules,
    :mod:`~sde_torchrl.envs.ballcatch.task`). Every episode is 500 steps long and ends by
    truncation (``terminated`` is always False); once the ball has touched the ground the world
    is frozen and each remaining step gives ``-3``.
    ``info`` holds ``distance`` (ball-palm centres), ``held`` (the ball is in contact with the
    palm or a finger and has never touched the ground) and ``grounded``.

    Args:
        render_mode: ``None`` or ``"rgb_array"`` (software renderer, no display needed).
        config: physical parameters; ``BallCatchConfig(jitter=0.0)`` makes every episode identical.
        render_size: ``(width, height)`` of rendered frames.
        model: the arm (``"pybrain"``, the default, ``"cup"`` or a diagnostic,
            :data:`~sde_torchrl.envs.ballcatch.models.ARM_MODELS`) when no ``config`` is
            given, e.g. ``gymnasium.make("sde_torchrl/BallCatch-v0", model="cup")``; with a
            ``config`` it must be ``None`` or the config's model.

    Examples:
        >>> import numpy as np
        >>> env = BallCatchEnv()
        >>> obs, info = env.reset(seed=0)
        >>> total = 0.0
        >>> for _ in range(500):
        ...     obs, r, terminated, truncated, info = env.step(scripted_action(obs))
        ...     total += r
        >>> bool(total / 500 > -1.1), truncated
        (True, True)
        >>> env.close()
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": round(1 / TIME_STEP)}

    def __init__(
        self,
        render_mode: str | None = None,
        config: BallCatchConfig | None = None,
        render_size: tuple[int, int] = (160, 120),
        model: str | None = None,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if config is not None and model not in (None, config.model):
            raise ValueError(f"model={model!r} contradicts config.model={config.model!r}")
        self.render_mode = render_mode
        self.render_size = render_size
        self.config = config or (BallCatchConfig() if model is None else BallCatchConfig(model=model))
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(3,), dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.world = BallCatchWorld(self.config, name="gym world")
        self.episode = CatchEpisode(self.world, EPISODE_STEPS)
        self._ready = False

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Restore the start pose and release the ball above the palm (jittered by ``seed``)."""
        super().reset(seed=seed)
        offset = self.np_random.uniform(-self.config.jitter, self.config.jitter, size=2)
        self.episode.reset(offset)
        self._ready = True
        info = {"distance": self.episode.distance, "held": False, "grounded": False}
        return np.asarray(self.episode.ball, dtype=np.float32), info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply the torques ``action * max_torques`` for one 0.01 s step.

        Raises:
            ValueError: if ``action`` does not have shape ``(4,)`` or is not finite.
            RuntimeError: if called before :meth:`reset` or the physics client died.
        """
        if not self._ready:
            raise RuntimeError("BallCatchEnv.step called before reset (or after the episode ended)")
        episode = self.episode
        reward = episode.step(validate_action(action).tolist())
        held = (not episode.grounded) and self.world.ball_touches_hand()
        self._ready = not episode.truncated
        info = {"distance": episode.distance, "held": held, "grounded": episode.grounded}
        return np.asarray(episode.ball, dtype=np.float32), reward, False, episode.truncated, info

    def render(self) -> np.ndarray | None:
        """An RGB frame (``render_mode="rgb_array"``), else ``None``."""
        if self.render_mode != "rgb_array":
            return None
        return self.world.render(*self.render_size)

    def close(self) -> None:
        """Disconnect the physics client."""
        self.world.close()


def episode_return(
    env: BallCatchEnv, policy: str | Callable[[np.ndarray], np.ndarray], seed: int,
    rng: np.random.Generator | None = None, frames: list | None = None, frame_every: int = 5,
) -> float:
    """Run one episode and return the paper's return (mean reward over the 500 steps).

    Args:
        env: the environment.
        policy: ``"scripted"`` (:func:`scripted_action` of the env's model), ``"zero"``,
            ``"random"``, or a function observation → action.
        seed: reset seed.
        rng: generator for the random policy (defaults to one seeded with ``seed``).
        frames: if given, every ``frame_every``-th rendered frame is appended to it.
        frame_every: frame subsampling.

    Examples:
        >>> env = BallCatchEnv(model="pybrain")
        >>> round(episode_return(env, "zero", seed=0), 2)  # the open hand: the ball rolls off
        -2.33
        >>> env.close()
    """
    if not callable(policy) and policy not in ("scripted", "zero", "random"):
        raise ValueError(f"policy must be 'scripted', 'zero', 'random' or a function, got {policy!r}")
    rng = rng or np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    total, truncated, t = 0.0, False, 0
    while not truncated:
        if callable(policy):
            action = policy(obs)
        elif policy == "scripted":
            action = scripted_action(obs, env.config.model)
        elif policy == "zero":
            action = np.zeros(4)
        else:
            action = rng.uniform(-1.0, 1.0, size=4)
        obs, reward, _, truncated, _ = env.step(action)
        total += reward
        if frames is not None and t % frame_every == 0:
            frames.append(env.render())
        t += 1
    return total / EPISODE_STEPS
