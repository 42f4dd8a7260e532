"""The tensor path of step collection and evaluation gives TorchRL's steps, bit for bit.

Each test builds the same job twice from one seed, one collecting through
``env.step_and_maybe_reset`` (``StepCollector(..., fast=False)``) and one through
:mod:`sde_torchrl.collectors.fused_steps`, and compares every tensor they produce.
"""

from __future__ import annotations

import copy

import pytest
import torch
from _helpers import compose_config
from torchrl.envs import Compose, StepCounter, TransformedEnv

from sde_torchrl.collectors.fused_steps import fused_env
from sde_torchrl.collectors.steps import StepCollector

#: A2C on Pendulum-v1 with episodes shorter than a rollout, 3 envs: resets inside every rollout.
PENDULUM = ("algorithm=a2c", "env=gym", "env.episode_length=5", "algorithm.n_steps=7", "algorithm.n_envs=3",
            "actor.hidden=[8]", "updates=4", "eval_episodes=2", "logger=none")


def _build(*overrides: str, fast: bool = True):
    from sde_torchrl.config.build_onpolicy import build_onpolicy_trainer
    from sde_torchrl.config.build_sac import build_sac_trainer
    from sde_torchrl.config.schemas.train import validate

    conf = validate(compose_config(*overrides))
    sac = conf.algorithm.__class__.__name__ == "SACConf"
    trainer = (build_sac_trainer if sac else build_onpolicy_trainer)(conf)
    c = trainer.collector
    trainer.collector = StepCollector(c.env, c.policy, c.steps, c.primer, c.keep, fast=fast)
    assert (trainer.collector.fused is not None) == fast
    return trainer


def _assert_same(reference, fast, what: str) -> None:
    keys = set(reference.keys(True, True))
    assert keys == set(fast.keys(True, True)), what
    for key in keys:
        a, b = reference[key], fast[key]
        assert a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b), f"{what}: {key}"


def _rollouts(overrides: tuple[str, ...], rollouts: int = 4, keep_all: bool = False):
    out = []
    for fast in (False, True):
        torch.manual_seed(0)
        trainer = _build(*overrides, fast=fast)
        if keep_all:
            trainer.collector.keep = None
        out.append([(trainer.collector.rollout(), trainer.collector.carried.clone()) for _ in range(rollouts)])
    return out


@pytest.mark.parametrize("overrides", [
    ("explorer.schedule=episode",),
    ("explorer.schedule=step", "explorer.gaussian_init_param=-1"),
    ("explorer.schedule=every_n", "explorer.every_n=2", "algorithm.normalize=true"),
    ("explorer.schedule=every_n_steps", "explorer.every_n=3", "algorithm.normalize=true"),
    ("explorer.schedule=rollout", "algorithm.normalize=true"),
    ("explorer=gaussian", "algorithm.normalize=true"),
], ids=["episode", "rex-gaussian-part", "every-n", "every-n-steps", "rollout", "gaussian"])
def test_every_entry_of_every_rollout_and_the_carried_state_are_the_reference_paths(overrides):
    reference, fast = _rollouts((*PENDULUM, *overrides), keep_all=True)
    assert int(sum(r["next", "done"].sum() for r, _ in reference)) >= 6  # resets inside the rollouts
    for k, ((ref_rollout, ref_carried), (rollout, carried)) in enumerate(zip(reference, fast, strict=True)):
        _assert_same(ref_rollout, rollout, f"rollout {k}")
        _assert_same(ref_carried, carried, f"carried after rollout {k}")


#: SAC's squashed SDE policy on Pendulum-v1, episodes shorter than a round.
SAC_PENDULUM = ("algorithm=sac", "env=gym", "env.episode_length=5", "algorithm.train_freq=7",
                "algorithm.learning_starts=0", "explorer.init_param=0.5", "actor.hidden=[8]", "updates=4",
                "eval_episodes=2", "logger=none")


@pytest.mark.parametrize("overrides", [
    (),
    ("explorer.schedule=step", "explorer.gaussian_init_param=-1"),
    ("explorer.schedule=episode",),
    ("explorer=gaussian",),
], ids=["sb3-rounds", "rex-gaussian-part", "episode", "tanh-normal"])
def test_sacs_squashed_policies_rollouts_are_the_reference_paths(overrides):
    reference, fast = _rollouts((*SAC_PENDULUM, *overrides), keep_all=True)
    assert int(sum(r["next", "done"].sum() for r, _ in reference)) >= 4  # resets inside the rounds
    assert bool((reference[-1][0]["action"].abs() > 1.5).any())  # tanh far from its linear part (bounds ±2)
    for k, ((ref_rollout, ref_carried), (rollout, carried)) in enumerate(zip(reference, fast, strict=True)):
        _assert_same(ref_rollout, rollout, f"rollout {k}")
        _assert_same(ref_carried, carried, f"carried after rollout {k}")


@pytest.mark.parametrize("noise", ["sde", "gaussian"])
def test_sacs_squashed_policies_step_on_tensors_without_calling_their_forward(noise):
    trainer = _build(*SAC_PENDULUM, f"explorer={noise}")
    calls = []
    trainer.collector.policy.register_forward_hook(lambda *_: calls.append(1))
    trainer.collector.rollout()
    assert calls == []
    trainer.collector.fast = trainer.collector.fused = None  # the reference path does call it
    trainer.collector.rollout()
    assert len(calls) == 7


def test_a_pybullet_job_trains_and_evaluates_to_the_same_numbers():
    """Hopper: the time feature, running normalisation and SB3's rollout-long noise, episodes
    that end inside rollouts; updates, evaluations and parameters all equal."""
    overrides = ("+experiment=a2c_hopper_bullet", "env.episode_length=20", "algorithm.n_steps=16", "updates=3",
                 "eval_episodes=2", "logger=none")
    results = []
    for fast in (False, True):
        trainer = _build(*overrides, fast=fast)
        rows = [trainer.update(k) for k in range(3)]
        results.append((rows, trainer.evaluate(), trainer.modules.state_dict(), trainer.normalizer.state_dict()))
    (ref_rows, ref_eval, ref_params, ref_norm), (rows, evaluation, params, norm) = results
    for ref_row, row in zip(ref_rows, rows, strict=True):
        assert ref_row.keys() == row.keys() and all(torch.equal(ref_row[k], row[k]) for k in row)
    assert torch.equal(ref_eval, evaluation)
    assert all(torch.equal(ref_params[k], params[k]) for k in params)
    assert all(torch.equal(ref_norm[k], norm[k]) for k in norm)


@pytest.mark.parametrize("noise", ["sde", "gaussian"])
def test_sac_with_its_warm_up_policy_swapped_in_collects_the_same_steps(noise):
    overrides = ("algorithm=sac", "env=gym", "env.episode_length=6", "algorithm.train_freq=4",
                 "algorithm.gradient_steps=1", "algorithm.batch_size=4", "algorithm.learning_starts=8", "updates=4",
                 "eval_episodes=2", "actor.hidden=[4]", "logger=none", f"explorer={noise}")
    results = []
    for fast in (False, True):
        trainer = _build(*overrides, fast=fast)
        results.append(([trainer.update(k) for k in range(4)], trainer.evaluate(), trainer.modules.state_dict()))
    (ref_rows, ref_eval, ref_params), (rows, evaluation, params) = results
    for ref_row, row in zip(ref_rows, rows, strict=True):  # the Gaussian's σ statistics are NaN
        assert all(torch.allclose(ref_row[k], row[k], rtol=0, atol=0, equal_nan=True) for k in row)
    assert torch.equal(ref_eval, evaluation)
    assert all(torch.equal(ref_params[k], params[k]) for k in params)


def test_an_evaluation_gives_the_reference_paths_returns():
    trainer = _build(*PENDULUM, "env.episode_length=9", "eval_episodes=3", "algorithm.normalize=true")
    for k in range(2):
        trainer.update(k)
    streams = copy.deepcopy(trainer.eval_env.base_env._streams)
    trainer.collector.fast = False
    reference = trainer.deterministic_episodes(trainer.eval_env, trainer.eval_normalizer)
    trainer.eval_env.base_env._streams = streams
    trainer.collector.fast = True
    fast = trainer.deterministic_episodes(trainer.eval_env, trainer.eval_normalizer)
    for key in (("next", "reward"), ("next", "done")):
        assert torch.equal(reference[key], fast[key])


def test_envs_the_tensor_path_does_not_know_take_torchrls_steps():
    trainer = _build(*PENDULUM)
    env = trainer.collector.env
    assert fused_env(env) is not None
    assert fused_env(env.base_env) is not None  # no transforms at all
    counted = TransformedEnv(env.base_env, Compose(StepCounter(), *[t.clone() for t in env.transform]))
    assert fused_env(counted) is None  # a transform it does not reproduce
    reordered = TransformedEnv(env.base_env, Compose(*[t.clone() for t in reversed(list(env.transform))]))
    assert fused_env(reordered) is None  # the episode sum after the noise primer: another order
