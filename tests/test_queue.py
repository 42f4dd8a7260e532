"""The episode queue (paper section 4.2): each update sees the last Q episodes of each run."""

from __future__ import annotations

import re

import pytest
import torch
from _helpers import build, read_rows


def test_queue_drops_the_oldest_and_adds_the_newest(tmp_path):
    trainer = build("runs=2", "updates=4", "episodes_per_update=2", "episode_queue=6", "eval_period=0")
    seen = []
    original = trainer.estimate

    def recording_update(episodes, k):
        seen.append(episodes["observation"].clone())
        return original(episodes, k)

    trainer.estimate = recording_update
    summary = trainer.train(tmp_path)
    assert [s.shape[:2] for s in seen] == [torch.Size([2, 6])] * 4
    for before, after in zip(seen, seen[1:], strict=False):
        torch.testing.assert_close(after[:, :4], before[:, 2:])  # kept, in order
        assert not torch.equal(after[:, 4:], before[:, 4:])       # two new episodes per run
    assert [int(r["episodes"]) for r in read_rows(tmp_path)][::2] == [6, 8, 10, 12]
    assert summary["env_steps"] == 12 * 15 * 2


def test_queue_must_be_a_multiple_of_the_new_episodes():
    with pytest.raises(ValueError, match="episode_queue"):
        build("episodes_per_update=4", "episode_queue=6")


@pytest.mark.e2e
def test_ballcatch_experiment_runs_end_to_end(tmp_path):
    from _helpers import run_cli, summary_without_wall

    result = run_cli("+experiment=ballcatch_paper", "runs=2", "updates=3", "episode_queue=2", "eval_period=2",
                     "env.episode_length=60", "logger=none", run_dir=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    summary = summary_without_wall(tmp_path)
    assert summary["experiment"] == "ballcatch_paper" and summary["runs"] == 2
    assert summary["env_steps"] == (2 + 2) * 60 * 2  # queue of 2, then one new episode per update
    assert summary["episode_return"] == "sum"  # the authors' learner: 60 rewards in [-3, -0.5] summed
    per_step = re.search(r"eval (-[\d.]+)  \(per step: return -[\d.]+  eval (-[\d.]+)\)", result.stderr + result.stdout)
    assert per_step and float(per_step[2]) == pytest.approx(float(per_step[1]) / 60, abs=1e-3)
    assert all(-3.0 * 60 <= r <= -0.5 * 60 for r in summary["final_eval_return"])
    evals = [r["eval_return"] for r in read_rows(tmp_path)]
    assert [bool(e) for e in evals] == [False, False, True, True, True, True]
