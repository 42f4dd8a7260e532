"""One process per run directory: an OS file lock on ``<run dir>/.lock``, held for the job's life.

Holding is the ``filelock`` package's :class:`~filelock.FileLock` (``fcntl.flock`` on Unix): the OS
releases it when the process ends, however it ends (a ``kill -9`` leaves no stale lock), a second
process asking for it is refused at once (``blocking=False``), nested holds in one process share
the one lock (``is_singleton=True``, its hold counter), and a process forked while holding it does
not keep it alive after the holder has died (filelock closes the inherited descriptor in the
child). Two things are ours, because filelock has neither: the holder's pid, written into the
file for the refusal message (``on_acquired``) and emptied on release, and :func:`held_by`, a
probe (a shared ``flock``) that takes no lock a job could be refused by and writes nothing. The
file itself stays (``preserve_lock_file=True``: removing it would let two processes lock two
different files).

This module imports neither torch nor anything that does: ``train.py`` takes the lock before
importing torch, so that a second command on a live run directory is refused in about a second
and changes nothing.
"""

from __future__ import annotations

import fcntl
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from filelock import FileLock, Timeout

from sde_torchrl.utils.checks import ArgumentError

LOCK = ".lock"


class RunDirectoryInUse(RuntimeError):
    """Another live process holds the run directory.

    Examples:
        >>> str(RunDirectoryInUse("runs/a", "4242")).split(":")[0]
        'runs/a is in use by another process (pid 4242)'
    """

    def __init__(self, path: str | os.PathLike, holder: str) -> None:
        self.path, self.holder = Path(path), holder
        super().__init__(
            f"{path} is in use by another process (pid {holder}): it was left unchanged; wait for "
            "that process to end, or give this job another run directory"
        )


@contextmanager
def hold_run_directory(path: str | os.PathLike) -> Iterator[None]:
    """Holds the run directory ``path`` (created if missing) for the ``with`` block.

    Args:
        path: the run directory.

    Raises:
        RunDirectoryInUse: another process holds it (nothing in ``path`` is changed).
        ArgumentError: ``path`` is a file.
        OSError: ``path`` cannot be created or its lock file opened (a read-only directory).

    Examples:
        >>> import tempfile
        >>> directory = tempfile.mkdtemp()
        >>> with hold_run_directory(directory):
        ...     with hold_run_directory(directory):  # the same process: nested, no conflict
        ...         pass
    """
    key = Path(path).resolve()
    make_run_directory(path)
    lock = _run_lock(key)
    try:
        lock.acquire()
    except Timeout:
        raise RunDirectoryInUse(key, _holder(key / LOCK)) from None
    try:
        yield
    finally:
        if lock.lock_counter == 1:  # the outermost hold ends: no pid left, nobody holds it
            os.truncate(key / LOCK, 0)
        lock.release()


def make_run_directory(path: str | os.PathLike) -> Path:
    """Creates the run directory ``path`` (and its parents) if missing.

    Raises:
        ArgumentError: ``path`` is a file.

    Examples:
        >>> import tempfile
        >>> make_run_directory(Path(tempfile.mkdtemp()) / "a" / "b").is_dir()
        True
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ArgumentError("run directory", str(path), "a directory; this path is a file (give the job another "
                                                        "hydra.run.dir, or hydra.sweep.dir for a sweep)")
    path.mkdir(parents=True, exist_ok=True)
    return path


def held_by(path: str | os.PathLike) -> str | None:
    """The pid of the live process that holds the run directory ``path``, or ``None`` (also
    for a directory without a lock file); nothing is written, and no lock is kept.

    A shared ``flock`` on a read-only descriptor: it contends with the holder's exclusive lock
    but not with other probes (filelock's locks and :func:`filelock.lock_descriptor` are
    exclusive, and opening a :class:`~filelock.FileLock` creates the file).

    Examples:
        >>> import tempfile
        >>> directory = tempfile.mkdtemp()
        >>> held_by(directory) is None
        True
        >>> with hold_run_directory(directory):
        ...     held_by(directory) == str(os.getpid())
        True
    """
    lock = Path(path) / LOCK
    if not lock.exists():
        return None
    fd = os.open(lock, os.O_RDONLY | os.O_CLOEXEC)
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return _holder(lock)
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _run_lock(directory: Path) -> FileLock:
    """The lock of ``directory``: one instance per path in this process, so holds nest."""
    return FileLock(directory / LOCK, mode=0o644, blocking=False, is_singleton=True, thread_local=False,
                    preserve_lock_file=True, on_acquired=_write_pid)


def _write_pid(fd: int) -> None:
    """Writes this process's pid into the lock file just acquired (filelock's ``on_acquired``)."""
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)


def _holder(lock: Path) -> str:
    """The pid the holder wrote (it may be writing it this instant: a short wait)."""
    for _ in range(20):
        try:
            text = lock.read_bytes()[:64].decode(errors="replace").strip()
        except FileNotFoundError:
            text = ""
        if text:
            return text
        time.sleep(0.01)
    return "unknown"
