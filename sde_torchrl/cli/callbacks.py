"""The Hydra callback through which the command learns, at multirun start, what only the sweep's
process knows then: the sweep's directory (where the jobs leave their reports, and what the
resume line of a stopped sweep names).

Registered under ``hydra.callbacks`` in the package's ``conf/config.yaml``; Hydra instantiates it.
It writes into the invocation's reports directory (:class:`~sde_torchrl.cli.reports.Reports`)
named by :data:`~sde_torchrl.cli.reports.REPORTS_ENV`, and does nothing when Hydra runs without
the command (no such variable).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from sde_torchrl.cli.reports import REPORTS_ENV, Reports, Sweep


class SweepStart(Callback):
    """Records the sweep's directory for the command (:meth:`Reports.note_sweep`)."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        directory = os.environ.get(REPORTS_ENV)
        if directory:
            Reports(Path(directory)).note_sweep(Sweep(str(config.hydra.sweep.dir), str(config.hydra.runtime.cwd)))
