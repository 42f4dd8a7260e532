"""Gymnasium registration of the ball-catching env, without importing pybullet."""

from __future__ import annotations

import gymnasium as gym

BALLCATCH_ID = "sde_torchrl/BallCatch-v0"
#: 500 steps of 0.01 s (paper section 4.2).
EPISODE_STEPS = 500


def register_ballcatch() -> None:
    """Register ``sde_torchrl/BallCatch-v0`` with gymnasium (safe to call more than once).

    ``import sde_torchrl`` calls it; pybullet is only imported when the env is made.

    Examples:
        >>> import gymnasium as gym
        >>> register_ballcatch()
        >>> register_ballcatch()
        >>> env = gym.make("sde_torchrl/BallCatch-v0")
        >>> env.close()
    """
    if BALLCATCH_ID in gym.registry:
        return
    gym.register(
        id=BALLCATCH_ID,
        entry_point="sde_torchrl.envs.ballcatch.gym_env:BallCatchEnv",
        max_episode_steps=EPISODE_STEPS,
    )
