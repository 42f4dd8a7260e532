"""The job's config in one form: built and frozen once at the edge (``validate``), its resolved
dict derived from it, and the run directory the one place that checks "same job?"."""

from __future__ import annotations

import json
from dataclasses import FrozenInstanceError
from pathlib import Path

import pytest
from _helpers import REPO, build, compose_config, crash_at
from omegaconf import OmegaConf

from sde_torchrl.config.schemas.train import validate
from sde_torchrl.jobs.checkpoint import CheckpointMismatchError
from sde_torchrl.jobs.run_dir import RunDirectory

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
    """Nothing there: nothing to refuse; a checkpoint: its config counts, not job_config.json's."""
    assert RunDirectory(tmp_path / "new", {"lr": 0.1}).check_job() is None
    _checkpointed(tmp_path, {"lr": 0.005, "updates": 4})
    (tmp_path / "job_config.json").write_text(json.dumps({"lr": 0.01, "updates": 4}))
    assert RunDirectory(tmp_path, {"lr": 0.005, "updates": 4}).check_job() is None
    with pytest.raises(CheckpointMismatchError, match="written by another config"):
        RunDirectory(tmp_path, {"lr": 0.01, "updates": 4}).check_job()
