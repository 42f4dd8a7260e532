"""One process per run directory: an OS file lock on ``<run dir>/.lock``, held for the job's life.

The lock is ``fcntl.flock`` on the open file: the OS releases it when the process ends, however
it ends (a ``kill -9`` leaves no stale lock), and a second process asking for it is refused at
once. The holder writes its pid into the file, for the refusal message, and empties it on
release. The file itself stays (removing it would let two processes lock two different files).

This module uses the standard library only: ``train.py`` takes the lock before importing torch,
so that a second command on a live run directory is refused in about a second and changes
nothing.
"""

from __future__ import annotations

import fcntl
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sde_torchrl.utils.checks import ArgumentError

LOCK = ".lock"

#: Run directories this process holds: resolved path → (pid, descriptor, depth). Nested holds
#: (``train.py`` around :meth:`~sde_torchrl.trainers.trainer.Trainer.train`) share the one lock.
_HELD: dict[Path, tuple[int, int, int]] = {}


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
    held = _HELD.get(key)
    if held is not None and held[0] == os.getpid():
        _HELD[key] = (held[0], held[1], held[2] + 1)
        try:
            yield
        finally:
            pid, fd, depth = _HELD[key]
            _HELD[key] = (pid, fd, depth - 1)
        return
    fd = _acquire(key)
    _HELD[key] = (os.getpid(), fd, 1)
    try:
        yield
    finally:
        del _HELD[key]
        os.ftruncate(fd, 0)  # no pid: nobody holds it
        os.close(fd)  # releases the lock


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

    Examples:
        >>> import tempfile
        >>> directory = tempfile.mkdtemp()
        >>> held_by(directory) is None
        True
    """
    lock = Path(path) / LOCK
    if not lock.exists():
        return None
    fd = os.open(lock, os.O_RDONLY | os.O_CLOEXEC)
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return _holder(fd)
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _acquire(directory: Path) -> int:
    """Opens ``directory/.lock``, locks it without waiting and writes this process's pid."""
    fd = os.open(directory / LOCK, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = _holder(fd)
        os.close(fd)
        raise RunDirectoryInUse(directory, holder) from None
    except BaseException:
        os.close(fd)
        raise
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd


def _holder(fd: int) -> str:
    """The pid the holder wrote (it may be writing it this instant: a short wait)."""
    for _ in range(20):
        text = os.pread(fd, 64, 0).decode(errors="replace").strip()
        if text:
            return text
        time.sleep(0.01)
    return "unknown"
