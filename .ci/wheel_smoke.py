"""The installed wheel, used from outside the repository: one REINFORCE + SDE estimate on the
function-minimisation task, and the ball-catching env registered with gymnasium."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import gymnasium
import torch

import sde_torchrl
from sde_torchrl import LinearActor, ReinforceEstimator, SDEParams, make_minimize_env, make_sde_actor
from sde_torchrl.collectors.rollout import collect_episodes

assert "site-packages" in Path(sde_torchrl.__file__).parts, sde_torchrl.__file__
torch.manual_seed(0)
sde = SDEParams(1, 1)
policy = make_sde_actor(LinearActor(1, 1, init=-2.0), sde)
env = make_minimize_env(15, episodes=10).append_transform(sde.make_tensordict_primer())
loss = ReinforceEstimator(policy)(collect_episodes(env, policy, 15))
assert torch.isfinite(loss["loss_objective"]), loss
assert "sde_torchrl/BallCatch-v0" in gymnasium.envs.registry
print(f"sde_torchrl {importlib.metadata.version('sde_torchrl')} from {Path(sde_torchrl.__file__).parent}: ok")
