"""Each run's best policy by its periodic evaluations (``best_policy.pt``) and the final check at
a job's end: the final and the best policies on the same fresh episodes, apart from training and
from the periodic evaluations; kept through a crash and a resume."""

from __future__ import annotations

import pytest
import torch
from _helpers import build, compose_config, crash_at, read_rows
from torch import nn

import sde_torchrl.config.schemas.envs  # noqa: F401 - the env schemas declare their reports
from sde_torchrl.trainers.best import BEST_POLICY, BestPolicy
from sde_torchrl.trainers.summary import checked_lines, final_levels

BUDGET = ("runs=3", "updates=12", "episodes_per_update=4", "eval_period=3",
          "final_episodes=5")


class Stacked(nn.Module):
    """Per-run parameters ``[runs, 2]`` and a buffer shared by the runs."""

    def __init__(self, runs: int) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.zeros(runs, 2))
        self.register_buffer("shared", torch.ones(2))


def test_each_run_keeps_the_parameters_of_its_own_best_evaluation():
    module = Stacked(3)
    best = BestPolicy(module, runs=3)
    history = {0: [-3.0, -1.0, -2.0], 1: [-2.0, -1.0, -5.0], 2: [-2.5, -0.5, -1.0]}  # ties keep the earlier one
    for update, evaluation in history.items():
        with torch.no_grad():
            module.weight.fill_(float(update))
        best.observe(update, torch.tensor(evaluation))
    assert best.update.tolist() == [1, 2, 2]
    assert best.score.tolist() == [-2.0, -0.5, -1.0]
    assert best.state["weight"][:, 0].tolist() == [1.0, 2.0, 2.0]
    with best.loaded():
        assert module.weight[:, 0].tolist() == [1.0, 2.0, 2.0]
    assert module.weight[:, 0].tolist() == [2.0, 2.0, 2.0]  # the module's own state again
    restored = BestPolicy(Stacked(3), runs=3)
    restored.load_state_dict(best.state_dict())
    assert restored.update.tolist() == [1, 2, 2] and torch.equal(restored.state["weight"], best.state["weight"])


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    out = tmp_path_factory.mktemp("best") / "job"
    summary = build(*BUDGET).train(out, checkpoint_period=4)
    return out, summary


def test_the_best_policy_is_the_best_periodic_evaluation_of_each_run(job):
    out, summary = job
    rows = [row for row in read_rows(out) if row["eval_return"]]
    for run in range(3):
        evals = [(float(row["eval_return"]), int(row["update"])) for row in rows if int(row["run"]) == run]
        value, update = max(evals, key=lambda pair: (pair[0], -pair[1]))
        assert summary["best_update"][run] == update
        assert summary["best_eval_return"][run] == pytest.approx(value, rel=1e-6)
    saved = torch.load(out / BEST_POLICY, weights_only=True)
    assert saved["update"] == summary["best_update"]
    trainer = build(*BUDGET)
    trainer.policy.load_state_dict(saved["state_dict"])  # loads into the job's policy as it is built
    last = max(int(row["update"]) for row in rows)
    for run in range(3):
        final = torch.tensor(summary["final_parameters"][next(iter(summary["final_parameters"]))][run])
        kept = saved["state_dict"][next(iter(summary["final_parameters"]))][run].reshape(-1)
        assert torch.equal(kept, final) == (summary["best_update"][run] == last)


def test_the_final_check_runs_both_policies_on_the_same_fresh_episodes(job):
    _, summary = job
    assert summary["check_episodes"] == 5
    last = summary["updates_done"] - 1
    for run in range(3):
        same_policy = summary["best_update"][run] == last
        assert (summary["best_check_return"][run] == summary["final_check_return"][run]) == same_policy
        # fresh episodes: not the final evaluation's (the toy task's state noise differs between them)
        assert summary["final_check_return"][run] != summary["final_eval_return"][run]


def test_best_and_checked_policies_survive_a_crash_and_a_resume(job, tmp_path):
    _, reference = job
    crashed = build(*BUDGET)
    crash_at(crashed, 10)
    with pytest.raises(RuntimeError, match="crash at 10"):
        crashed.train(tmp_path / "resumed", checkpoint_period=4)
    resumed = build(*BUDGET).train(tmp_path / "resumed", checkpoint_period=4)
    reference, resumed = dict(reference), dict(resumed)
    reference.pop("wall_s"), resumed.pop("wall_s")
    assert resumed == reference
    ours = torch.load(tmp_path / "resumed" / BEST_POLICY, weights_only=True)
    theirs = torch.load(job[0] / BEST_POLICY, weights_only=True)
    assert ours["update"] == theirs["update"]
    assert all(torch.equal(ours["state_dict"][k], theirs["state_dict"][k]) for k in theirs["state_dict"])


def test_ball_catching_lines_say_what_each_run_reached_and_what_its_policies_did():
    summary = {"env": "ballcatch", "first_run": 4, "episode_return": "sum", "settings": {"episode_length": 500},
               "final_eval_return": [-750.0, -1000.0], "final_return": [-800.0, -1200.0],
               "best_update": [379, 99], "best_eval_return": [-470.0, -800.0], "check_episodes": 20,
               "best_check_return": [-510.0, -900.0], "final_check_return": [-745.0, -1100.0]}
    summary.update(final_levels(summary))
    summary["level_first_update"] = [{"good catch": 379, "catch": 259, "on the hand": 19, "slowed": 19},
                                     {"good catch": None, "catch": None, "on the hand": 99, "slowed": 19}]
    lines = checked_lines(summary)
    assert lines[0].startswith("run 4: reached a good catch at update 379 (a catch at 259); best policy (update "
                               "379, evaluated -0.940) on 20 fresh balls: -1.020, a catch; final policy: -1.490, "
                               "on the hand")
    assert lines[1].startswith("run 5: reached on the hand at update 99; best policy (update 99, evaluated -1.600) "
                               "on 20 fresh balls: -1.800, slowed")
    assert lines[2] == ("of 2 runs, on 20 fresh balls each: the best policy catches in 1, the final policy in 0; "
                        "a catch was reached in training by 1")


@pytest.mark.parametrize("algorithm", ["ppo", "sac"])
def test_actor_critic_jobs_keep_and_check_their_best_policy(tmp_path, algorithm):
    """PPO (with its observation statistics) and SAC keep the best policy by evaluation and run it
    with the final one on the same fresh episodes; a policy evaluated again on them is the same."""
    from test_ppo_job import TINY as PPO
    from test_sac_job import TINY as SAC

    from sde_torchrl.config.build import run_job
    from sde_torchrl.config.schemas.train import validate

    overrides = [*(PPO if algorithm == "ppo" else SAC), "updates=4", "eval_period=1", "final_episodes=3",
                 "logger=none"]
    summary = run_job(validate(compose_config(*overrides)), str(tmp_path), {"algorithm": algorithm})
    saved = torch.load(tmp_path / BEST_POLICY, weights_only=True)
    assert saved["update"] == summary["best_update"] and 0 <= saved["update"][0] <= 3
    assert all(name.startswith(("policy.", "normalizer.")) for name in saved["state_dict"])
    assert (algorithm == "ppo") == any(name.startswith("normalizer.") for name in saved["state_dict"])
    assert summary["check_episodes"] == 3
    same = summary["best_update"][0] == 3
    assert (summary["best_check_return"] == summary["final_check_return"]) == same
