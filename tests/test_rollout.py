"""The tensor-stepping rollout produces exactly the episodes TorchRL's env.rollout produces."""

from __future__ import annotations

import pytest
import torch
from tensordict.nn import TensorDictSequential
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sde_torchrl import LinearActor, MLPActor, StateDependentExplorer, make_minimize_env
from sde_torchrl.rng import RunStreams
from torchrl.envs import RewardScaling

from sde_torchrl.rollout import tensor_rollout, tensor_step_env


def _setup(schedule, every_n=None, actor="linear", squash=False, gaussian=None):
    runs, dim = 2, 2
    actor_module = (LinearActor(dim, dim, runs=runs, init=[-1.0, 0.0]) if actor == "linear"
                    else MLPActor(dim, dim, hidden=[3], runs=runs, init=[-1.0, 0.0]))
    actor_module.module.reset_parameters(RunStreams(0, runs, "init"))
    explorer = StateDependentExplorer(dim, dim, schedule=schedule, every_n=every_n, runs=runs,
                                      squash=squash, gaussian_init_param=gaussian)
    explorer.streams = RunStreams(0, runs, "explore")
    env = make_minimize_env(6, dim=dim, episodes=3, runs=runs, x0_spread=1.0, seed=4)
    env.append_transform(explorer.make_tensordict_primer())
    return env, TensorDictSequential(actor_module, explorer)


@pytest.mark.parametrize("schedule, every_n, actor, squash, gaussian", [
    ("episode", None, "linear", False, None),
    ("step", None, "linear", False, None),
    ("every_n", 2, "mlp", False, None),
    ("episode", None, "mlp", True, -1.0),
])
def test_tensor_rollout_equals_env_rollout(schedule, every_n, actor, squash, gaussian):
    env, policy = _setup(schedule, every_n, actor, squash, gaussian)
    with torch.no_grad():
        reference = env.rollout(6, policy, break_when_any_done=False)
    env2, policy2 = _setup(schedule, every_n, actor, squash, gaussian)
    base = tensor_step_env(env2, policy2)
    assert base is env2.base_env
    with torch.no_grad():
        fast = tensor_rollout(base, policy2, 6)
    assert fast.batch_size == reference.batch_size == (2, 3, 6)
    for key in ["observation", "loc", "scale", "action_log_prob", "action", "action_sample", "sde_noise", "is_init",
                ("next", "observation"), ("next", "reward"), ("next", "truncated")]:
        torch.testing.assert_close(fast[key], reference[key], msg=lambda m: f"{key}: {m}")


def test_tensor_rollout_is_deterministic_under_deterministic_exploration():
    env, policy = _setup("episode")
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        fast = tensor_rollout(env.base_env, policy, 6)
    torch.testing.assert_close(fast["action"], policy.module[0](fast.select("observation"))["loc"])


def test_envs_or_policies_it_cannot_reproduce_fall_back():
    env, policy = _setup("episode")
    assert tensor_step_env(env, TensorDictSequential(policy.module[0])) is None
    env.append_transform(RewardScaling(loc=0.0, scale=2.0))  # a transform that must run
    assert tensor_step_env(env, policy) is None


def test_tensor_rollout_equals_env_rollout_on_the_ball_catching_worlds():
    from torchrl.envs import Compose as _Compose, InitTracker, TransformedEnv

    from sde_torchrl import BatchedBallCatchEnv

    def setup():
        torch.manual_seed(0)
        explorer = StateDependentExplorer(4, 3, squash=True)
        explorer.streams = RunStreams(0, 3, "explore")  # the primer's global draws then do not matter
        env = TransformedEnv(BatchedBallCatchEnv(num_worlds=3, seed=5),
                             _Compose(InitTracker(), explorer.make_tensordict_primer()))
        return env, TensorDictSequential(LinearActor(3, 4, init=[-0.5, 0.5]), explorer)

    env, policy = setup()
    with torch.no_grad():
        reference = env.rollout(40, policy, break_when_any_done=False)
    env2, policy2 = setup()
    base = tensor_step_env(env2, policy2)
    assert base is env2.base_env
    with torch.no_grad():
        fast = tensor_rollout(base, policy2, 40)
    for key in ["observation", "action", "sde_noise", ("next", "observation"), ("next", "reward")]:
        torch.testing.assert_close(fast[key], reference[key], msg=lambda m: f"{key}: {m}")
    env.close()
    env2.close()
