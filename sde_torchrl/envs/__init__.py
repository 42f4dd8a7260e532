"""Environments: the function-minimisation task (and, with pybullet, ball catching)."""

from __future__ import annotations

from sde_torchrl.envs.minimize import MinimizeEnv, expected_linear_return, make_minimize_env, midway_threshold

__all__ = ["MinimizeEnv", "expected_linear_return", "make_minimize_env", "midway_threshold"]
