"""A stop signal to a sweep reaches the jobs it runs in other processes.

Hydra's joblib launcher runs a sweep's jobs in loky worker processes, children of the process
the user started (the sweep's parent). A scheduler or a user stops the sweep with a signal to
that parent, which would die at once by default while the workers, which nobody signals, would train
on as orphans holding their run directories. So:

- the parent (:func:`handle_in_parent`, for a multirun) takes SIGTERM and SIGUSR2 with
  :func:`forward_to_workers`: with loky workers, it keeps the signal
  (:func:`~sde_torchrl.trainers.interrupt.stop_jobs`) and passes it on to each worker that handles
  it (``SigCgt`` in ``/proc/<pid>/status``: the workers that run a job of this sweep, see below),
  then and every :data:`FORWARD_PERIOD_S` after, so that a worker that takes a job later gets it
  too; the parent waits for the jobs' reports and exits with the signal's code and the resume
  lines (:mod:`sde_torchrl.cli`). A parent that runs its jobs itself (the basic launcher) keeps the signal
  the same way (training stops after its update, no further job starts); one that neither runs
  jobs nor has loky workers (submitit's and Ray's wait on jobs elsewhere) ends as before;
- a worker (:func:`job_started`, at the start of each job) takes the same signals with
  :func:`~sde_torchrl.trainers.interrupt.stop_jobs` where they are at their default (submitit's
  own handlers are left alone): a training job checkpoints after its update and reports itself
  interrupted, a job that has not started does not start. A worker that has not run a job yet
  does not handle the signals, is not sent them (the default would end it, and joblib would then
  end every worker) and, once it takes a job, is sent them like the others.

The parent is known to its workers by :data:`SWEEP_PID` in the environment, which workers
inherit. Linux only (``/proc``); elsewhere the parent stops the sweep's in-process jobs only.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
from pathlib import Path

from sde_torchrl.trainers.interrupt import stop_jobs, stop_requested

log = logging.getLogger(__name__)

#: The signals a sweep's parent passes on to its workers (Ctrl-C reaches them from the terminal).
SWEEP_SIGNALS = (signal.SIGTERM, signal.SIGUSR2)
#: Environment variable holding the pid of the sweep's parent, inherited by its workers.
SWEEP_PID = "SDE_TORCHRL_SWEEP_PID"
#: How often the parent looks for workers that took a job since the signal.
FORWARD_PERIOD_S = 0.2
#: Jobs started in this process (:func:`job_started`).
STARTED = {"jobs": 0}


def handle_in_parent() -> None:
    """Makes this process a sweep's parent: its pid in :data:`SWEEP_PID`, and the stop signals
    taken by :func:`forward_to_workers` (main thread only).

    Examples:
        >>> SWEEP_PID
        'SDE_TORCHRL_SWEEP_PID'
    """
    os.environ[SWEEP_PID] = str(os.getpid())
    if threading.current_thread() is threading.main_thread():
        for signum in SWEEP_SIGNALS:
            signal.signal(signum, forward_to_workers)


def forward_to_workers(signum: int, frame: object) -> None:
    """The parent's handler: the signal passed on to the loky workers, now and as they take jobs,
    and :func:`~sde_torchrl.trainers.interrupt.stop_jobs` for the jobs this process runs itself; a
    process with neither ends by the signal's default, as before."""
    first = stop_requested() is None
    if first and not STARTED["jobs"] and not loky_workers():
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    stop_jobs(signum, frame)
    if first:
        threading.Thread(target=_forward, args=(signum,), name="sweep-stop", daemon=True).start()


forward_to_workers.stops_jobs = True


def _forward(signum: int) -> None:
    """Sends ``signum`` once to each child process that handles it, until this process ends."""
    sent: set[int] = set()
    while True:
        for pid in set(handling_children(signum)) & set(loky_workers()):
            if pid not in sent:
                sent.add(pid)
                try:
                    os.kill(pid, signum)
                except ProcessLookupError:
                    continue
                log.info("%s passed on to the sweep's worker (pid %d)", signal.Signals(signum).name, pid)
        time.sleep(FORWARD_PERIOD_S)


def handling_children(signum: int, parent: int | None = None) -> list[int]:
    """The child processes of ``parent`` (this process) that catch ``signum`` with a handler.

    Examples:
        >>> handling_children(signal.SIGTERM, parent=1 << 30)
        []
    """
    parent = os.getpid() if parent is None else parent
    children = []
    for entry in Path("/proc").glob("[0-9]*"):
        try:
            status = dict(line.split(":", 1) for line in (entry / "status").read_text().splitlines() if ":" in line)
        except OSError:  # ended meanwhile, or no /proc
            continue
        if int(status.get("PPid", "0").strip() or 0) != parent:
            continue
        if int(status.get("SigCgt", "0").strip() or "0", 16) >> (signum - 1) & 1:
            children.append(int(entry.name))
    return children


def loky_workers(parent: int | None = None) -> list[int]:
    """The loky worker processes among the children of ``parent`` (this process).

    Examples:
        >>> loky_workers(parent=1 << 30)
        []
    """
    parent = os.getpid() if parent is None else parent
    workers = []
    for entry in Path("/proc").glob("[0-9]*"):
        try:
            ppid = (entry / "stat").read_text().rsplit(")", 1)[1].split()[1]
            command = (entry / "cmdline").read_bytes()
        except (OSError, IndexError):
            continue
        if int(ppid) == parent and b"popen_loky" in command:
            workers.append(int(entry.name))
    return workers


def in_worker() -> bool:
    """Whether this process is a worker of a sweep's parent (:data:`SWEEP_PID` is its parent).

    Examples:
        >>> in_worker()
        False
    """
    return os.environ.get(SWEEP_PID) == str(os.getppid())


def job_started() -> None:
    """Counts a job started in this process (:data:`STARTED`); in a sweep's worker, takes the
    stop signals left at their default with :func:`~sde_torchrl.trainers.interrupt.stop_jobs`
    (main thread only).

    Examples:
        >>> job_started()  # not a worker: counted only
        >>> STARTED["jobs"] > 0
        True
    """
    STARTED["jobs"] += 1
    if in_worker() and threading.current_thread() is threading.main_thread():
        for signum in SWEEP_SIGNALS:
            if signal.getsignal(signum) in (signal.SIG_DFL, stop_jobs):
                signal.signal(signum, stop_jobs)
