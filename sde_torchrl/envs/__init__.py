"""Environments: the function-minimisation task (and, with pybullet, ball catching).

The names below load :mod:`sde_torchrl.envs.minimize` (and torch) on first access (PEP 562), so
that importing :mod:`sde_torchrl.envs.registration` stays light.
"""

from __future__ import annotations

__all__ = ["MinimizeEnv", "expected_linear_return", "make_minimize_env", "midway_threshold"]


def __getattr__(name: str):
    if name in __all__:
        from sde_torchrl.envs import minimize

        return getattr(minimize, name)
    raise AttributeError(f"module 'sde_torchrl.envs' has no attribute {name!r}")
