"""Nothing lost, nothing silently wrong: the run-directory lock, damaged files, the
evaluation guard, strict summaries, logger CSV files, configurations that cannot learn, writes
that fail (a full disk, the file-size limit) and run directories that cannot be made."""

from __future__ import annotations

import errno
import json
import logging
import os
import random
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from _helpers import (
    REPO,
    Crash,
    build,
    compose_config,
    crash_at,
    own_stderr_lines,
    read_rows,
    run_cli,
    summary_without_wall,
    train_command,
)

from sde_torchrl.config.build import build_trainer
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.jobs.checkpoint import content_digest, load_checkpoint
from sde_torchrl.jobs.lock import RunDirectoryInUse, hold_run_directory
from sde_torchrl.jobs.run_dir import RunDirectory, read_summary
from sde_torchrl.trainers.guard import NonFiniteError
from sde_torchrl.utils.checks import ArgumentError
from sde_torchrl.utils.files import DamagedFileError

BUDGET = ("runs=2", "updates=12", "episodes_per_update=4", "eval_period=5")


def snapshot(directory: Path, skip: tuple[str, ...] = ()) -> dict[str, tuple[bytes, int]]:
    """Every file under ``directory`` but ``skip``: content and modification time (ns)."""
    return {str(p.relative_to(directory)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(directory.rglob("*")) if p.is_file() and p.name not in skip}


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted job of :data:`BUDGET` (checkpoint every 4 updates)."""
    out = tmp_path_factory.mktemp("reference")
    build(*BUDGET).train(out, checkpoint_period=4)
    return out


@pytest.fixture(scope="module")
def crashed_once(tmp_path_factory) -> Path:
    """The job of :data:`BUDGET` killed at update 10 (checkpoint after update 8), trained once for the module."""
    out = tmp_path_factory.mktemp("crashed")
    trainer = build(*BUDGET)
    crash_at(trainer, 10)
    with pytest.raises(Crash):
        trainer.train(out, checkpoint_period=4)
    return out


@pytest.fixture
def crashed(crashed_once, tmp_path) -> Path:
    """A copy of :func:`crashed_once` to damage or resume."""
    return Path(shutil.copytree(crashed_once, tmp_path / "crashed"))


# --------------------------------------------------------------------------- run-directory lock


def test_lock_is_held_for_the_job_and_nested_in_one_process(tmp_path):
    with hold_run_directory(tmp_path):
        assert (tmp_path / ".lock").read_text() == f"{os.getpid()}\n"
        with hold_run_directory(tmp_path):  # train.py around Trainer.train: one lock
            pass
        build("updates=2").train(tmp_path)  # the trainer's own hold nests too
        assert (tmp_path / ".lock").read_text() == f"{os.getpid()}\n"
    assert (tmp_path / ".lock").read_text() == ""  # released: no pid left


HOLD = "import sys, time; from sde_torchrl.jobs.lock import hold_run_directory\n" \
       "with hold_run_directory(sys.argv[1]):\n    print('held', flush=True); time.sleep(120)\n"


def start_holder(directory: Path) -> subprocess.Popen:
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(directory)], cwd=REPO, stdout=subprocess.PIPE,
                              text=True)
    assert holder.stdout.readline().strip() == "held"
    return holder


@pytest.mark.e2e
def test_in_use_directory_is_refused_without_changing_anything(tmp_path):
    cli = ("+experiment=minimize", "runs=2", "updates=4")
    assert run_cli(*cli, run_dir=tmp_path).returncode == 0
    holder = start_holder(tmp_path)  # it writes its pid into .lock
    before = snapshot(tmp_path)
    try:
        with pytest.raises(RunDirectoryInUse, match=rf"pid {holder.pid}"):
            build("runs=2", "updates=4").train(tmp_path)
        started = time.monotonic()
        refused = run_cli(*cli, run_dir=tmp_path)
        took = time.monotonic() - started
    finally:
        holder.kill()
        holder.wait()
    assert refused.returncode == 3, refused.stderr[-2000:]
    assert own_stderr_lines(refused.stderr) == [
        f"error: {tmp_path} is in use by another process (pid {holder.pid}): it was left unchanged; wait for "
        "that process to end, or give this job another run directory"]
    assert took < 5
    assert snapshot(tmp_path) == before  # not one byte, not one modification time
    # kill -9 left no stale lock: the next run goes ahead.
    assert run_cli(*cli, run_dir=tmp_path).returncode == 0


@pytest.mark.e2e
def test_sweep_job_in_use_is_refused_and_the_others_run(tmp_path):
    holder = start_holder(tmp_path / "0")
    try:
        result = run_cli("+experiment=minimize", "updates=3", "runs=1", "logger=none", "seed=0,1",
                         run_dir=tmp_path, multirun=True)
    finally:
        holder.kill()
        holder.wait()
    assert result.returncode == 3, result.stderr[-2000:]
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and "is in use by another process" in lines[0] and lines[0].endswith(" seed=0)"), lines
    assert sorted(p.name for p in (tmp_path / "0").iterdir()) == [".lock"]
    assert json.loads((tmp_path / "1" / "summary.json").read_text())["seed"] == 1


def without_timestamps(path: Path, run_dir: Path) -> list[str]:
    """A log or YAML file's lines without time stamps and speeds, the run directory neutral."""
    return [re.sub(r"\d+ env steps/s", "", line.split(" - ", 1)[-1]).replace(str(run_dir), "RUN")
            for line in path.read_text().splitlines()]


def checkpoint_without_wall(path: Path) -> str:
    """A checkpoint's digest without the wall time and NumPy's and Python's global generators
    (a job does not seed them: they differ between any two processes)."""
    state = load_checkpoint(path)
    assert isinstance(state["loop"].pop("wall_s"), float)
    del state["random"]["numpy"], state["random"]["python"]
    return content_digest(state)


@pytest.mark.e2e
def test_two_commands_on_one_run_directory(tmp_path):
    cli = ("+experiment=minimize", "runs=2", "updates=400", "checkpoint_period=50")
    run_dir = tmp_path / "both"
    commands = [subprocess.Popen(train_command(*cli, run_dir=run_dir), cwd=REPO, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True) for _ in range(2)]
    started = time.monotonic()
    ended = {}
    while len(ended) < 2:
        for i, proc in enumerate(commands):
            if i not in ended and proc.poll() is not None:
                ended[i] = time.monotonic() - started
        time.sleep(0.02)
    results = [(proc.returncode, *proc.communicate()) for proc in commands]
    assert sorted(code for code, _, _ in results) == [0, 3], [r[2][-2000:] for r in results]
    loser = next(i for i, (code, _, _) in enumerate(results) if code == 3)
    assert ended[loser] < 5
    lines = own_stderr_lines(results[loser][2])
    assert len(lines) == 1 and lines[0].startswith(f"error: {run_dir} is in use by another process (pid "), lines

    single = tmp_path / "single"
    assert run_cli(*cli, run_dir=single).returncode == 0
    files = sorted(str(p.relative_to(single)) for p in single.rglob("*") if p.is_file())
    assert sorted(str(p.relative_to(run_dir)) for p in run_dir.rglob("*") if p.is_file()) == files
    for name in files:
        if name in ("train.log", ".hydra/hydra.yaml"):
            assert without_timestamps(run_dir / name, run_dir) == without_timestamps(single / name, single), name
        elif name == "summary.json":
            assert summary_without_wall(run_dir) == summary_without_wall(single)
        elif name.startswith("checkpoint"):  # the same content but the wall time
            assert checkpoint_without_wall(run_dir / name) == checkpoint_without_wall(single / name), name
        else:
            assert (run_dir / name).read_bytes() == (single / name).read_bytes(), name


# --------------------------------------------------------------------------- damaged checkpoint


def damaged_variants(data: bytes, seed: int = 0) -> dict[str, bytes]:
    """Truncated, random bytes at a few offsets, garbage, empty."""
    rng = random.Random(seed)
    variants = {"truncated": data[: len(data) // 2], "garbage": rng.randbytes(4096), "empty": b""}
    for i in range(12):
        damaged = bytearray(data)
        for offset in rng.sample(range(len(data) - 8), 3):
            damaged[offset:offset + 8] = rng.randbytes(8)
        variants[f"random bytes {i}"] = bytes(damaged)
    return variants


def test_damaged_checkpoint_never_loads_other_content(crashed):
    path = crashed / "checkpoint.pt"
    data = path.read_bytes()
    original = content_digest(load_checkpoint(path))
    detected = 0
    for name, damaged in damaged_variants(data).items():
        path.write_bytes(damaged)
        try:
            state = load_checkpoint(path)
        except DamagedFileError as error:
            detected += 1
            assert str(error).startswith(f"{path} is damaged: "), name
            assert "delete checkpoint.pt" in str(error), name
        else:  # the damage missed the content (zip padding): exactly what was saved
            assert content_digest(state) == original, name
    assert detected >= 12


@pytest.mark.parametrize("kind", ["truncated", "garbage", "empty", "random bytes 0", "random bytes 1"])
def test_resume_refuses_a_damaged_checkpoint_and_changes_nothing(crashed, reference, kind):
    path = crashed / "checkpoint.pt"
    original = path.read_bytes()
    path.write_bytes(damaged_variants(original)[kind])
    before = snapshot(crashed, skip=(".lock",))  # the job's own lock: written to hold the directory
    try:
        build(*BUDGET).train(crashed, checkpoint_period=4)
    except DamagedFileError as error:
        assert error.path == path
        assert snapshot(crashed, skip=(".lock",)) == before
    else:  # damage outside the content: the run is the uninterrupted one
        assert (crashed / "metrics.csv").read_bytes() == (reference / "metrics.csv").read_bytes()


def test_damaged_checkpoint_points_to_the_previous_one(crashed, reference):
    path, previous = crashed / "checkpoint.pt", crashed / "checkpoint.prev.pt"
    assert load_checkpoint(previous)["updates"] == 4  # the one before the checkpoint after update 8
    path.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(DamagedFileError) as info:
        build(*BUDGET).train(crashed, checkpoint_period=4)
    assert str(info.value) == (
        f"{path} is damaged: it cannot be read (RuntimeError: PytorchStreamReader failed reading zip archive: "
        f"failed finding central directory); nothing was resumed from it; checkpoint.prev.pt (after update 4) is "
        f"intact: replace checkpoint.pt with it (mv {previous} {path}) to resume from there")
    previous.replace(path)  # the remedy: updates 4 to 9 are done again, identically
    resumed = build(*BUDGET).train(crashed, checkpoint_period=4)
    assert (crashed / "metrics.csv").read_bytes() == (reference / "metrics.csv").read_bytes()
    assert resumed["final_parameters"] == json.loads((reference / "summary.json").read_text())["final_parameters"]
    (crashed / "checkpoint.pt").unlink()  # a finished job without its checkpoint is still final
    assert build("updates=1").train(crashed) == resumed and previous.exists()
    (crashed / "summary.json").unlink()  # no longer finished: a new job removes the previous one's checkpoints
    build("updates=1").train(crashed)
    assert not previous.exists()


@pytest.mark.e2e
def test_damaged_checkpoint_on_the_command_line(tmp_path):
    cli = ("+experiment=minimize", "runs=2", "updates=3", "logger=none")
    assert run_cli(*cli, run_dir=tmp_path).returncode == 0
    (tmp_path / "summary.json").unlink()  # as a kill before the summary leaves it: the checkpoint is resumed from
    path = tmp_path / "checkpoint.pt"
    path.write_bytes(path.read_bytes()[:1000])
    result = run_cli(*cli, run_dir=tmp_path)
    assert result.returncode == 4, result.stderr[-2000:]
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith(f"error: {path} is damaged: it cannot be read ("), lines


# --------------------------------------------------------------------------- metrics.csv


@pytest.mark.e2e
def test_finished_job_rerun_detects_a_truncated_last_row(tmp_path):
    cli = ("+experiment=minimize", "runs=2", "updates=5", "logger=none")
    assert run_cli(*cli, run_dir=tmp_path).returncode == 0
    metrics = tmp_path / "metrics.csv"
    complete = metrics.read_bytes()
    metrics.write_bytes(complete[:-7])
    result = run_cli(*cli, run_dir=tmp_path)
    assert result.returncode == 4, result.stderr[-2000:]
    lines = own_stderr_lines(result.stderr)
    assert lines == [f"error: {metrics} is damaged: row 10 (run 1, update 4) is cut short; delete it and run the "
                     "job again: its 10 rows (every update up to the checkpoint) are rebuilt from checkpoint.pt, "
                     "nothing is lost"]
    assert metrics.read_bytes() == complete[:-7]  # left as it was
    metrics.unlink()  # the remedy
    assert run_cli(*cli, run_dir=tmp_path).returncode == 0
    assert metrics.read_bytes() == complete


@pytest.mark.parametrize("damage", ["short", "changed row", "extra lines"])
def test_metrics_that_disagree_with_the_checkpoint_are_refused(tmp_path, damage):
    build("updates=4").train(tmp_path)
    metrics = tmp_path / "metrics.csv"
    lines = metrics.read_bytes().splitlines(keepends=True)
    edited = {"short": lines[:-2], "changed row": [*lines[:2], lines[2].replace(b",", b",9", 1), *lines[3:]],
              "extra lines": [*lines, lines[-1]]}[damage]
    metrics.write_bytes(b"".join(edited))
    with pytest.raises(DamagedFileError, match="rebuilt from checkpoint.pt, nothing is lost"):
        build("updates=4").train(tmp_path)
    assert metrics.read_bytes() == b"".join(edited)


def test_short_metrics_on_resume_costs_no_progress(crashed, reference):
    metrics = crashed / "metrics.csv"
    metrics.write_bytes(b"".join(metrics.read_bytes().splitlines(keepends=True)[:7]))  # 6 of 16 rows
    with pytest.raises(DamagedFileError, match=r"holds 6 of the 16 rows checkpoint.pt recorded"):
        build(*BUDGET).train(crashed, checkpoint_period=4)
    metrics.unlink()  # the remedy: rebuilt from the checkpoint, then the job goes on
    resumed = build(*BUDGET).train(crashed, checkpoint_period=4)
    assert metrics.read_bytes() == (reference / "metrics.csv").read_bytes()
    assert resumed["final_parameters"] == json.loads((reference / "summary.json").read_text())["final_parameters"]


@pytest.mark.e2e
def test_short_metrics_is_not_a_config_error_on_the_command_line(tmp_path):
    cli = ("+experiment=minimize", "runs=2", "updates=3", "logger=none")
    assert run_cli(*cli, run_dir=tmp_path).returncode == 0
    (tmp_path / "metrics.csv").write_text("run,update\n")
    result = run_cli(*cli, run_dir=tmp_path)
    assert result.returncode == 4, result.stderr[-2000:]
    assert "is damaged: its header is not run,update,episodes" in result.stderr


# --------------------------------------------------------------------------- summary.json


def test_damaged_summary_is_named_and_rewritten_by_a_rerun(tmp_path):
    build("updates=3").train(tmp_path)
    good = json.loads((tmp_path / "summary.json").read_text())
    for damaged in (b"", b'{"runs": 1, "final_ret', bytes(range(256))):
        (tmp_path / "summary.json").write_bytes(damaged)
        with pytest.raises(DamagedFileError, match=r"summary.json is damaged: .*run the job's command again"):
            read_summary(tmp_path / "summary.json")
    again = build("updates=3").train(tmp_path)  # a finished job rewrites it from the checkpoint
    assert read_summary(tmp_path / "summary.json")["final_parameters"] == good["final_parameters"] \
        == again["final_parameters"]


def test_summary_with_a_non_finite_value_is_not_written(tmp_path):
    run_dir = RunDirectory(tmp_path)
    with pytest.raises(ValueError, match=r"not written: final_return\[1\] = nan is not a finite number"):
        run_dir.write_summary({"runs": 2, "final_return": [0.5, float("nan")]})
    assert not list(tmp_path.iterdir())


# --------------------------------------------------------------------------- evaluation guard


def test_non_finite_evaluation_names_update_and_runs(tmp_path):
    trainer = build("runs=3", "updates=4", "eval_period=2", "first_run=5")
    evaluate = trainer.evaluate
    trainer.evaluate = lambda: evaluate() * torch.tensor([1.0, float("inf"), 1.0])
    with pytest.raises(NonFiniteError) as info:
        trainer.train(tmp_path)
    assert (info.value.update, info.value.what, info.value.runs) == (1, "evaluation return", [6])
    assert [int(r["update"]) for r in read_rows(tmp_path)] == [0, 0, 0]  # the update before it
    assert not (tmp_path / "summary.json").exists()


@pytest.mark.e2e
def test_divergence_at_the_last_update_fails_by_name(tmp_path):
    result = run_cli("+experiment=minimize", "updates=1", "lr=1e6", "logger=none", run_dir=tmp_path)
    assert result.returncode == 1, result.stderr[-2000:]
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith("error: NonFiniteError: non-finite evaluation return at update 0"), \
        lines
    assert not (tmp_path / "summary.json").exists()
    assert read_rows(tmp_path) == []


# --------------------------------------------------------------------------- TorchRL CSV logger


def csv_logged(out_dir: Path):
    """A trainer of :data:`BUDGET` whose TorchRL CSV logger writes under ``out_dir``."""
    return build_trainer(compose_config("+experiment=minimize", "logger=csv", *BUDGET), str(out_dir))


@pytest.mark.parametrize("checkpoint_period", [0, 4])  # killed before the first checkpoint, after one
def test_logger_csv_has_no_duplicate_rows_after_a_kill(tmp_path, checkpoint_period):
    csv_logged(tmp_path / "ref").train(tmp_path / "ref", checkpoint_period=checkpoint_period)
    trainer = csv_logged(tmp_path / "run")
    crash_at(trainer, 6)
    with pytest.raises(Crash):
        trainer.train(tmp_path / "run", checkpoint_period=checkpoint_period)
    csv_logged(tmp_path / "run").train(tmp_path / "run", checkpoint_period=checkpoint_period)
    scalars = sorted((tmp_path / "ref").glob("*/scalars/*.csv"))
    assert len(scalars) == 2
    for ref in scalars:
        resumed = tmp_path / "run" / ref.relative_to(tmp_path / "ref")
        assert resumed.read_bytes() == ref.read_bytes(), ref.name


# --------------------------------------------------------------------------- cannot learn


def test_reinforce_on_a_single_episode_is_refused():
    with pytest.raises(ArgumentError, match=r"^episodes_per_update=1: at least 2 with estimator=reinforce"):
        validate(compose_config("+experiment=minimize", "episodes_per_update=1"))
    validate(compose_config("+experiment=minimize", "episodes_per_update=1", "episode_queue=4"))
    validate(compose_config("+experiment=minimize", "episodes_per_update=1", "estimator=enac"))


def test_rank_deficient_enac_warns(caplog):
    with caplog.at_level(logging.WARNING, logger="sde_torchrl.config.build"):
        build("estimator=enac", "episodes_per_update=2").close()
    assert "rank-deficient" in caplog.text and "for 3 unknowns" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="sde_torchrl.config.build"):
        build("estimator=enac", "episodes_per_update=3").close()
    assert "rank-deficient" not in caplog.text


@pytest.mark.e2e
def test_kill_during_a_run_leaves_no_stale_lock(tmp_path):
    proc = subprocess.Popen(train_command("+experiment=minimize", "runs=2", "updates=2000", "logger=none",
                                          run_dir=tmp_path), cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not (tmp_path / "metrics.csv").exists() or len((tmp_path / "metrics.csv").read_bytes()) < 200:
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert (tmp_path / ".lock").read_text().strip() == str(proc.pid)  # the pid stays, the lock does not
    with hold_run_directory(tmp_path):
        pass


FORKING_HOLD = "import os, sys, time; from sde_torchrl.jobs.lock import hold_run_directory\n" \
               "with hold_run_directory(sys.argv[1]):\n" \
               "    if os.fork() == 0:  # the child, past fork's handlers\n" \
               "        print(os.getpid(), flush=True); time.sleep(120); os._exit(0)\n" \
               "    time.sleep(120)\n"


def test_a_forked_child_does_not_keep_a_dead_holders_lock(tmp_path):
    """A worker forked by the job (multiprocessing's "fork") outlives the job's kill -9: the
    directory must not stay locked in the dead job's name (filelock closes the inherited
    descriptor in the child; a bare flock would stay held through the child's copy)."""
    from sde_torchrl.jobs.lock import held_by

    holder = subprocess.Popen([sys.executable, "-c", FORKING_HOLD, str(tmp_path)], cwd=REPO, stdout=subprocess.PIPE,
                              text=True)
    child = int(holder.stdout.readline())
    try:
        assert held_by(tmp_path) == str(holder.pid)
        holder.kill()
        holder.wait()
        assert held_by(tmp_path) is None
        with hold_run_directory(tmp_path):
            pass
    finally:
        holder.kill()
        holder.wait()
        os.kill(child, signal.SIGKILL)


@pytest.mark.e2e
def test_a_sweep_relaunched_with_other_values_leaves_the_finished_jobs_alone(tmp_path):
    """Relaunching a sweep into the same directory with another value: each finished job is
    refused (exit 2) with advice naming hydra.sweep.dir, and its directory is not changed:
    no error.txt beside its valid summary, no rewritten .hydra/ or log."""
    sweep = ("+experiment=minimize", "updates=3", "runs=1", "seed=0,1", "logger=none")
    assert run_cli(*sweep, run_dir=tmp_path, multirun=True).returncode == 0
    def job_files() -> dict:  # the jobs' directories (Hydra rewrites the sweep's own multirun.yaml)
        return {p: p.read_bytes() for job in ("0", "1") for p in (tmp_path / job).rglob("*")
                if p.is_file() and p.name != ".lock"}

    before = job_files()
    result = run_cli(*sweep, "lr=0.01", run_dir=tmp_path, multirun=True)
    assert result.returncode == 2
    refusals = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(refusals) == 2 and all("hydra.sweep.dir" in line and "lr: 0.002 -> 0.01" in line for line in refusals)
    assert job_files() == before
    assert not list(tmp_path.rglob("error.txt"))


# --------------------------------------------------------------------------- finished or not


def test_the_remedy_for_a_damaged_checkpoint_never_retrains_a_finished_job(tmp_path, reference):
    """Finish a job, damage its checkpoint, put the previous one in its place (the remedy a
    damaged checkpoint of an unfinished job gives): the finished job stays as it was."""
    from sde_torchrl.jobs.run_dir import read_finished_run

    run_dir = tmp_path / "job"
    build(*BUDGET).train(run_dir, checkpoint_period=4)
    summary = (run_dir / "summary.json").read_bytes()
    (run_dir / "checkpoint.pt").write_bytes(b"damaged")
    os.replace(run_dir / "checkpoint.prev.pt", run_dir / "checkpoint.pt")
    assert build(*BUDGET).train(run_dir, checkpoint_period=4) == json.loads(summary)
    assert (run_dir / "summary.json").read_bytes() == summary
    assert (run_dir / "metrics.csv").read_bytes() == (reference / "metrics.csv").read_bytes()
    assert read_finished_run(run_dir).summary == json.loads(summary)


def test_readers_refuse_a_run_in_progress_or_files_that_disagree(tmp_path, reference, caplog):
    from sde_torchrl.jobs.run_dir import UnfinishedRunError, finished_runs, read_finished_run

    run_dir = tmp_path / "sweep" / "0"
    run_dir.parent.mkdir()
    build(*BUDGET).train(run_dir, checkpoint_period=4)
    with hold_run_directory(run_dir):  # what a reader sees while a job (re)runs there
        with pytest.raises(UnfinishedRunError, match=rf"a job is running in it \(pid {os.getpid()}\)"):
            read_finished_run(run_dir)
    assert len(finished_runs(tmp_path / "sweep")) == 1
    lines = (run_dir / "metrics.csv").read_bytes().splitlines(keepends=True)
    (run_dir / "metrics.csv").write_bytes(b"".join(lines[:-2]))  # the last update's rows lost
    with pytest.raises(UnfinishedRunError, match="metrics.csv has 22 rows up to update 10, summary.json says "
                                                 "2 runs × 12 updates"):
        finished_runs(tmp_path / "sweep")
    (run_dir / "metrics.csv").write_bytes(b"".join(lines))
    os.replace(run_dir / "checkpoint.prev.pt", run_dir / "checkpoint.pt")  # not the finished one: named, not used
    with caplog.at_level(logging.WARNING, logger="sde_torchrl.jobs.run_dir"):
        assert read_finished_run(run_dir).summary["updates_done"] == 12
    assert "checkpoint.pt was left as it is and is not used: it is at update 8 (unfinished)" in caplog.text


# --------------------------------------------------------------------------- a full disk


@pytest.fixture
def small_device(tmp_path):
    """A 1 MiB tmpfs (a real full device, as root can mount one), unmounted afterwards."""
    mount = tmp_path / "device"
    mount.mkdir()
    made = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mount)], capture_output=True)
    if made.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {made.stderr.decode().strip()}")
    yield mount
    subprocess.run(["umount", str(mount)], check=True)


@pytest.mark.parametrize("free_kib", [40])
@pytest.mark.e2e
def test_a_full_disk_is_named_leaves_no_temporary_file_and_resumes_once_freed(tmp_path, small_device, free_kib):
    cli = ("+experiment=minimize", "runs=2", "updates=150", "eval_period=10", "checkpoint_period=7", "logger=none")
    reference = run_cli(*cli, run_dir=tmp_path / "reference")
    assert reference.returncode == 0, reference.stderr[-2000:]
    ballast = small_device / "ballast"
    ballast.write_bytes(bytes(1024 * (1024 - free_kib)))
    run_dir = small_device / "run"
    full = run_cli(*cli, run_dir=run_dir)
    assert full.returncode == 1, full.stderr[-2000:]
    lines = own_stderr_lines(full.stderr)
    assert len(lines) == 1 and re.match(rf"error: {run_dir}/\S+ could not be written: no space left on its device "
                                        r"\(\d+ KiB free\); free some space and run the same command again", lines[0])
    assert not [p.name for p in run_dir.rglob("*.tmp")]
    ballast.unlink()
    resumed = run_cli(*cli, run_dir=run_dir)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert (run_dir / "metrics.csv").read_bytes() == (tmp_path / "reference" / "metrics.csv").read_bytes()


#: A PPO job of one update whose checkpoint (a 256 × 256 layer and Adam's moments) is over 200 KiB.
BIG_CHECKPOINT = ("algorithm=ppo", "env=gym", "env.episode_length=20", "algorithm.n_steps=16", "algorithm.batch_size=8",
                  "algorithm.n_epochs=1", "eval_episodes=1", "actor.hidden=[256,256]", "actor.init=null", "updates=1",
                  "logger=none")


@pytest.mark.e2e
def test_the_file_size_limit_is_named_with_the_file_and_leaves_no_temporary_file(tmp_path):
    run_dir = tmp_path / "run"
    command = " ".join(map(shlex.quote, train_command(*BIG_CHECKPOINT, run_dir=run_dir)))
    limited = subprocess.run(["bash", "-c", f"ulimit -f 200; exec {command}"], cwd=REPO, capture_output=True,
                             text=True, timeout=300)
    assert limited.returncode == 1, limited.stderr[-2000:]
    assert own_stderr_lines(limited.stderr) == [
        f"error: {run_dir / 'checkpoint.pt'} could not be written: it reached this process's file-size limit (200 KiB, "
        "ulimit -f); raise the limit (ulimit -f unlimited) and run the same command again: the job resumes from its "
        "last checkpoint"]
    assert not [p.name for p in run_dir.rglob("*.tmp")]


def test_a_failed_write_names_the_file_and_the_cause(tmp_path):
    from sde_torchrl.utils.files import FileWriteError, write_atomically

    def failing(f):
        f.write(b"some")
        raise OSError(errno.EIO, "Input/output error")

    with pytest.raises(FileWriteError, match=rf"^{tmp_path}/summary.json could not be written: Input/output error$"):
        write_atomically(tmp_path / "summary.json", failing)
    assert not list(tmp_path.iterdir())


def test_a_run_directory_name_over_the_file_system_s_limit_is_a_config_error(tmp_path):
    path = tmp_path / ("x" * 300)
    result = run_cli("+experiment=minimize", "updates=2", run_dir=path)
    assert result.returncode == 2, result.stderr[-2000:]
    assert own_stderr_lines(result.stderr) == [f"error: {path}: a name of 300 bytes, over its file system's limit of "
                                               "255 bytes per name: give the job another hydra.run.dir "
                                               "(hydra.sweep.dir for a sweep)"]


def test_a_run_directory_that_is_a_file_is_a_config_error(tmp_path):
    path = tmp_path / "taken"
    path.write_text("not a directory\n")
    result = run_cli("+experiment=minimize", "updates=2", run_dir=path)
    assert result.returncode == 2, result.stderr[-2000:]
    assert own_stderr_lines(result.stderr) == [f"error: {path} is a file, not a run directory: give the job another "
                                               "hydra.run.dir (hydra.sweep.dir for a sweep)"]
    assert path.read_text() == "not a directory\n"
    with pytest.raises(ArgumentError, match="run directory=.*: a directory; this path is a file"):
        build("updates=2").train(path)


@pytest.mark.e2e
def test_another_config_before_the_first_checkpoint_is_refused_like_after_it(tmp_path):
    run_dir = tmp_path / "run"
    cli = ("+experiment=minimize", "runs=2", "updates=150", "eval_period=10", "checkpoint_period=0")
    killed = subprocess.Popen(train_command(*cli, run_dir=run_dir), cwd=REPO, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    metrics, deadline = run_dir / "metrics.csv", time.monotonic() + 120
    while not metrics.exists() or len(metrics.read_bytes().splitlines()) < 40:
        assert killed.poll() is None and time.monotonic() < deadline
        time.sleep(0.01)
    killed.kill()
    killed.wait()
    rows = metrics.read_bytes()
    other = run_cli(*cli[:-1], "checkpoint_period=0", "seed=7", run_dir=run_dir)
    assert other.returncode == 2, other.stderr[-2000:]
    lines = own_stderr_lines(other.stderr)
    assert len(lines) == 1 and "holds the rows of a job with another config (seed: 0 -> 7)" in lines[0], lines
    assert metrics.read_bytes() == rows  # nothing deleted
    same = run_cli(*cli, run_dir=run_dir)  # the same config: no checkpoint, so it starts over
    assert same.returncode == 0, same.stderr[-2000:]


@pytest.mark.parametrize("damage, problem", [
    ("negative update", "its update counter is -3, outside [0, 12]"),
    ("int64 weights", "its policy entry 'module.0.module.0.module.weight' is (2, 1, 1) torch.int64, this job's is "
                      "(2, 1, 1) torch.float32"),
    ("wrong shape", "its policy entry 'module.0.module.0.module.weight' is (2, 1, 2) torch.float32, this job's is "
                    "(2, 1, 1) torch.float32"),
])
def test_a_checkpoint_whose_content_does_not_fit_the_job_is_refused(crashed, damage, problem):
    """Its checksum matches (it is what was written), but it cannot be this job's state."""
    from sde_torchrl.jobs.checkpoint import save_checkpoint

    path = crashed / "checkpoint.pt"
    state = load_checkpoint(path)
    weight = state["policy"]["module.0.module.0.module.weight"]
    if damage == "negative update":
        state["updates"] = state["loop"]["update"] = -3
    elif damage == "int64 weights":
        state["policy"]["module.0.module.0.module.weight"] = weight.long()
    else:
        state["policy"]["module.0.module.0.module.weight"] = torch.cat([weight, weight], -1)
    save_checkpoint(path, state)
    before = snapshot(crashed, skip=(".lock",))
    with pytest.raises(DamagedFileError, match=re.escape(problem)):
        build(*BUDGET).train(crashed, checkpoint_period=4)
    assert snapshot(crashed, skip=(".lock",)) == before
    result = run_cli("+experiment=minimize", *BUDGET, "checkpoint_period=4", run_dir=crashed)
    assert result.returncode == 4, result.stderr[-2000:]
    assert own_stderr_lines(result.stderr)[0].startswith(f"error: {path} is damaged: {problem}")
