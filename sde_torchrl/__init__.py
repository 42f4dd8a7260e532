"""sde_torchrl: state-dependent exploration for episodic policy gradients, on TorchRL."""

from __future__ import annotations

from sde_torchrl.envs.registration import register_ballcatch

register_ballcatch()  # gymnasium.make("sde_torchrl/BallCatch-v0"); pybullet loads on first use

#: Public names, each loaded from its module on first access (PEP 562): ``import sde_torchrl``
#: does not import torch, so that ``train.py`` can lock its run directory first
#: (:mod:`sde_torchrl.jobs.lock`), and the ball-catching modules do not import pybullet before use.
_LAZY = {
    **dict.fromkeys(("LatentMLPActor", "LinearActor", "MLPActor"), "sde_torchrl.modules.actors"),
    **dict.fromkeys(("SDENormal", "TanhSDENormal"), "sde_torchrl.modules.distribution"),
    **dict.fromkeys(("MinimizeEnv", "make_minimize_env"), "sde_torchrl.envs.minimize"),
    **dict.fromkeys(("ENACEstimator", "GPOMDPEstimator", "ReinforceEstimator", "episode_scores"),
                    "sde_torchrl.objectives.estimators"),
    "episode_returns": "sde_torchrl.objectives.base",
    **dict.fromkeys(("SDEParams", "expln", "expln_inverse"), "sde_torchrl.modules.sde"),
    "SDENoisePrimer": "sde_torchrl.modules.noise",
    "ParameterExplorer": "sde_torchrl.modules.pgpe",
    "PGPEEstimator": "sde_torchrl.objectives.pgpe",
    **dict.fromkeys(("SDEActor", "action_bounds", "make_sde_actor"), "sde_torchrl.modules.sde_actor"),
    "BallCatchEnv": "sde_torchrl.envs.ballcatch.gym_env",
    "BatchedBallCatchEnv": "sde_torchrl.envs.ballcatch.batched",
    **dict.fromkeys(("catch_level", "catch_outcomes"), "sde_torchrl.envs.ballcatch.outcomes"),
    "nonfinite_policy": "sde_torchrl.utils.nonfinite",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'sde_torchrl' has no attribute {name!r}")

__all__ = [
    "BallCatchEnv",
    "BatchedBallCatchEnv",
    "ENACEstimator",
    "GPOMDPEstimator",
    "LatentMLPActor",
    "LinearActor",
    "MLPActor",
    "MinimizeEnv",
    "PGPEEstimator",
    "ParameterExplorer",
    "ReinforceEstimator",
    "SDEActor",
    "SDENoisePrimer",
    "SDENormal",
    "SDEParams",
    "TanhSDENormal",
    "action_bounds",
    "catch_level",
    "catch_outcomes",
    "episode_returns",
    "episode_scores",
    "expln",
    "expln_inverse",
    "make_minimize_env",
    "make_sde_actor",
    "nonfinite_policy",
]
