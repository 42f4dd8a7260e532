"""Sweeps split into shards: Hydra's joblib launcher runs shards in parallel processes, and
shards (first_run=0,2 of runs=2) reproduce one process training all runs (runs=4)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from sde_torchrl.jobs.run_dir import finished_runs

pytestmark = pytest.mark.e2e  # every test here trains sweeps as processes
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


def test_a_sweep_with_a_job_that_never_started_is_refused_until_it_runs(tmp_path):
    """A sweep stopped before its third job started leaves that job's directory empty: the
    sweep's own record (Hydra's multirun.yaml) lists the job, so the readers refuse the sweep,
    naming it; the same command then runs that job alone."""
    import shutil

    from sde_torchrl.jobs.run_dir import UnfinishedRunError

    sweep = tmp_path / "sweep"
    command = ("runs=2", "seed=0,1,2", f"hydra.sweep.dir={sweep}")
    _train(*command, multirun=True)
    finished = {job: (sweep / job / "summary.json").read_bytes() for job in "01"}
    shutil.rmtree(sweep / "2")
    (sweep / "2").mkdir()
    with pytest.raises(UnfinishedRunError, match=f"{sweep / '2'} is not a finished run: job 2 of the 3 its sweep "
                                                 r"lists \(seed=2\) never started"):
        finished_runs(sweep)
    _train(*command, multirun=True)
    assert [job.summary["seed"] for job in finished_runs(sweep)] == [0, 1, 2]
    assert {job: (sweep / job / "summary.json").read_bytes() for job in "01"} == finished


def test_a_joblib_sweep_reports_each_job_s_failure_and_exits_non_zero(tmp_path):
    """Jobs run in joblib's worker processes report back to the sweep's parent:
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
    assert not (tmp_path / ".job_reports").exists()  # the jobs' reports to the parent, removed once read


def _children(pid: int) -> list[int]:
    """The live child processes of ``pid`` (``/proc``)."""
    children = []
    for status in Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":\t", 1) for line in status.read_text().splitlines() if ":\t" in line)
        except OSError:
            continue
        if fields.get("PPid", "").strip() == str(pid):
            children.append(int(status.parent.name))
    return children


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/status").read_text().split("State:", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def test_sigterm_to_a_joblib_sweep_checkpoints_its_jobs_and_leaves_no_orphan(tmp_path):
    """SIGTERM to the parent of a real joblib sweep (two workers, three jobs)
    reaches the running jobs, which checkpoint (a job that had not started does not start; one
    that was being built checkpoints after its first update); the parent exits 143 with each
    stopped job's resume line; no worker lives on or holds a run directory; the same command
    then resumes to the uninterrupted sweep's result, byte for byte."""
    import os
    import re
    import signal
    import time

    from _helpers import own_stderr_lines, summary_without_wall, train_command

    from sde_torchrl.jobs.lock import held_by

    # 1000 updates keep a job training for seconds (120 took 0.3 s: under CI's load the second job
    # could finish between the test seeing its first metrics row and the signal reaching it)
    sweep = ("+experiment=minimize", "seed=0,1,2", "updates=1000", "runs=2", "eval_period=20", "checkpoint_period=0",
             "logger=none", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2")
    command = train_command(*sweep, run_dir=tmp_path / "sweep", multirun=True)
    log = tmp_path / "stderr.txt"
    with open(log, "w") as stderr_file:  # a file, not a pipe: the workers write to it too
        parent = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=stderr_file, text=True)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while not all(len((tmp_path / "sweep" / job / "metrics.csv").read_text().splitlines()) > 1
                      if (tmp_path / "sweep" / job / "metrics.csv").exists() else False for job in "01"):
            assert parent.poll() is None and time.monotonic() < deadline, log.read_text()[-3000:]
            time.sleep(0.05)
        workers = _children(parent.pid)
        parent.send_signal(signal.SIGTERM)
        parent.wait(timeout=120)
        deadline = time.monotonic() + 30  # loky's workers end once the parent has gone
        while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        orphans = [pid for pid in workers if _alive(pid)]
    finally:
        if parent.poll() is None:
            parent.kill()
        for pid in workers:  # whatever happens, no orphan outlives the test
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
    stderr = log.read_text()
    assert parent.returncode == 143, stderr[-3000:]
    assert not orphans, stderr[-3000:]
    lines = own_stderr_lines(stderr)
    lines = lines[lines.index(next(line for line in lines if line.startswith("interrupted by"))):]
    stopped = [job for job in "012" if (tmp_path / "sweep" / job / "checkpoint.pt").exists()
               and not (tmp_path / "sweep" / job / "summary.json").exists()]
    assert "1" in stopped and len(lines) == len(stopped), stderr[-3000:]  # job 1 was training
    for line, job in zip(lines, stopped, strict=True):
        assert re.fullmatch(f"interrupted by SIGTERM: checkpoint after update [0-9]+ in {tmp_path / 'sweep' / job}; "
                            f"run the same command with hydra.sweep.dir={tmp_path / 'sweep'} to resume", line), line
    assert all(held_by(tmp_path / "sweep" / job) is None for job in "012")
    for job in set("012") - set(stopped):  # finished before the signal, or not started
        assert (tmp_path / "sweep" / job / "summary.json").exists() or \
            not (tmp_path / "sweep" / job / "metrics.csv").exists()

    resumed = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    whole = subprocess.run(train_command(*sweep, run_dir=tmp_path / "whole", multirun=True), cwd=ROOT,
                           capture_output=True, text=True, timeout=300)
    assert whole.returncode == 0, whole.stderr[-3000:]
    for job in "012":
        assert (tmp_path / "sweep" / job / "metrics.csv").read_bytes() == \
            (tmp_path / "whole" / job / "metrics.csv").read_bytes()
        assert summary_without_wall(tmp_path / "sweep" / job) == summary_without_wall(tmp_path / "whole" / job)
