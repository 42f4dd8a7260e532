"""Sweeps split into shards: Hydra's joblib launcher runs shards in parallel processes, and
shards (first_run=0,2 of runs=2) reproduce one process training all runs (runs=4)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from sde_torchrl.jobs.run_dir import finished_runs

ROOT = Path(__file__).resolve().parents[1]
COMMON = ["+experiment=minimize", "updates=6", "logger=none", "eval_period=3"]


def _metrics(directory: Path) -> dict[tuple[int, int], tuple[float, float | None]]:
    return {(row.run, row.update): (row.return_mean, row.eval_return)
            for job in finished_runs(directory) for row in job.rows}


def _train(*overrides: str, multirun: bool = False) -> None:
    flags = ["-m"] if multirun else []
    result = subprocess.run([sys.executable, "train.py", *flags, *COMMON, *overrides], cwd=ROOT,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]


def test_joblib_shards_equal_one_process(tmp_path):
    _train("runs=4", f"hydra.run.dir={tmp_path / 'one'}")
    _train("runs=2", "first_run=0,2", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
           f"hydra.sweep.dir={tmp_path / 'shards'}", multirun=True)
    one, shards = _metrics(tmp_path / "one"), _metrics(tmp_path / "shards")
    assert len(one) == 4 * 6 and len(list((tmp_path / "shards").rglob("summary.json"))) == 2
    assert shards == one  # bitwise the same numbers


def test_a_joblib_sweep_reports_each_job_s_failure_and_exits_non_zero(tmp_path):
    """Jobs run in joblib's worker processes report back to the sweep's parent (issue 38 item 4):
    a non-finite job (exit 1), a job whose directory is in use (exit 3), a finished job (its line)."""
    from _helpers import own_stderr_lines, run_cli

    from sde_torchrl.jobs.lock import hold_run_directory

    common = ("+experiment=minimize", "updates=2", "runs=2", "logger=none")
    assert run_cli(*common, "lr=0.002", run_dir=tmp_path / "1").returncode == 0  # the sweep's job 1, finished
    with hold_run_directory(tmp_path / "2"):
        result = run_cli(*common, "lr=1e38,0.002,0.003", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
                         run_dir=tmp_path, multirun=True)
    assert result.returncode == 1, result.stderr[-2000:]  # the failures' codes differ (1 and 3)
    errors = [line for line in own_stderr_lines(result.stderr) if line.startswith("error:")]
    assert len(errors) == 2, result.stderr[-3000:]
    assert errors[0].startswith("error: NonFiniteError: non-finite parameter") and "(job " in errors[0]
    assert "lr=1e+38, see " in errors[0] and errors[0].endswith("/0/error.txt)")
    assert errors[1].startswith(f"error: {tmp_path / '2'} is in use by another process (pid ")
    assert errors[1].endswith("lr=0.003)")
    assert f"{tmp_path / '1'} holds a finished job (2 updates of 2 runs): nothing was changed" in result.stdout
