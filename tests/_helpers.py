"""Helpers shared by the tests of the training entry points (not a test module)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: Lines some native extensions print on import (pybullet's build banner), not ours.
FOREIGN_STDERR = ("pybullet build time",)


def compose_config(*overrides: str):
    """The composed config for ``overrides``, as ``train.py`` would see it."""
    from sde_torchrl.config.compose import compose

    return compose(overrides)


def build(*overrides: str):
    """A trainer for the minimise experiment with ``overrides`` and no TorchRL logger."""
    from sde_torchrl.config.build import build_trainer

    return build_trainer(compose_config("+experiment=minimize", "logger=none", *overrides))


def train_command(*overrides: str, run_dir: Path, multirun: bool = False) -> list[str]:
    """``python train.py [-m] overrides hydra.(run|sweep).dir=run_dir``."""
    key = "hydra.sweep.dir" if multirun else "hydra.run.dir"
    return [sys.executable, "train.py", *(["-m"] if multirun else []), *overrides, f"{key}={run_dir}"]


def run_cli(*overrides: str, run_dir: Path, multirun: bool = False, timeout: float = 300):
    """Runs ``train.py`` to completion; returns the ``CompletedProcess`` (text output)."""
    return subprocess.run(train_command(*overrides, run_dir=run_dir, multirun=multirun), cwd=REPO,
                          capture_output=True, text=True, timeout=timeout)


def own_stderr_lines(stderr: str) -> list[str]:
    """Non-empty stderr lines, without other libraries' import banners."""
    return [line for line in stderr.splitlines() if line.strip() and not line.startswith(FOREIGN_STDERR)]


def read_rows(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


def summary_without_wall(run_dir: Path) -> dict:
    summary = json.loads((run_dir / "summary.json").read_text())
    assert isinstance(summary.pop("wall_s"), float)
    return summary


class Crash(RuntimeError):
    """Stands in for a kill: raised from inside the training loop."""


def crash_at(trainer, at: int) -> None:
    """Makes ``trainer`` raise :class:`Crash` when it starts update ``at``."""
    original = trainer.update

    def crashing_update(k):
        if k == at:
            raise Crash(f"crash at {k}")
        return original(k)

    trainer.update = crashing_update


def sde_policy(actor, action_dim: int, feature_dim: int, *, squash: bool = False, **sde_options):
    """``(policy, sde)``: the SDE policy over ``actor`` as the trainer builds it
    (``make_sde_actor`` with ``SDEParams(action_dim, feature_dim, **sde_options)``; ``squash`` is
    tanh onto ``[-1, 1]``). Append ``sde.make_tensordict_primer()`` to the env."""
    from sde_torchrl import SDEParams, make_sde_actor

    sde = SDEParams(action_dim, feature_dim, **sde_options)
    return make_sde_actor(actor, sde, squash=squash, low=-1.0, high=1.0), sde
