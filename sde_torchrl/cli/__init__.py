"""The training command (``sde-train``, ``python -m sde_torchrl``, the clone's ``train.py``): its
entry point :func:`cli` (:mod:`~sde_torchrl.cli.main`), one job (:mod:`~sde_torchrl.cli.job`), the
jobs' reports to the command (:mod:`~sde_torchrl.cli.reports`, :mod:`~sde_torchrl.cli.callbacks`),
its one-line errors and exit codes (:mod:`~sde_torchrl.cli.errors`) and its last lines
(:mod:`~sde_torchrl.cli.outcome`). It stands above the rest of the package and imports no torch
until a job holds its run directory."""

from __future__ import annotations

from sde_torchrl.cli.main import cli

__all__ = ["cli"]
