"""Reporting an update as it finishes: the log line, the TorchRL logger's curves, the progress bar."""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from typing import Any

from sde_torchrl.jobs.metrics import logged_values
from sde_torchrl.trainers.progress import Progress, RateMeter

log = logging.getLogger("sde_torchrl.trainers.job")
#: Between evaluations the log still says how far the job is: at least every this many seconds in
#: a session's first minute, then at least every :data:`LATER_LINE_S`.
FIRST_MINUTE_LINE_S, LATER_LINE_S = 10.0, 60.0


class Reporter:
    """Reports each update of a job.

    Args:
        logger: optional TorchRL logger (``log_scalar``) for run-averaged curves: the metrics
            that name a logger key (:func:`~sde_torchrl.jobs.metrics.logged_values`).
        updates: the job's number of updates.
        done: updates already done (a resumed job).
        steps_per_update: env steps of one update (all runs), for the speed figure.
        progress: show a progress bar (:mod:`sde_torchrl.trainers.progress`).
        per_step: the factor to the paper's mean reward per step
            (:func:`~sde_torchrl.trainers.summary.per_step_factor`); unless 1, the log line adds the returns
            in those units.

    Examples:
        >>> import torch
        >>> from sde_torchrl.jobs.metrics import update_statistics
        >>> reporter = Reporter(None, updates=2, done=0, steps_per_update=100)
        >>> reporter.update(0, 10, update_statistics(0, 0, 10, {"return_mean": torch.tensor([-1.0])}, None))
        >>> reporter.close()
    """

    def __init__(self, logger: Any, updates: int, done: int, steps_per_update: int, progress: bool = False,
                 per_step: float = 1.0) -> None:
        self.logger, self.updates, self.steps_per_update = logger, updates, steps_per_update
        self.per_step = per_step
        self.bar = Progress(updates, done, enabled=progress)
        self.rate = RateMeter()
        self.started = self.last_line = time.monotonic()

    def update(self, k: int, step: int, statistics: Mapping[str, Any]) -> None:
        """Update ``k`` (0-based) is done.

        Args:
            k: the update.
            step: the curves' x axis (episodes per run, or env steps, so far).
            statistics: the update's statistics (:func:`~sde_torchrl.jobs.metrics.update_statistics`).
        """
        speed = self.rate.add(self.steps_per_update)
        mean, eval_return = float(statistics["return_mean"].mean()), statistics["eval_return"]
        if self.logger is not None:
            for key, value in logged_values(statistics).items():
                self.logger.log_scalar(key, value, step=step)
        if eval_return is not None:
            evaluation = float(eval_return.mean())
            per_step = "" if self.per_step == 1.0 else \
                f"  (per step: return {mean * self.per_step:.3f}  eval {evaluation * self.per_step:.3f})"
            log.info("update %d/%d  return %.3f  eval %.3f%s  %.0f env steps/s", k + 1, self.updates, mean,
                     evaluation, per_step, speed)
            self.last_line = time.monotonic()
        elif self._line_due():
            per_step = "" if self.per_step == 1.0 else f"  (per step: return {mean * self.per_step:.3f})"
            log.info("update %d/%d  return %.3f%s  %.0f env steps/s", k + 1, self.updates, mean, per_step, speed)
            self.last_line = time.monotonic()
        self.bar.step(mean, speed)

    def _line_due(self) -> bool:
        now = time.monotonic()
        interval = FIRST_MINUTE_LINE_S if now - self.started < 60.0 else LATER_LINE_S
        return now - self.last_line >= interval

    def close(self) -> None:
        """Ends the progress bar."""
        self.bar.close()


def close_logger(logger: Any) -> None:
    """Flushes and closes a TorchRL logger's backend (ends a wandb run, closes event files)."""
    experiment = getattr(logger, "experiment", None)
    for method in ("finish", "close"):  # wandb runs finish; tensorboard writers close
        if callable(getattr(experiment, method, None)):
            getattr(experiment, method)()
            return
