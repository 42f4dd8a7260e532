"""sde_torchrl: state-dependent exploration for episodic policy gradients, on TorchRL."""

from __future__ import annotations

from sde_torchrl.actors import LinearActor, MLPActor
from sde_torchrl.distribution import SDENormal, TanhSDENormal
from sde_torchrl.envs import MinimizeEnv, make_minimize_env
from sde_torchrl.envs.registration import register_ballcatch
from sde_torchrl.estimators import ENACEstimator, ReinforceEstimator, episode_returns, episode_scores
from sde_torchrl.exploration import StateDependentExplorer, expln, expln_inverse
from sde_torchrl.sde_actor import SDENoisePrimer, SDEParams, action_bounds, make_sde_actor

register_ballcatch()  # gymnasium.make("sde_torchrl/BallCatch-v0"); pybullet loads on first use

#: Public names whose modules import pybullet: loaded on first access (PEP 562).
_LAZY = {"BallCatchEnv": "sde_torchrl.envs.ballcatch.gym_env",
         "BatchedBallCatchEnv": "sde_torchrl.envs.ballcatch.batched"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'sde_torchrl' has no attribute {name!r}")

__all__ = [
    "BallCatchEnv",
    "BatchedBallCatchEnv",
    "ENACEstimator",
    "LinearActor",
    "MLPActor",
    "MinimizeEnv",
    "ReinforceEstimator",
    "SDENoisePrimer",
    "SDENormal",
    "SDEParams",
    "StateDependentExplorer",
    "TanhSDENormal",
    "action_bounds",
    "episode_returns",
    "episode_scores",
    "expln",
    "expln_inverse",
    "make_minimize_env",
    "make_sde_actor",
]
