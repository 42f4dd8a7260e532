"""Stopping a job cleanly: Ctrl-C, a scheduler's SIGTERM, or the signal submitit sends before a
Slurm time limit or at preemption (SIGUSR2): finish the current update, save a checkpoint, then
stop, or hand over to the handler that was there before.

After the checkpoint, a signal whose earlier handler was Python's (submitit's requeue on
SIGUSR2, which exits the process; submitit's logging of SIGTERM, which returns) is passed on to
it, and training goes on if it returns; a signal that would have ended the process (Ctrl-C, or a
default SIGTERM / SIGUSR2) raises :class:`TrainingInterrupted`, whose ``exit_code`` is the
shell's: 130 for Ctrl-C, ``128 + signal number`` otherwise (143 for SIGTERM).

A process that runs several jobs (a sweep's parent, joblib's workers: :mod:`sde_torchrl.trainers.sweep_stop`)
handles the stop signals between trainings with :func:`stop_jobs`: the signal is kept
(:data:`PENDING`), the next training checkpoints after its first update and stops, and a job that
has not started yet does not start; such a handler is never passed a signal to "go on" after.
"""

from __future__ import annotations

import logging
import signal
import threading
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

#: The signals that stop a job cleanly.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGUSR2)
#: The stop signal this process received outside training (:func:`stop_jobs`), under ``"signum"``.
PENDING: dict[str, int] = {}


def stop_jobs(signum: int, frame: Any) -> None:
    """Handler of a process that runs jobs one after another: keeps the stop signal, so that
    training stops after its next update (with a checkpoint) and no further job starts.

    Examples:
        >>> stop_jobs.stops_jobs
        True
    """
    if "signum" not in PENDING:
        PENDING["signum"] = signum
        log.warning("%s: the running job checkpoints after its update and stops; no further job starts",
                    signal.Signals(signum).name)


stop_jobs.stops_jobs = True  # DeferredInterrupt raises after its checkpoint instead of going on


def stop_requested() -> int | None:
    """The stop signal this process received outside training (:func:`stop_jobs`), if any.

    Examples:
        >>> stop_requested() is None
        True
    """
    return PENDING.get("signum")


class TrainingInterrupted(KeyboardInterrupt):
    """A stop signal during training: a checkpoint was saved after the last finished update.

    Args:
        updates_done: updates done (the checkpoint's).
        out_dir: the run directory.
        signum: the signal (``SIGINT`` for Ctrl-C).

    Examples:
        >>> stop = TrainingInterrupted(12, Path("run"), signal.SIGTERM)
        >>> stop.signal_name, stop.exit_code
        ('SIGTERM', 143)
    """

    def __init__(self, updates_done: int, out_dir: Path, signum: int = signal.SIGINT) -> None:
        self.updates_done, self.out_dir, self.signum = updates_done, out_dir, signum
        super().__init__(f"{self.signal_name} after update {updates_done}; checkpoint saved in {out_dir}")

    @property
    def signal_name(self) -> str:
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """130 for Ctrl-C (as a shell reports it), ``128 + signal number`` for the others."""
        return 130 if self.signum == signal.SIGINT else 128 + self.signum


class DeferredInterrupt:
    """Turns the first stop signal into a request the loop honours after the current update
    (:data:`STOP_SIGNALS`); a second Ctrl-C interrupts at once, a repeated SIGTERM or SIGUSR2
    is only logged. A no-op outside the main thread.

    Examples:
        >>> with DeferredInterrupt() as interrupt:
        ...     interrupt.requested
        False
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    @property
    def requested(self) -> bool:
        """A stop signal arrived since the last :meth:`stop`."""
        return self.signum is not None

    def _handle(self, signum: int, frame: Any) -> None:
        name = signal.Signals(signum).name
        if self.signum is not None:
            if signum == signal.SIGINT == self.signum:
                raise KeyboardInterrupt
            log.warning("%s again: the checkpoint after this update is on its way", name)
            return
        self.signum = signum
        again = " (Ctrl-C again to abort now)" if signum == signal.SIGINT else ""
        log.warning("%s: saving a checkpoint after this update%s", "Ctrl-C" if signum == signal.SIGINT else name,
                    again)

    def stop(self, updates_done: int, out_dir: Path) -> None:
        """Called once the checkpoint after update ``updates_done`` is saved: raises
        :class:`TrainingInterrupted`, or passes the signal on to the earlier Python handler
        (which may exit; if it returns, training goes on)."""
        signum, self.signum = self.signum, None
        previous = self._previous.get(signum)
        log.warning("%s: checkpoint after update %d saved in %s", signal.Signals(signum).name, updates_done, out_dir)
        if getattr(previous, "stops_jobs", False):  # a sweep's process: no further job either
            previous(signum, None)
        elif callable(previous) and previous is not signal.default_int_handler:
            previous(signum, None)
            return
        if previous is signal.SIG_IGN:
            return
        raise TrainingInterrupted(updates_done, out_dir, signum)

    def __enter__(self) -> DeferredInterrupt:
        if threading.current_thread() is threading.main_thread():
            self._previous = {signum: signal.signal(signum, self._handle) for signum in STOP_SIGNALS}
            pending = stop_requested()
            if pending is not None and getattr(self._previous.get(pending), "stops_jobs", False):
                self.signum = pending  # it arrived before training: stop after the first update
                log.warning("%s arrived before training: a checkpoint after its first update",
                            signal.Signals(pending).name)
        return self

    def __exit__(self, *exc: Any) -> None:
        for signum, previous in self._previous.items():
            signal.signal(signum, previous if previous is not None else signal.SIG_DFL)
        self._previous = {}
