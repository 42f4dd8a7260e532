"""One training job in its run directory: the loop every trainer runs.

A trainer says how it does one update, how it evaluates, what its checkpoint holds besides its
modules and what its summary reports; :class:`Job` does the rest, the same way for each:
the run directory held and checked (:mod:`~sde_torchrl.jobs.run_dir`), a finished job left as it
is, a checkpoint resumed, then updates with periodic evaluations, one ``metrics.csv`` row per run
and update, checkpoints, the best policy (:mod:`~sde_torchrl.trainers.best`), the final check and
the summary. The trainers: :class:`~sde_torchrl.trainers.trainer.Trainer` (the episodic
estimators), :class:`~sde_torchrl.trainers.onpolicy.OnPolicyTrainer` (PPO, A2C) and
:class:`~sde_torchrl.trainers.offpolicy.SACTrainer` (SAC).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from abc import ABC, abstractmethod
from typing import Any, Protocol

import torch
from torch import nn

from sde_torchrl.jobs.checkpoint import restore_job, result_config, save_job
from sde_torchrl.jobs.metrics import MetricRow, metric_rows, recorded_rows, update_statistics
from sde_torchrl.jobs.run_dir import FinishedRun, RunDirectory
from sde_torchrl.trainers.best import BEST_POLICY, BestPolicy, write_best_policy
from sde_torchrl.trainers.guard import EPISODIC_REMEDY, check_finite
from sde_torchrl.trainers.interrupt import DeferredInterrupt
from sde_torchrl.trainers.report import Reporter, close_logger
from sde_torchrl.trainers.summary import LoopState, best_and_checked, final_levels

log = logging.getLogger(__name__)


class JobSettings(Protocol):
    """What the loop reads of a trainer's settings."""

    updates: int
    eval_period: int
    first_run: int
    final_episodes: int


class Job(ABC):
    """A training job: the trainer's part (the abstract methods) and the loop that runs it (:meth:`train`).

    Attributes a trainer sets: ``settings`` (:class:`JobSettings`), ``runs`` (learners side by
    side), ``logger`` (a TorchRL logger or ``None``), ``optimizer`` (what a checkpoint saves of the
    optimisation) and ``best`` (:class:`~sde_torchrl.trainers.best.BestPolicy`).
    """

    settings: JobSettings
    runs: int
    logger: Any
    optimizer: Any
    best: BestPolicy
    #: What a non-finite stop advises (:class:`~sde_torchrl.trainers.guard.NonFiniteError`): settings of the job.
    nonfinite_remedy: str = EPISODIC_REMEDY
    #: A session whose first update takes longer than this many seconds says what it is doing
    #: (:meth:`first_update_notice`; a job is silent until its first update ends).
    first_update_notice_s: float = 10.0
    #: Entries of a checkpoint's ``loop`` that the trainer saves and restores itself.
    checkpoint_extras: tuple[str, ...] = ()

    # ------------------------------------------------------------------ the trainer's part
    @abstractmethod
    def update(self, k: int) -> dict[str, torch.Tensor]:
        """Update ``k`` (0-based): collect, estimate, step; the statistics of its rows, each ``[runs]``
        (``return_mean``, ``grad_norm``; ``exploration`` ``[3, runs]``), checked finite."""

    @abstractmethod
    def evaluate(self) -> torch.Tensor:
        """Mean deterministic return per run, ``[runs]``."""

    @abstractmethod
    def episodes_after(self, k: int) -> int:
        """Training episodes each run has by the end of update ``k`` (``metrics.csv``'s ``episodes``)."""

    @abstractmethod
    def logged_step(self, updates: int) -> int:
        """The logger's step after ``updates`` updates (0 before the first)."""

    @abstractmethod
    def make_reporter(self, done: int, progress: bool) -> Reporter:
        """The session's reporter, ``done`` updates into the job."""

    @abstractmethod
    def checkpointed(self) -> tuple[nn.Module, dict[str, Any]]:
        """The modules a checkpoint saves, and the random streams it carries
        (:func:`~sde_torchrl.jobs.checkpoint.job_streams`)."""

    @abstractmethod
    def final_check(self, run_dir: RunDirectory) -> dict[str, Any]:
        """The final and the best policies on ``final_episodes`` fresh episodes
        (:func:`~sde_torchrl.trainers.final_check.run_final_check`)."""

    @abstractmethod
    def summarize(self, state: LoopState) -> dict[str, Any]:
        """What ``summary.json`` says of the finished loop."""

    @abstractmethod
    def close(self) -> None:
        """Closes the envs (their simulators), so that a worker running job after job does not keep them."""

    @abstractmethod
    def save_extras(self, state: LoopState) -> dict[str, Any]:
        """What the checkpoint's ``loop`` holds besides ``state`` (keys :attr:`checkpoint_extras`)."""

    @abstractmethod
    def restore_extras(self, extras: dict[str, Any], state: LoopState) -> None:
        """Puts back what :meth:`save_extras` saved, once ``state`` is restored."""

    def ends_early(self, state: LoopState, stats: dict[str, torch.Tensor]) -> bool:
        """Whether the job ends after the update of ``stats`` (before its last); tracks ``state.reached``."""
        return False

    def check_evaluation(self, k: int, returns: torch.Tensor) -> torch.Tensor:
        """The evaluation after update ``k``, if finite (else :class:`~sde_torchrl.trainers.guard.NonFiniteError`)."""
        check_finite(k, "evaluation return", returns, self.runs, self.settings.first_run, self.nonfinite_remedy)
        return returns

    def first_update_notice(self, update: int) -> str | None:
        """What a session's first update does, said if it runs long (``None``: nothing)."""
        return None

    # ------------------------------------------------------------------ the job
    def train(
        self, out_dir: str | os.PathLike, labels: dict[str, Any] | None = None, *,
        checkpoint_period: int = 0, progress: bool = False,
    ) -> dict[str, Any]:
        """Runs the job (or resumes it) and writes ``metrics.csv``, ``checkpoint.pt``,
        ``summary.json`` (and ``best_policy.pt``).

        The job holds ``out_dir`` (:meth:`RunDirectory.lock`) until it returns. If ``out_dir``
        holds a checkpoint, the job resumes from it: ``metrics.csv`` is checked against it, cut
        back to the checkpointed update and continued, and every random stream continues where
        it was, so the outputs equal those of an uninterrupted job. A finished job is final
        (:meth:`RunDirectory.check_job`): if its files agree nothing is changed and its summary
        is returned; a finished checkpoint whose summary is missing or disagrees with it only
        rewrites the summary, once ``metrics.csv`` is checked.

        Args:
            out_dir: the run directory.
            labels: entries that head ``summary.json`` (config choices, seed, the config); its
                ``config``, the job's resolved config, is the job's identity: the run directory
                records it and refuses a job of another config. Without it nothing is checked.
            checkpoint_period: also checkpoint every this many updates (0: only at the end and
                on a stop signal).
            progress: show a progress bar (:mod:`sde_torchrl.trainers.progress`).

        Returns:
            The summary (also written to ``summary.json``).

        Raises:
            NonFiniteError: a non-finite value; ``metrics.csv`` keeps the updates before it.
            TrainingInterrupted: on Ctrl-C, SIGTERM or SIGUSR2, after saving a checkpoint
                (:mod:`~sde_torchrl.trainers.interrupt`).
            CheckpointMismatchError: ``out_dir`` holds another job's checkpoint, or another
                config's finished job.
            RunDirectoryInUse: another process holds ``out_dir`` (nothing is changed).
            DamagedFileError: ``checkpoint.pt`` or ``metrics.csv`` is damaged (nothing is resumed),
                or the files of a finished job without a checkpoint disagree.
        """
        run_dir = RunDirectory(out_dir, result_config((labels or {}).get("config")))
        with run_dir.lock():
            done = run_dir.check_job()
            if done is not None:
                log.info("%s", finished_line(done))
                return done.summary
            state = self.resume(run_dir)
            try:
                if not state.finished:
                    self.run_updates(run_dir, state, checkpoint_period, progress)
            finally:
                close_logger(self.logger)
            if state.best is not None:
                write_best_policy(run_dir.path / BEST_POLICY, state.best)
            summary = {**(labels or {}), **self.summarize(state), **best_and_checked(state)}
            summary = run_dir.write_summary({**summary, **final_levels(summary, state)})
        log.info("results in %s", run_dir.path.resolve())
        return summary

    def run_updates(self, run_dir: RunDirectory, state: LoopState, period: int, progress: bool) -> None:
        """Updates from ``state.update`` to the end: update, evaluate, record, checkpoint; the final check."""
        s = self.settings
        session_start, session_wall = time.perf_counter(), state.wall_s
        reporter = self.make_reporter(state.update, progress)
        notice = self._notice(state.update)
        with run_dir.open_metrics(self.recorded_rows(state)) as metrics, DeferredInterrupt() as interrupt:
            try:
                for k in range(state.update, s.updates):
                    stats = self.update(k)
                    notice.cancel()
                    state.add(stats)
                    is_last = self.ends_early(state, stats) or k == s.updates - 1
                    eval_return = None
                    if is_last or (s.eval_period and (k + 1) % s.eval_period == 0):
                        eval_return = state.evals[k] = self.check_evaluation(k, self.evaluate())
                        self.best.observe(k, eval_return)
                    statistics = update_statistics(s.first_run, k, self.episodes_after(k), stats, eval_return)
                    metrics.write(metric_rows(statistics))
                    state.update, state.finished = k + 1, is_last
                    state.wall_s = session_wall + time.perf_counter() - session_start
                    reporter.update(k, self.logged_step(k + 1), statistics)
                    if is_last:
                        break
                    if interrupt.requested or (period and state.update % period == 0):
                        metrics.sync()
                        self.save(run_dir, state)
                    if interrupt.requested:
                        interrupt.stop(state.update, run_dir.path)
            finally:
                notice.cancel()
                reporter.close()
            metrics.sync()
            if s.final_episodes and state.finished:
                state.final_check = self.final_check(run_dir)
        self.save(run_dir, state)

    def save(self, run_dir: RunDirectory, state: LoopState) -> None:
        """Checkpoints the job where ``state`` stands."""
        state.best = self.best.state_dict()
        extras = self.save_extras(state)
        modules, streams = self.checkpointed()
        save_job(run_dir.checkpoint, config=run_dir.config, loop={**state.state_dict(), **extras}, policy=modules,
                 optimizer=self.optimizer, streams=streams)

    def resume(self, run_dir: RunDirectory) -> LoopState:
        """A fresh :class:`LoopState`, or the checkpointed one with everything restored."""
        if not run_dir.has_checkpoint():
            run_dir.start_new_job()
            return LoopState(update=0, reached=torch.zeros(self.runs, dtype=torch.bool))
        modules, streams = self.checkpointed()
        loop = restore_job(run_dir.checkpoint, policy=modules, optimizer=self.optimizer, streams=streams,
                           updates=self.settings.updates)
        extras = {key: loop.pop(key) for key in self.checkpoint_extras}
        state = LoopState.from_state_dict(loop)
        self.restore_extras(extras, state)
        run_dir.check_metrics(self.recorded_rows(state), state.finished)
        if state.best is not None:
            self.best.load_state_dict(state.best)
        run_dir.clear_error()
        if state.finished:
            log.info("%s holds a finished job whose summary.json is missing or disagrees with its checkpoint: "
                     "rewritten from it", run_dir.path)
        else:  # an earlier session's summary (a checkpoint replaced by an older one) goes
            run_dir.summary.unlink(missing_ok=True)
            run_dir.truncate_logger_csv(self.logged_step(state.update))
            log.info("resuming %s after update %d of %d", run_dir.path, state.update, self.settings.updates)
        return state

    def recorded_rows(self, state: LoopState) -> list[MetricRow]:
        """The ``metrics.csv`` rows of the updates ``state`` holds (what a checkpoint recorded)."""
        return recorded_rows(state.record(), self.settings.first_run, self.episodes_after)

    def _notice(self, update: int) -> threading.Timer:
        """A timer that logs :meth:`first_update_notice` if the session's first update runs long
        (started only where the trainer has a notice; cancelling an unstarted one is harmless)."""
        text = self.first_update_notice(update)
        notice = threading.Timer(self.first_update_notice_s, log.info, [text])
        notice.daemon = True
        if text:
            notice.start()
        return notice


def finished_line(job: FinishedRun) -> str:
    """The one line that reports a finished job found in its directory, and the choices left.

    Examples:
        >>> from pathlib import Path
        >>> finished_line(FinishedRun(Path("runs/a"), {"runs": 2, "updates_done": 12}, []))  # doctest: +ELLIPSIS
        'runs/a holds a finished job (12 updates of 2 runs): nothing was changed; a finished job is final: ...'
    """
    return (f"{job.path} holds a finished job ({job.summary['updates_done']} updates of {job.summary['runs']} runs): "
            "nothing was changed; a finished job is final: to train with other settings (more updates, say), give "
            "the job another directory; to train this one again from the start, remove its directory first")


__all__ = ["Job", "JobSettings", "finished_line"]
