"""The committed runs under ``results/`` stay final and readable: a committed run directory survives
its documented command unchanged; every committed sweep holds the jobs its record lists and every
committed run reads as finished; the analysis scripts read sweeps through the refusing reader
(a sweep with a job that never started is refused in one line); run records live under
``results/``, never under ``docs/``."""

from __future__ import annotations

import logging
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from _helpers import REPO, own_stderr_lines, run_cli

from sde_torchrl.jobs.run_dir import UnfinishedRunError, finished_runs, job_directories, read_finished_run
from sde_torchrl.jobs.sweeps import listed_jobs

COMMITTED = REPO / "results" / "ballcatch" / "runs" / "score_probe" / "sde"


def snapshot(directory: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under ``directory`` but the lock: content and modification time (ns)."""
    return {str(p.relative_to(directory)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(directory.rglob("*")) if p.is_file() and p.name != ".lock"}


@pytest.mark.e2e
def test_a_committed_run_directory_survives_its_documented_command(tmp_path):
    """A committed run directory (no checkpoint, by design), copied, and its command run on it
    (the overrides it recorded, as its page documents them): one line, exit 0, no file changed."""
    run_dir = Path(shutil.copytree(COMMITTED, tmp_path / "copy"))
    overrides = yaml.safe_load((run_dir / ".hydra" / "overrides.yaml").read_text())
    assert overrides == ["+experiment=ballcatch_reinforce", "final_episodes=0", "explorer.learn_sigma=false",
                         "seed=2000", "runs=16", "logger=none"]
    before = snapshot(run_dir)
    # its experiment has since started σ̂ at e⁻³: the documented command names the job's e⁻²
    result = run_cli(*overrides, "explorer.init_param=-2", run_dir=run_dir)
    assert result.returncode == 0, result.stderr[-2000:]
    assert own_stderr_lines(result.stderr) == []
    assert result.stdout.splitlines() == [
        f"{run_dir} holds a finished job (500 updates of 16 runs): nothing was changed; a finished job is final: to "
        "train with other settings (more updates, say), give the job another directory; to train this one again "
        "from the start, remove its directory first"]
    assert snapshot(run_dir) == before



#: A committed joblib sweep, its multirun.yaml as Hydra wrote it: explorer=sde,rex, jobs 0 and 1.
FIG5 = REPO / "results" / "ballcatch" / "runs" / "fig5"


@pytest.mark.parametrize("state", ["missing", "empty"])
def test_sweep_readers_refuse_a_job_the_sweep_lists_that_never_started(tmp_path, state, caplog):
    """A sweep stopped before a job started leaves its directory empty (or none): the sweep's
    record still lists it, and the readers name it instead of reading the sweep as complete."""
    sweep = Path(shutil.copytree(FIG5, tmp_path / "fig5"))
    shutil.rmtree(sweep / "1")
    if state == "empty":
        (sweep / "1").mkdir()
    directory = "is missing" if state == "missing" else "holds none of a job's files"
    says = re.escape(f"{sweep / '1'} is not a finished run: job 1 of the 2 its sweep lists (explorer=rex) never "
                     f"started: its directory {directory}; run the sweep's command again with hydra.sweep.dir={sweep}")
    for read in (finished_runs, job_directories):
        with pytest.raises(UnfinishedRunError, match=says):
            read(sweep)
    with pytest.raises(UnfinishedRunError, match=says):
        finished_runs(tmp_path)  # a sweep below the directory given
    with caplog.at_level(logging.WARNING, logger="sde_torchrl.jobs.run_dir"):
        assert [job.path for job in finished_runs(sweep, finished_only=True)] == [sweep / "0"]
    left_out = [record.getMessage() for record in caplog.records]
    assert len(left_out) == 1 and re.match(f"left out \\(finished_only\\): {says}", left_out[0]), left_out


@pytest.mark.e2e
def test_an_analysis_script_refuses_a_sweep_with_a_job_missing_in_one_line(tmp_path):
    sweep = Path(shutil.copytree(FIG5, tmp_path / "fig5"))
    shutil.rmtree(sweep / "1")
    result = subprocess.run([sys.executable, "-m", "analysis.paper.fig5", str(sweep), "--out", str(tmp_path / "out")],
                            cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr[-2000:]
    assert own_stderr_lines(result.stderr) == [
        f"error: {sweep / '1'} is not a finished run: job 1 of the 2 its sweep lists (explorer=rex) never started: "
        f"its directory is missing; run the sweep's command again with hydra.sweep.dir={sweep} to run it (its "
        "finished jobs are left as they are)"]
    assert not (tmp_path / "out").exists()


def test_every_analysis_script_reads_sweeps_through_the_refusing_reader():
    """``analysis.sweeps.finished_jobs`` turns a refusal into one line and exit 2; a script
    calling ``finished_runs`` itself would end in a traceback."""
    callers = [path.relative_to(REPO) for path in sorted((REPO / "analysis").rglob("*.py"))
               if "finished_runs(" in path.read_text()]
    assert callers == [Path("analysis/sweeps.py")]


def test_every_committed_sweep_holds_the_jobs_its_record_lists():
    """Committed sweeps read as before: those with a multirun.yaml hold every job it lists; those
    laid out by hand, or copied without it, are read by the job directories they hold."""
    files = subprocess.run(["git", "ls-files", "results"], cwd=REPO, capture_output=True, text=True,
                           check=True).stdout.split()
    sweeps = sorted((REPO / name).parent for name in files if name.endswith("/multirun.yaml"))
    assert len(sweeps) >= 14
    for sweep in sweeps:
        jobs = listed_jobs(sweep)
        assert jobs and {job.path for job in jobs} <= set(job_directories(sweep)), sweep
    for hand_laid in ("ballcatch/tuning", "ppo/f025", "gsde_table/f002", "ballcatch/runs/score_probe/sde"):
        assert listed_jobs(REPO / "results" / hand_laid) is None and job_directories(REPO / "results" / hand_laid)


@pytest.mark.e2e  # every committed run directory (about 80) through the strict reader
def test_every_committed_run_directory_reads_as_finished():
    files = subprocess.run(["git", "ls-files", "results"], cwd=REPO, capture_output=True, text=True,
                           check=True).stdout
    directories = sorted((REPO / name).parent for name in files.split() if name.endswith("/summary.json"))
    assert len(directories) >= 78
    for directory in directories:
        assert read_finished_run(directory).summary["updates_done"] > 0, directory


#: What marks a file as a run record (a job's own files, a re-evaluation of its policies, a
#: benchmark run's record) rather than a page, a figure or the table a script writes from records.
RUN_RECORD = re.compile(r"(^|/)(\.hydra/|summary\.json$|metrics\.csv$|job_config\.json$|train\.log$|"
                        r"final_policy\.json$|multirun\.yaml$|reevaluation_[a-z_]+\.json$|.*_seed\d+\.json$)")


def test_no_run_record_is_under_docs():
    """Run records live under ``results/``; ``docs/`` holds the pages, the figures and the tables
    the scripts write from them."""
    assert RUN_RECORD.search("results/ballcatch/runs/fig5_seed3/sde/0/.hydra/overrides.yaml")
    assert RUN_RECORD.search("results/sac/runs/mountaincar_sde_seed0.json")
    assert not RUN_RECORD.search("docs/study/ballcatch/reevaluation.json")
    files = subprocess.run(["git", "ls-files", "docs"], cwd=REPO, capture_output=True, text=True, check=True).stdout
    assert [name for name in files.split() if RUN_RECORD.search(name)] == []
