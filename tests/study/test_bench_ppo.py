"""analysis/benchmarks/bench_ppo/: timed iterations of the PPO job and of SB3 built from the job's config,
split into phases, and its command line."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from analysis.benchmarks.bench_ppo import cli, iterations, speed, timing

#: Tiny sizes of the experiment (2 envs × 16 steps, one epoch, eager), for both sides.
TINY = ("algorithm.n_envs=2", "algorithm.n_steps=16", "algorithm.batch_size=16", "algorithm.n_epochs=1",
        "actor.hidden=[8]", "algorithm.compile=false")


@pytest.mark.parametrize("argv, message", [
    (["speed", "job", "--rollouts", "1"], "--rollouts must be at least 2"),
    (["phases", "sb3", "--rollouts", "1"], "--rollouts must be at least 2"),
    (["speed", "sde+compile"], "invalid choice"),
    (["run", "--method", "sde"], "invalid choice"),
    (["speed", "sb3", "job", "--repeats", "0"], "--repeats must be at least 1"),
])
def test_bad_command_lines_are_refused_by_name(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize("variant", ["job", "sb3"])
def test_phases_split_an_iteration_into_parts_that_fit_inside_it(monkeypatch, variant):
    """``bench_ppo phases`` on a tiny iteration: every phase is timed once per iteration, the parts
    of collection and update fit inside them, and collection plus GAE plus update make up the
    iteration."""
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("pybullet_envs_gymnasium")
    monkeypatch.setitem(speed.OVERRIDES, variant, TINY)
    clip = torch.nn.utils.clip_grad_norm_
    phases = speed.iteration_phases(variant, 3)
    from sde_torchrl.collectors import fused_steps, steps

    assert not timing.TIMER.active and torch.nn.utils.clip_grad_norm_ is clip  # nothing left switched on or patched
    assert steps.tensor_policy is fused_steps.tensor_policy
    assert {"iteration", "collect", "collect: pybullet step", "update"} <= set(phases)
    assert 0 < phases["collect: pybullet step"] < phases["collect"]
    if variant == "sb3":
        parts = ["update: loss forward", "update: clip + Adam step"]
        assert 0 < sum(phases[p] for p in parts) < phases["update"]
    else:
        parts = ["collect: pybullet step", "collect: policy forward", "collect: env transforms"]
        assert all(phases[p] > 0 for p in parts) and sum(phases[p] for p in parts) < phases["collect"]
    whole = phases["collect"] + phases.get("GAE", 0.0) + phases["update"]
    assert whole == pytest.approx(phases["iteration"], rel=0.2)


@pytest.mark.parametrize("train", [iterations.train_job, iterations.train_sb3])
def test_both_sides_are_timed_by_iteration_and_collection(train):
    """``bench_ppo speed``: the shipped experiment's trainer and SB3 built from its config (tiny sizes
    here), each iteration's end in wall and CPU time, each rollout's collection inside its iteration."""
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("pybullet_envs_gymnasium")
    result = train(3, TINY)
    ends, cpu_ends, collect = result["iteration_ends_s"], result["iteration_cpu_ends_s"], result["collect_s"]
    assert len(ends) == len(cpu_ends) == len(collect) == 3
    assert all(np.diff(ends) > 0) and all(c > 0 for c in cpu_ends)
    assert all(0 < c < d for c, d in zip(collect[1:], np.diff(ends), strict=True))


def test_the_raw_limit_steps_one_gymnasium_env_as_many_times_as_an_iteration():
    """``bench_ppo speed ... raw``: the experiment's env stepped with random actions, reset at
    episode ends, timed per iteration of ``frames`` steps."""
    pytest.importorskip("pybullet_envs_gymnasium")
    result = iterations.train_raw(2, 64)
    assert len(result["collect_s"]) == 2 and all(c > 0 for c in result["collect_s"])
    assert all(0 < c <= d for c, d in zip(result["collect_s"][1:], np.diff(result["iteration_ends_s"]), strict=True))


def test_sb3_is_built_from_the_jobs_config():
    """The SB3 side reads the experiment's settings: a change to the job's config reaches it."""
    pytest.importorskip("stable_baselines3")
    from analysis.benchmarks.gsde_table.sb3 import sb3_settings

    shipped = sb3_settings(iterations.job_config())
    tiny = sb3_settings(iterations.job_config(TINY))
    assert (shipped["env"]["n_envs"], shipped["kwargs"]["n_steps"]) == (16, 512)
    assert (tiny["env"]["n_envs"], tiny["kwargs"]["n_steps"], tiny["kwargs"]["n_epochs"]) == (2, 16, 1)
    assert shipped["kwargs"]["use_sde"] and not sb3_settings(iterations.job_config(("explorer=gaussian",)))[
        "kwargs"].get("use_sde", False)
    assert speed.iteration_frames() == 16 * 512


class _Raised(Exception):
    pass


def test_timing_sb3s_update_patches_torch_and_the_model_for_the_block_only():
    """``phases`` times SB3's clip by standing in for ``torch.nn.utils.clip_grad_norm_``, which SB3
    calls by that name: within the block the stand-ins time under the TorchRL update's names, and
    after it, also after an error, torch's function and the model's own methods are back."""
    from types import SimpleNamespace

    clip, parameter = torch.nn.utils.clip_grad_norm_, torch.zeros(2, requires_grad=True)
    optimizer = torch.optim.SGD([parameter], lr=0.1)
    policy = SimpleNamespace(evaluate_actions=lambda x: 2 * x, optimizer=optimizer)
    timer = timing.PhaseTimer()
    with timer.on() as seconds, timing.sb3_update_timed(SimpleNamespace(policy=policy), timer):
        assert torch.nn.utils.clip_grad_norm_ is not clip and "step" in vars(optimizer)
        assert policy.evaluate_actions(3) == 6
        parameter.grad = torch.ones(2)
        torch.nn.utils.clip_grad_norm_([parameter], 0.5)
        optimizer.step()
    assert set(seconds) == {"update: loss forward", "update: clip + Adam step"}
    assert parameter.grad.norm() == pytest.approx(0.5) and parameter.detach().tolist() != [0.0, 0.0]
    assert torch.nn.utils.clip_grad_norm_ is clip and "step" not in vars(optimizer)
    assert policy.evaluate_actions(3) == 6 and policy.evaluate_actions.__name__ == "<lambda>"
    with pytest.raises(_Raised), timing.sb3_update_timed(SimpleNamespace(policy=policy), timer):
        raise _Raised
    assert torch.nn.utils.clip_grad_norm_ is clip and "step" not in vars(optimizer)
    assert policy.evaluate_actions.__name__ == "<lambda>"
