"""A finished run is final: rerunning its command on its directory, with or without
its checkpoint, whatever was done to that checkpoint, changes nothing; the reader checks what the
job checks; sweep readers find jobs by their job record and by the sweep's job list, and refuse a
sweep with a job that is not finished or never started; and the smaller
cases around it (run directories that cannot be made, a full disk while closing ``metrics.csv``)."""

from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path

import pytest
from _helpers import compose_config, own_stderr_lines, run_cli

from sde_torchrl.config.build import run_job
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.jobs.checkpoint import load_checkpoint
from sde_torchrl.jobs.lock import hold_run_directory
from sde_torchrl.jobs.run_dir import (
    FinishedRunError,
    RunDirectory,
    UnfinishedRunError,
    finished_runs,
    job_directories,
    read_finished_run,
)
from sde_torchrl.utils.files import DamagedFileError

BUDGET = ("+experiment=minimize", "logger=none", "runs=2", "updates=12", "episodes_per_update=4", "eval_period=5",
          "checkpoint_period=4")


def snapshot(directory: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under ``directory`` but the lock: content and modification time (ns)."""
    return {str(p.relative_to(directory)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(directory.rglob("*")) if p.is_file() and p.name != ".lock"}


def train(run_dir: Path, *overrides: str) -> dict:
    """The job of :data:`BUDGET` (with ``overrides``), run as ``train.py`` runs it, in this process."""
    return run_job(validate(compose_config(*BUDGET, *overrides)), str(run_dir), {"experiment": "minimize"})


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> Path:
    """A finished job of :data:`BUDGET`, its checkpoints kept."""
    out = tmp_path_factory.mktemp("finished") / "job"
    train(out)
    return out


@pytest.fixture
def finished(made, tmp_path) -> Path:
    """A copy of :func:`made` to change."""
    return Path(shutil.copytree(made, tmp_path / "job"))


# ------------------------------------------------------------------------------- the job

@pytest.mark.parametrize("checkpoint", ["kept", "removed"])
@pytest.mark.e2e
def test_a_finished_run_is_final_with_or_without_its_checkpoint(tmp_path, checkpoint):
    cli = ("+experiment=minimize", "runs=2", "updates=6", "eval_period=3", "logger=none")
    run_dir = tmp_path / "run"
    assert run_cli(*cli, run_dir=run_dir).returncode == 0
    if checkpoint == "removed":
        for path in run_dir.glob("checkpoint*.pt"):
            path.unlink()
    before = snapshot(run_dir)
    again = run_cli(*cli, run_dir=run_dir)
    assert again.returncode == 0, again.stderr[-2000:]
    assert [line for line in again.stdout.splitlines() if line.strip()] == [
        f"{run_dir} holds a finished job (6 updates of 2 runs): nothing was changed; a finished job is final: to "
        "train with other settings (more updates, say), give the job another directory; to train this one again "
        "from the start, remove its directory first"]
    assert snapshot(run_dir) == before
    for other, code, says in [(("lr=0.01",), 2, "holds a finished job of another config (lr: 0.002 -> 0.01)"),
                              (("updates=9",), 2, "updates: 6 -> 9"),
                              (("explorer.bogus=1",), 2, "explorer.bogus: unknown key")]:
        refused = run_cli(*cli, *other, run_dir=run_dir)
        lines = own_stderr_lines(refused.stderr)
        assert refused.returncode == code and len(lines) == 1 and says in lines[0], (other, refused.stderr[-2000:])
        assert snapshot(run_dir) == before, other  # no error.txt, no rewritten .hydra/overrides.yaml or train.log


def test_a_job_never_removes_a_finished_run(finished):
    for path in finished.glob("checkpoint*.pt"):
        path.unlink()
    before = snapshot(finished)
    with pytest.raises(FinishedRunError, match="holds a finished job: a new job would remove its files; it was left "
                                               "unchanged: .* or remove that one to start over"):
        RunDirectory(finished).start_new_job()
    summary = json.loads((finished / "summary.json").read_text())
    assert train(finished) == summary  # nothing trained, nothing written
    assert snapshot(finished) == before


def test_a_finished_checkpoint_rewrites_a_damaged_summary_only(finished):
    summary = (finished / "summary.json").read_bytes()
    (finished / "summary.json").write_bytes(summary.replace(b'"seed": 0', b'"seed": 5'))
    with pytest.raises(UnfinishedRunError, match="summary.json does not match its digest"):
        read_finished_run(finished)
    train(finished)
    assert (finished / "summary.json").read_bytes() == summary
    assert read_finished_run(finished).summary["seed"] == 0


# ------------------------------------------------------------------- what the reader checks

def _change_a_value(lines: list[bytes]) -> list[bytes]:
    fields = lines[7].split(b",")
    fields[3] = repr(float(fields[3]) + 1e-6).encode()
    return [*lines[:7], b",".join(fields), *lines[8:]]


DAMAGES = {
    "a changed value": lambda lines: _change_a_value(lines),
    "a row overwritten by its neighbour": lambda lines: [*lines[:7], lines[6], *lines[8:]],
    "an extra column": lambda lines: [line.rstrip(b"\r\n") + b",0\r\n" for line in lines],
    "other line endings": lambda lines: [line.replace(b"\r\n", b"\n") for line in lines],
}


@pytest.mark.parametrize("damage", sorted(DAMAGES))
@pytest.mark.parametrize("checkpoint", ["kept", "removed"])
def test_the_reader_refuses_rows_the_job_refuses(finished, damage, checkpoint):
    if checkpoint == "removed":
        for path in finished.glob("checkpoint*.pt"):
            path.unlink()
    metrics = finished / "metrics.csv"
    metrics.write_bytes(b"".join(DAMAGES[damage](metrics.read_bytes().splitlines(keepends=True))))
    with pytest.raises(UnfinishedRunError):
        read_finished_run(finished)
    before = snapshot(finished)
    with pytest.raises(DamagedFileError):  # the job: exit 4, nothing changed
        train(finished)
    assert snapshot(finished) == before


def test_the_reader_refuses_an_edited_summary_and_the_job_too_without_a_checkpoint(finished):
    for path in finished.glob("checkpoint*.pt"):
        path.unlink()
    summary = json.loads((finished / "summary.json").read_text())
    summary["final_parameters"]["module.0.module.0.module.weight"][0][0] += 0.5
    (finished / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(UnfinishedRunError, match="summary.json does not match its digest .*; without a checkpoint.pt "
                                                 "nothing can rebuild them: restore the directory"):
        read_finished_run(finished)
    before = snapshot(finished)
    with pytest.raises(UnfinishedRunError):
        train(finished)
    assert snapshot(finished) == before


def _flip_a_byte(run_dir: Path, tmp_path: Path) -> None:
    path = run_dir / "checkpoint.pt"
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(DamagedFileError, match="does not match its checksum"):  # the damage reaches its content
        load_checkpoint(path)


def _follow_the_old_advice(run_dir: Path, tmp_path: Path) -> None:
    """A byte flipped, then ``mv checkpoint.prev.pt checkpoint.pt``, as a damaged checkpoint's
    remedy advises for a job that has not finished."""
    _flip_a_byte(run_dir, tmp_path)
    os.replace(run_dir / "checkpoint.prev.pt", run_dir / "checkpoint.pt")


def _another_seeds_checkpoint(run_dir: Path, tmp_path: Path) -> None:
    train(tmp_path / "seed1", "seed=1")
    shutil.copy(tmp_path / "seed1" / "checkpoint.pt", run_dir / "checkpoint.pt")


#: What can be done to a finished job's checkpoint, and the problem its one line names.
CHECKPOINT_CHANGES = {
    "a byte flipped": (_flip_a_byte, "it is damaged (its content does not match its checksum)"),
    "mv checkpoint.prev.pt checkpoint.pt": (_follow_the_old_advice, "it is at update 8 (unfinished), summary.json "
                                                                    "says 12"),
    "cp checkpoint.prev.pt checkpoint.pt": (lambda run_dir, _: shutil.copy(run_dir / "checkpoint.prev.pt",
                                                                           run_dir / "checkpoint.pt"),
                                            "it is at update 8 (unfinished), summary.json says 12"),
    "another seed's checkpoint": (_another_seeds_checkpoint, "it was written by another config than summary.json's "
                                                             "(seed: 1 -> 0)"),
}


@pytest.mark.parametrize("change", sorted(CHECKPOINT_CHANGES))
def test_a_finished_job_never_trains_again_whatever_is_done_to_its_checkpoint(finished, tmp_path, change, caplog):
    """Its summary and rows, which agree with their digests, are its result: the job reports it
    finished and names the checkpoint's problem in one line, the reader reads it, nothing changes."""
    summary = json.loads((finished / "summary.json").read_text())
    change_checkpoint, problem = CHECKPOINT_CHANGES[change]
    change_checkpoint(finished, tmp_path)
    before = snapshot(finished)
    with caplog.at_level(logging.WARNING, logger="sde_torchrl.jobs.run_dir"):
        assert train(finished) == summary
    assert snapshot(finished) == before
    lines = [record.getMessage() for record in caplog.records if record.levelno >= logging.WARNING]
    assert len(lines) == 1 and lines[0].startswith(f"{finished / 'checkpoint.pt'} was left as it is and is not used: "
                                                   f"{problem}; the job finished"), lines
    assert "mv " not in lines[0]
    assert read_finished_run(finished).summary == summary


@pytest.mark.e2e
def test_a_damaged_checkpoint_of_a_finished_job_on_the_command_line(made, tmp_path):
    """Exit 0 with the finished line and the checkpoint's line, no advice to move the previous
    checkpoint in, and no file changed."""
    run_dir = Path(shutil.copytree(made, tmp_path / "job"))
    _flip_a_byte(run_dir, tmp_path)
    before = snapshot(run_dir)
    result = run_cli(*BUDGET, run_dir=run_dir)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "checkpoint.prev.pt" not in result.stdout + result.stderr
    said = [line for line in result.stdout.splitlines() if line.strip()]
    assert len(said) == 2 and said[1].startswith(f"{run_dir} holds a finished job (12 updates of 2 runs)"), said
    assert f"{run_dir / 'checkpoint.pt'} was left as it is and is not used: it is damaged" in said[0]
    assert snapshot(run_dir) == before


@pytest.mark.parametrize("damage", ["a row overwritten by its neighbour", "an extra column", "other line endings"])
def test_a_summary_written_before_the_digests_is_still_checked_against_its_rows(finished, damage):
    """Committed runs' summaries record no digests: their rows are checked against the summary,
    their order and the bytes the job writes."""
    for path in finished.glob("checkpoint*.pt"):
        path.unlink()
    summary = json.loads((finished / "summary.json").read_text())
    del summary["sha256"], summary["metrics_sha256"]
    (finished / "summary.json").write_text(json.dumps(summary))
    assert read_finished_run(finished).summary == summary
    metrics = finished / "metrics.csv"
    metrics.write_bytes(b"".join(DAMAGES[damage](metrics.read_bytes().splitlines(keepends=True))))
    with pytest.raises(UnfinishedRunError):
        read_finished_run(finished)


# ------------------------------------------------------------------------------ sweep readers

def test_sweep_readers_find_jobs_by_their_record_and_refuse_one_not_finished(made, tmp_path, caplog):
    sweep = tmp_path / "sweep"
    for job in ("0", "1", "2"):
        shutil.copytree(made, sweep / job)
    assert [job.path.name for job in finished_runs(sweep)] == ["0", "1", "2"]
    (sweep / "3").mkdir()
    (sweep / "3" / "job_config.json").write_text("{}")  # killed before its first row
    with pytest.raises(UnfinishedRunError, match=f"{sweep / '3'} is not a finished run: it has no summary.json"):
        finished_runs(sweep)
    (sweep / "1" / "metrics.csv").unlink()
    with hold_run_directory(sweep / "2"):  # live
        assert job_directories(sweep) == [sweep / name for name in ("0", "1", "2", "3")]
        with pytest.raises(UnfinishedRunError, match=f"{sweep / '1'} is not a finished run: it has no metrics.csv"):
            finished_runs(sweep)
        with caplog.at_level(logging.WARNING, logger="sde_torchrl.jobs.run_dir"):
            assert [job.path.name for job in finished_runs(sweep, finished_only=True)] == ["0"]
    left_out = [record.getMessage() for record in caplog.records]
    assert len(left_out) == 3 and all(message.startswith("left out (finished_only): ") for message in left_out)
    assert "a job is running in it" in left_out[1]


def test_a_logger_folder_cannot_take_the_name_of_a_file_the_job_writes():
    from sde_torchrl.config.schemas.loggers import RUN_DIRECTORY_NAMES
    from sde_torchrl.jobs.checkpoint import PREVIOUS
    from sde_torchrl.jobs.run_dir import JOB_FILES

    assert {*JOB_FILES, PREVIOUS, ".hydra", "train.log"} <= set(RUN_DIRECTORY_NAMES)


@pytest.mark.parametrize("kind", ["dangling link", "link loop", "below a file"])
def test_a_run_directory_that_cannot_be_made_is_a_config_error_in_one_line(tmp_path, kind):
    """Exit 2 and one line naming the path, instead of exit 1 with a raw OSError."""
    (tmp_path / "file").write_text("x\n")
    path = {"dangling link": tmp_path / "dangling", "link loop": tmp_path / "loop",
            "below a file": tmp_path / "file" / "run"}[kind]
    if kind != "below a file":
        path.symlink_to(tmp_path / "nowhere" if kind == "dangling link" else path)
    result = run_cli("+experiment=minimize", "updates=2", "logger=none", run_dir=path)
    assert result.returncode == 2, result.stderr[-2000:]
    says = ("below a file (" if kind == "below a file" else "is a symbolic link to nothing (dangling, or a loop)")
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith(f"error: {path} ") and says in lines[0], lines


def test_a_full_disk_while_closing_metrics_is_named_not_a_bare_os_error(tmp_path):
    """Rows left in the buffer by a full disk fail again when the file is closed: that second
    ENOSPC must not replace the named DiskFullError."""
    import subprocess as sp

    import torch

    from sde_torchrl.jobs.run_dir import MetricsFile, csv_lines, metric_rows, update_statistics
    from sde_torchrl.utils.files import DiskFullError

    device = tmp_path / "device"
    device.mkdir()
    made = sp.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(device)], capture_output=True)
    if made.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {made.stderr.decode().strip()}")
    try:
        (device / "ballast").write_bytes(bytes(1024 * 1000))
        stats = {"return_mean": torch.full((2000,), -1.5), "grad_norm": torch.ones(2000),
                 "exploration": torch.ones(3, 2000)}
        rows = metric_rows(update_statistics(0, 0, 5, stats, None))
        with pytest.raises(DiskFullError, match=f"^{device / 'metrics.csv'} could not be written: no space left"):
            with MetricsFile(device / "metrics.csv", csv_lines([])) as metrics:
                metrics.write(rows)
    finally:
        sp.run(["umount", str(device)], check=True)
