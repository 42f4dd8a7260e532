"""The lines that end a multirun, one per method, comparing what their runs reached."""

from __future__ import annotations

import pytest
from _helpers import run_cli

import sde_torchrl.config.schemas.envs  # noqa: F401 - the env schemas declare their reports
from sde_torchrl.trainers.comparison import comparison_lines, job_result


def test_methods_are_the_overrides_that_differ_with_seeds_and_shards_merged():
    summaries = {"explorer=sde": {"env": "ballcatch", "final_eval_mean_reward": [-1.0, -1.05],
                                  "final_eval_return": [-500.0, -525.0],
                                  "final_eval_level": ["good catch", "catch"], "best_check_level": ["catch", "slowed"]},
                 "explorer=rex": {"env": "ballcatch", "final_eval_mean_reward": [-2.5], "final_eval_return": [-1250.0],
                                  "final_eval_level": ["dropped"], "best_check_level": ["catch"]}}
    results = [job_result(["+experiment=ballcatch", explorer, f"seed={seed}", "hydra.sweep.dir=x"], summary)
               for explorer, summary in summaries.items() for seed in (0, 1)]
    lines = comparison_lines(results)
    assert lines[0].startswith("explorer=sde: 4 runs in 2 jobs; final evaluation mean -1.025 [")
    assert "last evaluation a catch in 4 (100 % [51, 100])" in lines[0]
    assert lines[0].endswith("best policy catches on the fresh balls in 2 (50 % [15, 85])")
    assert lines[1].startswith("explorer=rex: 2 runs in 2 jobs; final evaluation mean -2.500 [-2.500, -2.500]")
    assert comparison_lines([]) == []


@pytest.mark.e2e
def test_a_multirun_ends_with_one_line_per_method(tmp_path):
    result = run_cli("+experiment=minimize", "explorer=sde,rex", "runs=3", "updates=4", "logger=none",
                     run_dir=tmp_path / "sweep", multirun=True)
    assert result.returncode == 0, result.stderr[-2000:]
    last = result.stdout.splitlines()[-2:]
    assert [line.split(":")[0] for line in last] == ["explorer=sde", "explorer=rex"]
    assert all(": 3 runs in 1 job; final evaluation mean " in line for line in last)
