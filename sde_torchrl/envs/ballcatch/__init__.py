"""Ball-catching task of the SDE paper (Rückstieß et al. 2008, section 4.2), rebuilt in pybullet.

An arm with a hand must catch a ball released above its palm; the agent observes the ball's
xyz and outputs 4 torques (shoulder, elbow, wrist, all fingers). Each part has one module:

* :mod:`~sde_torchrl.envs.ballcatch.models`: the arms (``"pybrain"``, the default, after PyBrain's
  ``arm.xode``; ``"cup"``), their figures and hand-written catching controllers (plain data);
* :mod:`~sde_torchrl.envs.ballcatch.world`: the physics, one pybullet world per
  :class:`BallCatchWorld` built from a :class:`BallCatchConfig`;
* :mod:`~sde_torchrl.envs.ballcatch.task`: the task rules (action clipping, ground contact,
  reward, episode length), :class:`CatchEpisode`, through which every form below steps a world;
* :mod:`~sde_torchrl.envs.ballcatch.gym_env`: the gymnasium env ``sde_torchrl/BallCatch-v0``;
* :mod:`~sde_torchrl.envs.ballcatch.batched`: the TorchRL env of N worlds;
* :mod:`~sde_torchrl.envs.ballcatch.episodes`: whole episodes of linear controllers (fast path);
* :mod:`~sde_torchrl.envs.ballcatch.demo`: the demo and GIF command line,
  ``python -m sde_torchrl.envs.ballcatch --policy scripted --episodes 5 [--model cup]``.
"""

from __future__ import annotations

from sde_torchrl.envs.ballcatch.batched import BatchedBallCatchEnv, make_ballcatch_env, make_parallel_ballcatch
from sde_torchrl.envs.ballcatch.gym_env import BallCatchEnv, episode_return
from sde_torchrl.envs.ballcatch.models import ARM_MODELS, DEFAULT_MODEL, ArmModel, scripted_action, scripted_weights
from sde_torchrl.envs.ballcatch.task import EPISODE_STEPS, CatchEpisode
from sde_torchrl.envs.ballcatch.world import BallCatchConfig, BallCatchWorld
from sde_torchrl.envs.registration import BALLCATCH_ID, register_ballcatch

__all__ = [
    "ARM_MODELS",
    "DEFAULT_MODEL",
    "BALLCATCH_ID",
    "EPISODE_STEPS",
    "ArmModel",
    "BallCatchConfig",
    "BallCatchEnv",
    "BallCatchWorld",
    "BatchedBallCatchEnv",
    "CatchEpisode",
    "episode_return",
    "make_ballcatch_env",
    "make_parallel_ballcatch",
    "register_ballcatch",
    "scripted_action",
    "scripted_weights",
]
