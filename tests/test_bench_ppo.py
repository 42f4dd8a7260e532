"""analysis/benchmarks/bench_ppo/: SB3's normalisation rule, a short real PPO run with the SDE policy, the report."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from _helpers import REPO

from analysis.benchmarks import common
from analysis.benchmarks.bench_ppo import build, cli, report, speed, timing, train
from sde_torchrl.envs.normalize import running_update


def test_running_statistics_match_stable_baselines3():
    from stable_baselines3.common.running_mean_std import RunningMeanStd

    reference, rng = RunningMeanStd(shape=(3,)), np.random.default_rng(0)
    mean, var, count = torch.zeros(3, dtype=torch.float64), torch.ones(3, dtype=torch.float64), torch.tensor(1e-4)
    for _ in range(5):
        batch = rng.normal(2.0, 3.0, size=(16, 3))
        reference.update(batch)
        mean, var, count = running_update(mean, var, count.double(), torch.from_numpy(batch))
    np.testing.assert_allclose(mean.numpy(), reference.mean, rtol=1e-12)
    np.testing.assert_allclose(var.numpy(), reference.var, rtol=1e-12)


def test_normalizer_scales_rewards_by_the_discounted_return_like_vecnormalize():
    from stable_baselines3.common.running_mean_std import RunningMeanStd
    from tensordict import TensorDict

    gamma, normalizer, reference = 0.9, build.make_normalizer(2, 0.9), RunningMeanStd(shape=())
    returns = np.zeros(4)
    for step in range(6):
        reward, done = torch.full((4, 1), float(step + 1)), torch.tensor([[False]] * 3 + [[step == 2]])
        td = TensorDict({"observation": torch.randn(4, 2), "reward": reward, "done": done}, [4])
        out = normalizer._step(TensorDict({}, [4]), td)
        returns = returns * gamma + reward.squeeze(-1).numpy()
        reference.update(returns)
        expected = np.clip(reward.squeeze(-1).numpy() / np.sqrt(reference.var + 1e-8), -10, 10)
        np.testing.assert_allclose(out["reward"].squeeze(-1).numpy(), expected, rtol=1e-6)
        returns[done.squeeze(-1).numpy()] = 0


def test_the_env_steps_with_the_clipped_action_and_the_batch_keeps_the_sampled_one():
    """SB3 clips before ``env.step``; pybullet charges its energy costs on the action it is given."""
    env = build.make_torchrl_env(2, 0, build.make_normalizer(26, 0.99))
    reference = build.make_torchrl_env(2, 0, build.make_normalizer(26, 0.99))
    try:
        td = env.reset()
        td["action"] = torch.tensor([[3.0, -3.0, 0.5, 1.0, -1.0, 0.0]] * 2)
        out = env.step(td)
        ref = reference.reset()
        ref["action"] = td["action"].clamp(-1, 1)
        expected = reference.step(ref)["next", "episode_reward"]
    finally:
        env.close()
        reference.close()
    assert torch.equal(out["action"], td["action"])  # what the loss scores: the sampled action
    torch.testing.assert_close(out["next", "episode_reward"], expected)  # what the env got: the clipped one
    unclipped = build.make_torchrl_env(2, 0, build.make_normalizer(26, 0.99), clip_actions=False)
    try:
        raw = unclipped.step(unclipped.reset().update({"action": td["action"]}))["next", "episode_reward"]
    finally:
        unclipped.close()
    assert (raw < expected - 0.5).all()  # the ablation's env charges the energy costs on the raw action


@pytest.mark.e2e
def test_a_short_sde_run_writes_its_result(tmp_path):
    result = subprocess.run([sys.executable, "-m", "analysis.benchmarks.bench_ppo", "run", "--method", "sde",
                             "--steps", "8192", "--out", str(tmp_path)],
                            cwd=REPO, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    data = json.loads((tmp_path / "sde_seed0.json").read_text())
    assert data["env_steps"] == 8192 and len(data["eval_returns"]) == common.EVAL_EPISODES
    assert np.isfinite(data["eval_returns"]).all() and data["env_steps_per_s"] > 0
    assert data["final_return_mean"] == pytest.approx(np.mean(data["eval_returns"]))
    assert len(data["iteration_ends_s"]) == 1 and 0 < data["iteration_ends_s"][0] <= data["wall_s"]
    assert data["compiled"] is False and data["clipped_actions"] is True
    assert "sde seed 0: final return" in result.stdout


@pytest.mark.parametrize("argv, message", [
    (["speed", "sde", "--rollouts", "1"], "--rollouts must be at least 2"),
    (["run", "--method", "sb3", "--compile"], "apply to the TorchRL methods"),
    (["run", "--method", "sb3_gauss", "--unclipped-actions"], "apply to the TorchRL methods"),
    (["speed", "sde+fast"], "invalid choice"),
    (["speed", "sb3", "job", "--repeats", "0"], "--repeats must be at least 1"),
])
def test_bad_command_lines_are_refused_by_name(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("method", ["plain", "sb3", "sb3_gauss"])
def test_a_short_run_of_the_other_methods(tmp_path, method):
    train.run(method, 1, 8192, tmp_path)
    data = json.loads((tmp_path / f"{method}_seed1.json").read_text())
    assert data["env_steps"] == 8192 and np.isfinite(data["eval_returns"]).all()


def _fresh_loss():
    from torchrl.objectives import ClipPPOLoss

    torch.manual_seed(0)
    policy, critic, _ = build.make_torchrl_policy("sde", 26, 6)
    return ClipPPOLoss(policy, critic, clip_epsilon=0.4, entropy_bonus=False, critic_coeff=0.5,
                       loss_critic_type="l2", normalize_advantage=True)


def _parameters_after_two_updates(minibatch, compile_update):
    from tensordict import TensorDict

    loss = _fresh_loss()
    step = train.make_update(loss, torch.optim.Adam(loss.parameters(), lr=1e-2, eps=1e-5), compile_update)
    for _ in range(2):  # the second step runs on Adam's state, with the ratio away from 1
        step(minibatch.clone())
    return TensorDict.from_module(loss).detach()


@pytest.mark.e2e  # compiles the PPO update with inductor
def test_the_compiled_update_equals_the_eager_one():
    """``run --compile`` changes how the step runs, not what it computes."""
    from tensordict import TensorDict

    torch.manual_seed(1)
    n = 64
    policy = build.make_torchrl_policy("sde", 26, 6)[0]
    batch = TensorDict({"observation": torch.randn(n, 26), "sde_noise": torch.randn(n, 6, 256),
                        "advantage": torch.randn(n, 1), "value_target": torch.randn(n, 1)}, [n])
    with torch.no_grad():
        policy(batch)  # the action and its log-prob, as collected
    minibatch = batch.select(*build.MINIBATCH_KEYS, strict=False)
    initial = TensorDict.from_module(_fresh_loss()).detach()
    eager = _parameters_after_two_updates(minibatch, compile_update=False)
    compiled = _parameters_after_two_updates(minibatch, compile_update=True)
    assert max((eager - initial).abs().max().values(True, True)) > 1e-3  # the steps moved the parameters
    for key, value in eager.items(True, True):
        torch.testing.assert_close(compiled[key], value, rtol=1e-4, atol=1e-5, msg=str(key))


def _fake_run(folder, method, seed, final, speed):
    curve = [[16_000 * (k + 1), final * k / 30] for k in range(31)]
    (folder / f"{method}_seed{seed}.json").write_text(json.dumps(
        {"method": method, "seed": seed, "env_steps": 507_904, "curve": curve, "final_return_mean": final,
         "env_steps_per_s": speed, "eval_returns": [final]}))


def test_report_gives_means_spreads_and_the_ratios_to_sb3(tmp_path):
    for seed, (sde, sb3) in enumerate([(1800, 2000), (2000, 2200), (2200, 2400)]):
        _fake_run(tmp_path, "sde", seed, sde, 600)
        _fake_run(tmp_path, "sb3", seed, sb3, 1000)
    table = report.report(tmp_path, tmp_path / "out")
    assert "| TorchRL PPO, SDE (ours) | 3 | 507,904 | 2000 ± 200 | 1800, 2000, 2200 | 600 |" in table
    assert "final return 0.91×" in table and "env steps per second 0.60× [0.60, 0.60]" in table  # equal speeds
    ratios = json.loads((tmp_path / "out" / "bench_ppo.json").read_text())["sde_over_sb3"]
    assert ratios["final"]["estimate"] == pytest.approx(2000 / 2200)
    assert ratios["final"]["low"] < ratios["final"]["estimate"] < ratios["final"]["high"]
    assert (tmp_path / "out" / "bench_ppo.png").stat().st_size > 0


def test_report_without_runs_says_what_to_run(tmp_path):
    with pytest.raises(SystemExit, match="analysis.benchmarks.bench_ppo run"):
        report.report(tmp_path, tmp_path / "out")


@pytest.mark.parametrize("variant", ["sde", "sb3"])
def test_phases_split_an_iteration_into_parts_that_fit_inside_it(monkeypatch, variant):
    """``bench_ppo phases`` on a tiny iteration (2 envs × 16 steps, one epoch): every phase is
    timed once per iteration, the parts of collection and update fit inside them, and collection
    plus GAE plus update make up the iteration."""
    pytest.importorskip("stable_baselines3")
    for key, value in {"n_envs": 2, "n_steps": 16, "n_epochs": 1, "batch_size": 8}.items():
        monkeypatch.setitem(build.ZOO, key, value)
    clip = torch.nn.utils.clip_grad_norm_
    phases = speed.iteration_phases(variant, 3)
    assert not timing.TIMER.active and torch.nn.utils.clip_grad_norm_ is clip  # nothing left switched on or patched
    parts = ["update: loss forward", "update: clip + Adam step"] + (["update: backward"] if variant == "sde" else [])
    assert {"iteration", "collect", "collect: pybullet step", "update", *parts} <= set(phases)
    assert 0 < phases["collect: pybullet step"] < phases["collect"]
    assert 0 < sum(phases[p] for p in parts) < phases["update"]
    whole = phases["collect"] + phases.get("GAE", 0.0) + phases["update"]
    assert whole == pytest.approx(phases["iteration"], rel=0.2)


def test_the_job_variant_times_train_pys_own_trainer_by_iteration_and_collection():
    """``bench_ppo speed job``: the shipped experiment's trainer (tiny sizes here), each update's
    end in wall and CPU time, each rollout's collection inside its update."""
    pytest.importorskip("pybullet_envs_gymnasium")
    tiny = ("algorithm.n_envs=2", "algorithm.n_steps=16", "algorithm.batch_size=16", "algorithm.n_epochs=1",
            "actor.hidden=[8]", "algorithm.compile=false")
    result = train.train_job(3, tiny)
    ends, cpu_ends, collect = result["iteration_ends_s"], result["iteration_cpu_ends_s"], result["collect_s"]
    assert len(ends) == len(cpu_ends) == len(collect) == 3
    assert all(np.diff(ends) > 0) and all(c > 0 for c in cpu_ends)
    assert all(0 < c < d for c, d in zip(collect[1:], np.diff(ends), strict=True))


def test_the_job_variants_phases_fit_inside_its_collection_and_iteration():
    """``bench_ppo phases job`` (tiny sizes): pybullet's step, the policy's forward and the env's
    transforms are parts of collection, and collection, GAE and update make up the iteration."""
    pytest.importorskip("pybullet_envs_gymnasium")
    tiny = ("algorithm.n_envs=2", "algorithm.n_steps=16", "algorithm.batch_size=16", "algorithm.n_epochs=1",
            "actor.hidden=[8]", "algorithm.compile=false")
    with timing.TIMER.on() as phases:
        result = train.train_job(3, tiny)
    parts = ["collect: pybullet step", "collect: policy forward", "collect: env transforms"]
    assert all(phases[p] > 0 for p in parts) and sum(phases[p] for p in parts) < phases["collect"]
    iterations = result["iteration_ends_s"][-1] - result["iteration_ends_s"][0]  # the two timed ones
    assert phases["collect"] + phases["GAE"] + phases["update"] == pytest.approx(iterations, rel=0.2)


@pytest.mark.e2e  # torch.compile of the SDE policy (inductor)
def test_the_compiled_collection_policy_acts_as_the_eager_one():
    """``+policy`` (``Collector(compile_policy=True)``) changes how the SDE policy's forward runs,
    not the action it takes with the carried noise, nor any random stream (it draws nothing)."""
    from tensordict import TensorDict

    torch.manual_seed(0)
    policy, _, sde = build.make_torchrl_policy("sde", 5, 2)
    td = TensorDict({"observation": torch.randn(4, 5), sde.noise_key: torch.randn(4, 2, sde.feature_dim)}, [4])
    with torch.no_grad():
        eager = policy(td.clone())
        state = torch.get_rng_state()
        compiled = torch.compile(policy)(td.clone())
        assert torch.equal(torch.get_rng_state(), state)
    for key in ("action", "action_log_prob"):
        torch.testing.assert_close(compiled[key], eager[key], rtol=1e-5, atol=1e-6)


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
