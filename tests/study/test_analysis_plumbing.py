"""What the analysis scripts share: the run-directory reader beside its writer
(``sde_torchrl.jobs.run_dir``), the job runner (``analysis/runner.py``) and the figure helpers
(``analysis/figures.py``)."""

from __future__ import annotations

import csv
import shutil
import time

import pytest
from _helpers import REPO

from analysis import figures, runner
from analysis.benchmarks import common, time_split
from analysis.benchmarks.bench_ppo import speed as ppo_speed
from analysis.benchmarks.bench_ppo import timing as ppo_timing
from analysis.benchmarks.gsde_table import cells as gsde_cells
from analysis.benchmarks.gsde_table import report as gsde_report
from analysis.paper import ballcatch_scores, fig5
from analysis.selection import ballcatch_tuning
from sde_torchrl.jobs.run_dir import MetricRow, finished_runs, read_finished_run, read_metrics

RUNS = REPO / "results" / "ballcatch" / "runs"


def _plain_rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("job", [RUNS / "fig5" / "0", RUNS / "selected" / "seed0"])
def test_metrics_are_read_typed_with_what_is_not_recorded_as_none(job):
    """A file from before the exploration state was recorded (fig5/0) and one with it (seed0)."""
    plain, rows = _plain_rows(job / "metrics.csv"), read_metrics(job / "metrics.csv")
    assert len(rows) == len(plain) > 0 and all(isinstance(row, MetricRow) for row in rows)
    for want, row in zip(plain, rows, strict=True):
        assert (row.run, row.update, row.episodes) == (int(want["run"]), int(want["update"]), int(want["episodes"]))
        assert row.return_mean == float(want["return_mean"])
        for name in ("eval_return", "grad_norm", "sigma_min", "sigma_max", "weight_max"):
            assert getattr(row, name) == (float(want[name]) if want.get(name) else None), name
    assert any(row.eval_return is None for row in rows) and any(row.eval_return is not None for row in rows)
    assert all((row.sigma_min is None) == ("sigma_min" not in plain[0]) for row in rows)


def test_a_finished_run_gives_its_columns_per_run_in_update_order():
    job = read_finished_run(RUNS / "fig5" / "0")
    summary = job.summary
    evals, returns = job.series("eval_return"), job.values("return_mean")
    assert sorted(evals) == sorted(returns) == list(range(summary["first_run"], summary["first_run"] + summary["runs"]))
    for run, points in evals.items():
        updates = [update for update, _ in points]
        assert updates == sorted(updates) and len(returns[run]) == summary["updates_done"]
        assert points[-1][1] == summary["final_eval_return"][run - summary["first_run"]]
    assert job.series("sigma_min") == {}  # not recorded by this job
    assert job.config is summary["config"] and job.config["runs"] == summary["runs"]


def test_finished_runs_of_several_directories_follow_their_order():
    shards = [RUNS / "fig6" / "shard50_1", RUNS / "fig6" / "shard50_0"]
    assert [job.path for job in finished_runs(*shards)] == shards
    assert [job.path for job in finished_runs(RUNS / "fig6")] == sorted(p.parent for p in
                                                                       (RUNS / "fig6").rglob("metrics.csv"))


# ----------------------------------------------------------------------------------- the runner

TINY = ("+experiment=minimize", "runs=2", "updates=3", "episodes_per_update=2", "logger=none")


@pytest.mark.e2e  # training jobs in the runner's worker process, checked by what they leave behind
def test_the_runner_skips_finished_jobs_runs_the_others_and_reports_failures_by_name(tmp_path):
    finished = tmp_path / "finished"
    shutil.copytree(REPO / "results" / "ballcatch" / "tuning" / "reinforce_sde" / "C1", finished)
    before = {p.name: p.read_bytes() for p in finished.iterdir() if p.is_file()}
    jobs = [runner.TrainJob("finished", ("+experiment=minimize",), finished),
            runner.TrainJob("fresh", TINY, tmp_path / "fresh", cost=1),
            runner.TrainJob("bad", ("+experiment=minimize", "runs=0"), tmp_path / "bad", cost=2)]
    failures = runner.run_train_jobs(jobs, workers=1)
    assert [(f.job.name, "runs=0" in f.message) for f in failures] == [("bad", True)]
    assert {p.name: p.read_bytes() for p in finished.iterdir() if p.is_file()} == before  # skipped, untouched
    assert read_finished_run(tmp_path / "fresh").summary["updates_done"] == 3
    assert (tmp_path / "fresh" / "checkpoint.pt").exists()
    summary = (tmp_path / "fresh" / "summary.json").read_bytes()
    assert runner.run_train_jobs(jobs[:2], workers=1, keep_checkpoints=False) == []  # both finished now: skipped
    assert (tmp_path / "fresh" / "summary.json").read_bytes() == summary
    assert (tmp_path / "fresh" / "checkpoint.pt").exists()  # not run again: left as it was


@pytest.mark.e2e  # a training job in the runner's worker process, interrupted and resumed
def test_the_runner_resumes_an_unfinished_job(tmp_path):
    job = runner.TrainJob("job", TINY, tmp_path / "job")
    assert runner.run_train_jobs([job], workers=1) == []
    reference = (tmp_path / "job" / "metrics.csv").read_bytes()
    (tmp_path / "job" / "summary.json").unlink()  # as if interrupted after its last checkpoint
    assert not runner.is_finished(job.run_dir)
    assert runner.run_train_jobs([job], workers=1, keep_checkpoints=False) == []
    assert runner.is_finished(job.run_dir) and (tmp_path / "job" / "metrics.csv").read_bytes() == reference
    assert not list((tmp_path / "job").glob("checkpoint*.pt"))


def test_a_train_py_job_that_fails_is_reported_with_train_py_s_error_line(tmp_path):
    job = runner.TrainJob("bad", ("+experiment=minimize", "runs=0"), tmp_path / "bad")
    (failure,) = runner.run_train_jobs([job], workers=1, command=True)
    assert failure.job == job and failure.message.startswith("exit 2: runs=0")


def _slow_square(x: int) -> int:
    time.sleep(0.05)
    return x * x


def test_the_pool_stops_at_the_first_result_asked_for():
    with runner.JobPool(1) as pool:
        everything = pool.run(_slow_square, {x: (x,) for x in range(4)})
        stopped = pool.run(_slow_square, {x: (x,) for x in range(8)}, stop=lambda result: result == 0)
    assert everything == {0: 0, 1: 1, 2: 4, 3: 9}
    assert next(iter(stopped)) == 0 and len(stopped) < 8  # the tasks not started were cancelled


def test_figure_helpers():
    import numpy as np

    assert figures.style("SDE + GPOMDP") == figures.style("sde_gpomdp") == figures.STYLES["sde+gpomdp"]
    assert figures.style("sb3") == {}
    a, b = np.array([[2.0, 4.0]]), np.array([[1.0, 1.0]])
    assert figures.ratio_of_means(a, b).tolist() == [3.0] and figures.difference_of_means(a, b).tolist() == [2.0]
    assert figures.bounds((1.0, 0.5, 2.0)) == [0.5, 2.0]


@pytest.mark.parametrize("module", [
    runner, figures, ballcatch_tuning, fig5, ballcatch_scores, common, ppo_speed, ppo_timing, gsde_cells, gsde_report,
    time_split,
], ids=lambda module: module.__name__)
def test_docstring_examples_of_the_analysis_modules_run(module):
    import doctest

    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0
