"""The job's config in one form: built and frozen once at the edge (``validate``), its resolved
dict derived from it, and the run directory the one place that checks "same job?"; its record
``job_config.json`` checked wherever it is read, and rows never kept or lost without it."""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
from dataclasses import FrozenInstanceError
from pathlib import Path

import pytest
from _helpers import REPO, build, compose_config, crash_at, own_stderr_lines, run_cli
from omegaconf import OmegaConf

from sde_torchrl.config.build import run_job
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.jobs.checkpoint import CheckpointMismatchError
from sde_torchrl.jobs.run_dir import RunDirectory, read_finished_run, read_job_config
from sde_torchrl.utils.files import DamagedFileError

#: The library's experiments (conf/experiment/; the study's: tests/study/test_study_configs.py).
EXPERIMENTS = sorted(path.stem for path in (REPO / "conf" / "experiment").glob("*.yaml"))
#: Jobs beside the experiments: the other groups' options.
OTHERS = [("algorithm=ppo", "env=gym", "explorer=gsde"),
          ("algorithm=sac", "env=gym", "explorer=gaussian"),
          ("estimator=pgpe", "explorer=pgpe"), ("estimator=gpomdp", "optimizer=rmsprop", "logger=tensorboard")]


@pytest.mark.parametrize("overrides", [(f"+experiment={name}",) for name in EXPERIMENTS] + OTHERS)
def test_the_resolved_config_is_what_hydra_resolves(overrides):
    """``job_config.json`` and the summary's config come from the typed object now: they must be
    Hydra's resolved config key for key, in the same order (the bytes written depend on it)."""
    cfg = compose_config(*overrides, "max_memory_gb=1000")
    resolved = validate(cfg).resolved()
    expected = OmegaConf.to_container(cfg, resolve=True)
    assert json.dumps(resolved) == json.dumps(expected)


def test_a_validated_config_is_frozen():
    conf = validate(compose_config("+experiment=minimize"))
    with pytest.raises(FrozenInstanceError, match="'updates' of a validated config"):
        conf.updates = 3
    with pytest.raises(FrozenInstanceError, match="'episode_length'"):
        conf.env.episode_length = 3
    with pytest.raises(FrozenInstanceError):
        del conf.estimator.max_grad_norm
    assert conf.updates == 300 and conf.env.episode_length == 15


def _checkpointed(run_dir: Path, config: dict) -> None:
    """A job of ``config`` stopped after checkpointing update 2 of 4."""
    trainer = build("updates=4")
    crash_at(trainer, 2)
    with pytest.raises(Exception, match="crash at 2"):
        trainer.train(run_dir, {"config": config}, checkpoint_period=1)


def test_the_run_directory_alone_refuses_another_config(tmp_path, monkeypatch):
    """The run directory's check is the one: with it, another config is refused by name; without
    it, nothing else (the checkpoint, the trainer) checks again, and the job resumes."""
    _checkpointed(tmp_path, {"lr": 0.005, "updates": 4})
    refused = r"checkpoint.pt was written by another config \(lr: 0.005 -> 0.01\)"
    with pytest.raises(CheckpointMismatchError, match=refused):
        build("updates=4").train(tmp_path, {"config": {"lr": 0.01, "updates": 4}})
    monkeypatch.setattr(RunDirectory, "check_job", lambda self: None)
    summary = build("updates=4").train(tmp_path, {"config": {"lr": 0.01, "updates": 4}})
    assert summary["updates_done"] == 4


def test_check_job_reads_the_record_of_what_the_directory_holds(tmp_path):
    """Nothing there: nothing to refuse; a checkpoint: its config counts, and ``job_config.json``
    must record the same."""
    assert RunDirectory(tmp_path / "new", {"lr": 0.1}).check_job() is None
    _checkpointed(tmp_path, {"lr": 0.005, "updates": 4})
    assert RunDirectory(tmp_path, {"lr": 0.005, "updates": 4}).check_job() is None
    with pytest.raises(CheckpointMismatchError, match="written by another config"):
        RunDirectory(tmp_path, {"lr": 0.01, "updates": 4}).check_job()
    (tmp_path / "job_config.json").write_text(json.dumps({"lr": 0.01, "updates": 4}))  # as written before the digest
    with pytest.raises(DamagedFileError, match=r"job_config.json is damaged: it records another config than "
                                               r"checkpoint.pt \(lr: 0.01 -> 0.005\)"):
        RunDirectory(tmp_path, {"lr": 0.005, "updates": 4}).check_job()


# ------------------------------------------------------------- job_config.json, checked like the others

BUDGET = ("+experiment=minimize", "logger=none", "runs=2", "updates=12", "episodes_per_update=4", "eval_period=5",
          "checkpoint_period=4")


def train(run_dir: Path, *overrides: str) -> dict:
    """The job of :data:`BUDGET` (with ``overrides``), run as ``train.py`` runs it, in this process."""
    return run_job(validate(compose_config(*BUDGET, *overrides)), str(run_dir), {"experiment": "minimize"})


def snapshot(directory: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under ``directory`` but the lock: content and modification time (ns)."""
    return {str(p.relative_to(directory)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(directory.rglob("*")) if p.is_file() and p.name != ".lock"}


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> Path:
    """A finished job of :data:`BUDGET`, its checkpoints kept (after updates 8 and 12)."""
    out = tmp_path_factory.mktemp("job_config") / "job"
    train(out)
    return out


@pytest.fixture
def finished(made, tmp_path) -> Path:
    return Path(shutil.copytree(made, tmp_path / "finished"))


@pytest.fixture
def resumable(made, tmp_path) -> Path:
    """The job as a kill after update 9 leaves it: its checkpoint after update 8, no summary."""
    run_dir = Path(shutil.copytree(made, tmp_path / "resumable"))
    os.replace(run_dir / "checkpoint.prev.pt", run_dir / "checkpoint.pt")
    (run_dir / "summary.json").unlink()
    return run_dir


@pytest.fixture
def rows_only(made, tmp_path) -> Path:
    """The job as a kill before its first checkpoint leaves it: rows, no checkpoint, no summary."""
    run_dir = Path(shutil.copytree(made, tmp_path / "rows"))
    for name in ("checkpoint.pt", "checkpoint.prev.pt", "summary.json"):
        (run_dir / name).unlink()
    return run_dir


def _edit_seed(path: Path, keep_digest: bool) -> None:
    record = json.loads(path.read_text())
    record["seed"] = 3
    if not keep_digest:
        record.pop("sha256", None)  # as written before the digests
    path.write_text(json.dumps(record, indent=2))


#: Damage to job_config.json, and the problem the refusal names (against a checkpoint's config,
#: or a summary's, where its digest is gone).
DAMAGES = {
    "truncated": (lambda path: path.write_bytes(path.read_bytes()[:100]), "it is not valid JSON"),
    "edited": (lambda path: _edit_seed(path, keep_digest=True), "it does not match its digest (sha256)"),
    "edited, its digest removed": (lambda path: _edit_seed(path, keep_digest=False), "it records another config "
                                                                                     "than {record} (seed: 3 -> 0)"),
}


@pytest.mark.e2e
def test_rows_without_their_job_config_are_refused_never_overwritten(rows_only):
    """A job killed before its first checkpoint, its job_config.json deleted, then run with
    another seed: exit 4 naming the file and the remedy, the rows as they were."""
    (rows_only / "job_config.json").unlink()
    rows = (rows_only / "metrics.csv").read_bytes()
    result = run_cli(*BUDGET, "seed=7", run_dir=rows_only)
    assert result.returncode == 4, result.stderr[-2000:]
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith(
        f"error: {rows_only / 'job_config.json'} is damaged: it is missing, and metrics.csv holds 24 rows written "
        "under the config it recorded"), lines
    assert "the rows were left unchanged: restore job_config.json" in lines[0] and "move metrics.csv" in lines[0]
    assert (rows_only / "metrics.csv").read_bytes() == rows
    before = snapshot(rows_only)
    with pytest.raises(DamagedFileError, match="it is missing, and metrics.csv holds 24 rows"):
        train(rows_only)  # the same seed too: nothing tells the rows' config
    assert snapshot(rows_only) == before


@pytest.mark.parametrize("damage", sorted(DAMAGES))
def test_a_damaged_job_config_is_refused_before_a_resume_and_changes_nothing(resumable, damage):
    record = resumable / "job_config.json"
    change, problem = DAMAGES[damage]
    change(record)
    before = snapshot(resumable)
    refused = re.escape(f"{record} is damaged: {problem.format(record='checkpoint.pt')}") + \
        ".*; delete it and run the job again: it is written again from the config its checkpoint.pt records"
    with pytest.raises(DamagedFileError, match=refused):
        train(resumable)
    assert snapshot(resumable) == before


def test_a_deleted_job_config_is_written_again_from_the_checkpoint_with_a_warning(resumable, made, caplog):
    (resumable / "job_config.json").unlink()
    with caplog.at_level(logging.WARNING, logger="sde_torchrl.jobs.run_dir"):
        summary = train(resumable)
    assert [record.getMessage() for record in caplog.records] == [
        f"{resumable / 'job_config.json'} was missing: written again from the config checkpoint.pt records"]
    assert read_job_config(resumable / "job_config.json") == read_job_config(made / "job_config.json")
    assert (resumable / "metrics.csv").read_bytes() == (made / "metrics.csv").read_bytes()
    assert {k: v for k, v in summary.items() if k != "wall_s"} == \
        {k: v for k, v in json.loads((made / "summary.json").read_text()).items() if k != "wall_s"}


@pytest.mark.parametrize("damage", sorted(DAMAGES))
def test_a_finished_job_s_damaged_job_config_is_refused_by_the_job_and_the_reader(finished, damage):
    """Refused by both, naming the file (the job: exit 4), and nothing rewritten: not the
    summary, even with the finished checkpoint there."""
    record = finished / "job_config.json"
    change, problem = DAMAGES[damage]
    change(record)
    before = snapshot(finished)
    refused = re.escape(f"{record} is damaged: {problem.format(record='summary.json')}") + \
        ".*; restore it from where the directory was copied, or delete it: summary.json records"
    with pytest.raises(DamagedFileError, match=refused):
        train(finished)
    assert snapshot(finished) == before
    with pytest.raises(DamagedFileError, match=refused):
        read_finished_run(finished)


@pytest.mark.e2e
def test_a_truncated_job_config_of_a_finished_job_on_the_command_line(finished):
    path = finished / "job_config.json"
    path.write_bytes(path.read_bytes()[:100])
    result = run_cli(*BUDGET, run_dir=finished)
    assert result.returncode == 4, result.stderr[-2000:]
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith(f"error: {path} is damaged: it is not valid JSON ("), lines
