"""Any gymnasium continuous-control env: ``env=gym env.id=Pendulum-v1``."""

from __future__ import annotations

import pytest
import torch
from _helpers import compose_config, read_rows
from gymnasium.spaces import Box, Dict, Discrete, Tuple
from torchrl.envs.utils import check_env_specs

from sde_torchrl.collectors.rollout import tensor_step_env
from sde_torchrl.config.build import build_trainer
from sde_torchrl.envs.gym import FEATURES_KEY, GymRunsEnv, make_gym_env
from sde_torchrl.envs.gym_checks import check_spaces
from sde_torchrl.utils.checks import ArgumentError

SMALL = ("runs=2", "episodes_per_update=3", "eval_episodes=2", "env.episode_length=20", "eval_period=0")


def gym_trainer(*overrides: str):
    return build_trainer(compose_config("+experiment=pendulum", "logger=none", *overrides))


def test_env_specs_batch_and_seeding():
    env = make_gym_env("Pendulum-v1", 10, episodes=3, runs=2, normalize_obs="bounds", constant_feature=True)
    check_env_specs(env)
    td = env.rollout(10, break_when_any_done=False)
    assert td.batch_size == (2, 3, 10)
    assert td["observation"].abs().max() <= 1.0  # bounds → [-1, 1]
    assert torch.equal(td[FEATURES_KEY][..., -1], torch.ones(2, 3, 10))  # constant feature
    assert torch.equal(td[FEATURES_KEY][..., :-1], td["observation"])
    # Every episode of every run starts from its own state; run 1 is the run of a single job
    # with first_run=1.
    starts = td["observation"][:, :, 0].reshape(6, -1)
    assert len({tuple(s.tolist()) for s in starts}) == 6
    batched = make_gym_env("Pendulum-v1", 10, episodes=3, runs=2, seed=7)
    single = make_gym_env("Pendulum-v1", 10, episodes=3, runs=1, first_run=1, seed=7)
    assert torch.equal(single.reset()["observation"][0], batched.reset()["observation"][1])
    assert not torch.equal(batched.reset()["observation"][0], batched.reset()["observation"][1])


def test_early_end_is_held_absorbing():
    env = GymRunsEnv("MountainCarContinuous-v0", episodes=2, runs=1, gym_kwargs={"max_episode_steps": 5})
    env.reset()
    for _ in range(5):
        out = env.step(env.full_action_spec.zero().update({"action": torch.ones(1, 2, 1)}))
        env_td = out["next"]
    frozen = env_td["observation"].clone()
    after = env.step(env.full_action_spec.zero().update({"action": torch.ones(1, 2, 1)}))["next"]
    assert torch.equal(after["observation"], frozen) and bool((after["reward"] == 0).all())
    assert not bool(after["done"].any())  # the horizon is StepCounter's, not the task's


def test_episode_length_beyond_time_limit_is_refused():
    with pytest.raises(ValueError, match="at most 200"):
        make_gym_env("Pendulum-v1", 300, episodes=1)


def test_collection_falls_back_to_env_rollout():
    trainer = gym_trainer(*SMALL)
    assert tensor_step_env(trainer.env, trainer.policy) is None
    td = trainer.collect()
    assert td.batch_size == (2, 3, 20)


@pytest.mark.parametrize("overrides", [
    ("explorer=rex", "estimator=enac"),
    ("explorer=sde", "estimator=enac", "actor.bias=true", "env.normalize_obs=stats",
     "env.norm_init_steps=200", "env.constant_feature=true"),
    ("explorer=sde_gauss", "estimator=reinforce", "env.normalize_obs=bounds"),
])
def test_explorers_and_estimators_train(tmp_path, overrides):
    summary = gym_trainer(*SMALL, "updates=3", *overrides).train(tmp_path)
    assert summary["updates_done"] == 3
    assert all(torch.isfinite(torch.tensor(summary["final_return"])))
    if "env.constant_feature=true" in overrides:  # Θ̂ sees [x, 1]: σ̂ has S + 1 = 4 columns
        assert len(summary["final_parameters"]["module.0.module.1.sigma_param"][0]) == 4
        assert "module.0.module.0.module.bias" in summary["final_parameters"]


def test_gym_resume_is_bitwise(tmp_path):
    budget = (*SMALL, "updates=6")
    reference = gym_trainer(*budget).train(tmp_path / "ref", checkpoint_period=2)
    crashed = gym_trainer(*budget)
    original = crashed.update

    def crash(k):
        if k == 5:
            raise KeyboardInterrupt
        return original(k)

    crashed.update = crash
    with pytest.raises(KeyboardInterrupt):
        crashed.train(tmp_path / "resumed", checkpoint_period=2)
    resumed = gym_trainer(*budget).train(tmp_path / "resumed", checkpoint_period=2)
    assert (tmp_path / "resumed" / "metrics.csv").read_bytes() == (tmp_path / "ref" / "metrics.csv").read_bytes()
    reference.pop("wall_s"), resumed.pop("wall_s")
    assert resumed == reference


def test_pendulum_return_rises(tmp_path):
    """The shipped experiment: 20 updates of 10 episodes, SDE + REINFORCE."""
    summary = gym_trainer().train(tmp_path)
    returns = [float(row["return_mean"]) for row in read_rows(tmp_path)]
    assert len(returns) == 20
    first, last = sum(returns[:5]) / 5, sum(returns[-5:]) / 5
    print(f"pendulum: mean return {first:.3f} (first 5 updates) -> {last:.3f} (last 5)")
    assert last > first + 1.0, (first, last)
    assert summary["final_eval_return"][0] > -2.0


@pytest.mark.parametrize("action, observation, expected", [
    (Discrete(2), Box(-1, 1, (4,)), "an env with a continuous (Box) action space; X-v0 has Discrete(2)"),
    (Tuple((Discrete(2), Box(-1, 1, (1,)))), Box(-1, 1, (4,)),
     "an env with a continuous (Box) action space; X-v0 has Tuple(Discrete(2), Box(-1.0, 1.0, (1,), float32))"),
    (Box(-1, 1, (2, 2)), Box(-1, 1, (4,)),
     "an env with a flat (1-D Box) action space; X-v0 has Box(-1.0, 1.0, (2, 2), float32)"),
    (Box(-1, 1, (1,)), Dict({"a": Box(-1, 1, (2,))}),
     "an env with a flat (1-D Box) observation space; X-v0 has Dict('a': Box(-1.0, 1.0, (2,), float32))"),
])
def test_unsupported_spaces_are_named(action, observation, expected):
    with pytest.raises(ArgumentError) as info:
        check_spaces("X-v0", action, observation)
    assert str(info.value) == f"env.id=X-v0: {expected}"


def test_discrete_env_is_refused_when_built():
    """Python callers (and ``module:Env-v0`` ids, which the schema leaves to the build) get the
    schema's error."""
    with pytest.raises(ArgumentError, match="^env.id=CartPole-v1: an env with a continuous"):
        GymRunsEnv("CartPole-v1", episodes=1)
