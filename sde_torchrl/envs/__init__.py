"""Environments: the function-minimisation task (and, with pybullet, ball catching)."""

from __future__ import annotations

from sde_torchrl.envs.minimize import MinimizeEnv, make_minimize_env

__all__ = ["MinimizeEnv", "make_minimize_env"]
