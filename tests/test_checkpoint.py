"""Checkpoint and resume: an interrupted job, started again, ends exactly like an uninterrupted one."""

from __future__ import annotations

import json
import signal
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import torch
from _helpers import (
    REPO,
    Crash,
    build,
    crash_at,
    own_stderr_lines,
    read_rows,
    run_cli,
    summary_without_wall,
    train_command,
)

from sde_torchrl.jobs.checkpoint import (
    FORMAT,
    CheckpointMismatchError,
    config_differences,
    load_checkpoint,
    save_checkpoint,
)
from sde_torchrl.utils.files import write_json_atomic

# ------------------------------------------------------------------------------ in process


@pytest.mark.parametrize("overrides", [
    ("explorer=sde",), ("explorer=rex", "estimator=enac"), ("explorer=sde_gauss", "tensor_rollout=false"),
    ("episode_queue=8",), ("episode_queue=8", "queue_scores=as_collected"),
    ("episode_queue=8", "queue_scores=as_collected", "estimator=gpomdp", "scores=closed_form"),
    ("episode_queue=8", "queue_scores=as_collected", "explorer=pgpe", "estimator=pgpe", "explorer.symmetric=false"),
])
def test_resume_after_crash_equals_uninterrupted(tmp_path, overrides):
    budget = ("runs=2", "updates=12", "episodes_per_update=4", "eval_period=5", *overrides)
    reference = build(*budget).train(tmp_path / "ref", checkpoint_period=4)

    crashed = build(*budget)
    crash_at(crashed, 10)  # after the checkpoint at update 8: updates 8 and 9 are lost
    with pytest.raises(Crash):
        crashed.train(tmp_path / "resumed", checkpoint_period=4)
    assert len(read_rows(tmp_path / "resumed")) == 2 * 10  # rows beyond the checkpoint
    assert load_checkpoint(tmp_path / "resumed" / "checkpoint.pt")["updates"] == 8
    # A fresh process would do torch.manual_seed(seed) again: the checkpoint must not need more.
    torch.manual_seed(1234)
    resumed = build(*budget).train(tmp_path / "resumed", checkpoint_period=4)

    assert (tmp_path / "resumed" / "metrics.csv").read_bytes() == (tmp_path / "ref" / "metrics.csv").read_bytes()
    reference.pop("wall_s"), resumed.pop("wall_s")
    assert resumed == reference


def test_a_format_3_checkpoint_resumes_bit_for_bit(tmp_path):
    """Format 3 (before TorchRL's GlobalRNGState) named torch's generator ``torch``: a job
    interrupted under it resumes under format 4 to the uninterrupted outputs."""
    budget = ("runs=2", "updates=12", "episodes_per_update=4", "eval_period=5")
    build(*budget).train(tmp_path / "ref", checkpoint_period=4)
    crashed = build(*budget)
    crash_at(crashed, 10)
    with pytest.raises(Crash):
        crashed.train(tmp_path / "resumed", checkpoint_period=4)
    path = tmp_path / "resumed" / "checkpoint.pt"
    state = load_checkpoint(path)
    assert state["format"] == FORMAT == 4 and sorted(state["random"]) == ["numpy", "python", "torch_cpu"]
    generators = state["random"]
    state["format"], state["random"] = 3, {"torch": generators["torch_cpu"], "numpy": list(generators["numpy"]),
                                           "python": generators["python"]}
    save_checkpoint(path, state)
    torch.manual_seed(1234)
    build(*budget).train(tmp_path / "resumed", checkpoint_period=4)
    assert (tmp_path / "resumed" / "metrics.csv").read_bytes() == (tmp_path / "ref" / "metrics.csv").read_bytes()


def test_finished_job_is_not_trained_again(tmp_path):
    trainer = build("updates=3")
    first = trainer.train(tmp_path, checkpoint_period=1)
    again = build("updates=3")
    crash_at(again, 0)  # would raise if it trained
    (tmp_path / "summary.json").unlink()  # e.g. killed between checkpoint and summary
    assert again.train(tmp_path) == first


def test_checkpoint_of_another_config_is_refused(tmp_path):
    build("updates=3").train(tmp_path, {"config": {"lr": 0.005, "updates": 3}})
    with pytest.raises(CheckpointMismatchError, match=r"lr: 0.005 -> 0.01"):
        build("updates=3").train(tmp_path, {"config": {"lr": 0.01, "updates": 3}})
    # Keys that do not change the numbers may differ.
    build("updates=3").train(tmp_path, {"config": {"lr": 0.005, "updates": 3, "logger": {"x": 1},
                                                           "checkpoint_period": 9, "progress": True}})


def test_config_differences_names_nested_keys():
    saved = {"explorer": {"sharing": "element"}, "runs": 2}
    assert config_differences(saved, {"explorer": {"sharing": "single"}, "runs": 2}) == [
        "explorer.sharing: 'element' -> 'single'"]


def test_json_written_atomically(tmp_path, monkeypatch):
    path = tmp_path / "summary.json"
    write_json_atomic(path, {"a": 1})

    def broken_dump(data, f, **kwargs):
        f.write('{"a": ')
        raise OSError("disk full")

    monkeypatch.setattr(json, "dump", broken_dump)
    with pytest.raises(OSError):
        write_json_atomic(path, {"a": 2})
    assert json.loads(path.read_text()) == {"a": 1}  # the old file, whole


# --------------------------------------------------------------------------- command line

# 1,000 updates (about 4 s of training under CI's load): a signal sent once some rows are written
# lands in the middle of training, not after the last update (150 left a few tenths of a second).
CLI = ("+experiment=minimize", "runs=2", "updates=1000", "eval_period=10", "checkpoint_period=7")


def rows_in(path: Path) -> int:
    try:
        return max(len(path.read_bytes().splitlines()) - 1, 0)
    except FileNotFoundError:
        return 0


def start_and_signal(run_dir: Path, sig: int, after_rows: int,
                     cli: tuple[str, ...] = CLI) -> subprocess.CompletedProcess:
    """Starts ``train.py`` with ``cli``, sends ``sig`` once metrics.csv has ``after_rows``
    rows, and waits for the process to end."""
    # SIGINT at its default in the child, as in a terminal: a shell's background job (a CI
    # script's `cmd &`, nohup) inherits it ignored, and a job that ignores SIGINT rightly goes on.
    proc = subprocess.Popen(train_command(*cli, run_dir=run_dir), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while rows_in(run_dir / "metrics.csv") < after_rows:
        assert proc.poll() is None, f"ended before the signal:\n{proc.stderr.read()[-2000:]}"
        assert time.monotonic() < deadline, "no progress"
        time.sleep(0.01)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=120)
    assert not (run_dir / "summary.json").exists(), "the job finished before the signal"
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


@pytest.mark.e2e
def test_ctrl_c_and_kill_then_resume_equals_uninterrupted(tmp_path):
    with ThreadPoolExecutor(max_workers=1) as pool:
        reference = pool.submit(run_cli, *CLI, run_dir=tmp_path / "ref")
        run_dir = tmp_path / "interrupted"

        # Ctrl-C: a checkpoint after the current update, a message, a clean exit.
        stopped = start_and_signal(run_dir, signal.SIGINT, after_rows=40)
        assert stopped.returncode == 130, stopped.stderr[-2000:]
        lines = own_stderr_lines(stopped.stderr)
        assert len(lines) == 1 and lines[0].startswith("interrupted by SIGINT: checkpoint after update "), lines
        assert f"hydra.run.dir={run_dir}" in lines[0]
        done = load_checkpoint(run_dir / "checkpoint.pt")["updates"]
        assert rows_in(run_dir / "metrics.csv") == 2 * done  # saved exactly where it stopped

        # SIGKILL at an arbitrary moment of the resumed job: rows after its last checkpoint
        # are lost from the checkpoint's point of view and must be redone identically.
        killed = start_and_signal(run_dir, signal.SIGKILL, after_rows=2 * done + 110)
        assert killed.returncode == -signal.SIGKILL
        assert load_checkpoint(run_dir / "checkpoint.pt")["updates"] > done

        finished = run_cli(*CLI, run_dir=run_dir)
        assert finished.returncode == 0, finished.stderr[-2000:]
        assert "resuming" in finished.stdout
        ref = reference.result()
        assert ref.returncode == 0, ref.stderr[-2000:]

    ref_dir = tmp_path / "ref"
    assert (run_dir / "metrics.csv").read_bytes() == (ref_dir / "metrics.csv").read_bytes()
    resumed, uninterrupted = summary_without_wall(run_dir), summary_without_wall(ref_dir)
    assert resumed == uninterrupted
    assert resumed["updates_done"] == 1000
    scalars = Path("sde_torchrl", "scalars", "return_mean.csv")  # TorchRL's CSV logger too
    assert (run_dir / scalars).read_bytes() == (ref_dir / scalars).read_bytes()
    assert not list(run_dir.glob("*.tmp"))


@pytest.mark.e2e
def test_sigterm_without_periodic_checkpoints_loses_nothing(tmp_path):
    """A scheduler's SIGTERM is handled as Ctrl-C is, also with ``checkpoint_period=0``: the job
    checkpoints after its update, names the signal, exits 143, and the same command resumes it
    to the uninterrupted outputs. SIGTERM before the job has started (imports) loses nothing
    either: there is nothing yet."""
    cli = (*CLI[:-1], "checkpoint_period=0")
    with ThreadPoolExecutor(max_workers=1) as pool:
        reference = pool.submit(run_cli, *cli, run_dir=tmp_path / "ref")
        run_dir = tmp_path / "terminated"
        early = subprocess.Popen(train_command(*cli, run_dir=run_dir), cwd=REPO, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE)
        time.sleep(0.3)
        early.send_signal(signal.SIGTERM)
        early.communicate(timeout=60)
        assert rows_in(run_dir / "metrics.csv") == 0

        stopped = start_and_signal(run_dir, signal.SIGTERM, after_rows=60, cli=cli)
        assert stopped.returncode == 143, stopped.stderr[-2000:]
        lines = own_stderr_lines(stopped.stderr)
        assert len(lines) == 1 and lines[0].startswith("interrupted by SIGTERM: checkpoint after update "), lines
        done = load_checkpoint(run_dir / "checkpoint.pt")["updates"]
        assert rows_in(run_dir / "metrics.csv") == 2 * done >= 60

        finished = run_cli(*cli, run_dir=run_dir)
        assert finished.returncode == 0, finished.stderr[-2000:]
        assert reference.result().returncode == 0
    assert (run_dir / "metrics.csv").read_bytes() == (tmp_path / "ref" / "metrics.csv").read_bytes()
    assert summary_without_wall(run_dir) == summary_without_wall(tmp_path / "ref")


def test_the_previous_checkpoint_is_a_copy_never_a_hard_link(tmp_path):
    """A job killed between keeping the previous checkpoint and renaming the new one in must not
    leave both names on one file: damaging one would damage both."""
    from sde_torchrl.jobs.checkpoint import CHECKPOINT, PREVIOUS, keep_previous

    build("updates=3").train(tmp_path, checkpoint_period=1)
    path, previous = tmp_path / CHECKPOINT, tmp_path / PREVIOUS
    keep_previous(path, previous)  # the moment of the kill: before the new checkpoint is renamed in
    assert previous.read_bytes() == path.read_bytes() and path.stat().st_nlink == previous.stat().st_nlink == 1
    path.write_bytes(b"damaged")
    assert load_checkpoint(previous)["updates"] == 3


@pytest.mark.parametrize("multirun", [False, True])
@pytest.mark.e2e
def test_the_resume_line_pastes_back_as_it_is_printed(tmp_path, multirun):
    """A path with a space is quoted for the shell, and a job of a multirun names
    its sweep's directory (hydra.sweep.dir), not its own; the printed override, pasted back into
    the same command, resumes the job to its end."""
    import shlex
    import sys

    where = tmp_path / "runs with spaces"
    run_dir = where / "0" if multirun else where
    cli = (*CLI[:2], "updates=1000", "eval_period=10", "checkpoint_period=0", "logger=none")
    proc = subprocess.Popen(train_command(*cli, run_dir=where, multirun=multirun), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while rows_in(run_dir / "metrics.csv") < 40:
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()[-2000:] if proc.poll() else ""
        time.sleep(0.01)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 143, stderr[-2000:]
    line = next(line for line in own_stderr_lines(stderr) if line.startswith("interrupted by SIGTERM"))
    assert load_checkpoint(run_dir / "checkpoint.pt")["updates"] < 1000, "the signal came after the last update"
    override = shlex.quote(f"hydra.{'sweep' if multirun else 'run'}.dir={where}")
    assert line.endswith(f"; run the same command with {override} to resume"), line
    resumed = subprocess.run([sys.executable, "train.py", *(["-m"] if multirun else []), *cli, *shlex.split(override)],
                             cwd=REPO, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "resuming" in resumed.stdout and (run_dir / "summary.json").exists()
