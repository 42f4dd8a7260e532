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
