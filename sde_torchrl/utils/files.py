"""Atomic file replacement: a reader (or a resumed job) sees the old complete file or the new one.

Every file a job rewrites (``checkpoint.pt``, ``summary.json``, a ``metrics.csv`` cut back on
resume, the TorchRL logger's CSV files) goes through :func:`write_atomically`: written to
``<name>.tmp``, flushed and fsynced, then renamed over the old file, and the rename made durable.
A write that fails because the device is full raises :class:`DiskFullError`, naming the file
and the remedy, and leaves no temporary file.
"""

from __future__ import annotations

import errno
import io
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any


class DamagedFileError(RuntimeError):
    """A file of a run directory is damaged or unreadable: nothing is resumed from it.

    Args:
        path: the file.
        problem: what is wrong with it.
        remedy: the least destructive way out.

    Examples:
        >>> str(DamagedFileError("run/metrics.csv", "row 3 is cut short", "delete it"))
        'run/metrics.csv is damaged: row 3 is cut short; delete it'
    """

    def __init__(self, path: str | os.PathLike, problem: str, remedy: str) -> None:
        self.path, self.problem, self.remedy = Path(path), problem, remedy
        super().__init__(f"{path} is damaged: {problem}; {remedy}")


class DiskFullError(OSError):
    """A file of a run directory could not be written because its device is full; the file
    was left as it was (no temporary file stays behind).

    Args:
        path: the file.
        free: bytes free on its device after the failed write.

    Examples:
        >>> str(DiskFullError("run/checkpoint.pt", 4096)).split(";")[0]
        'run/checkpoint.pt could not be written: no space left on its device (4 KiB free)'
    """

    def __init__(self, path: str | os.PathLike, free: int) -> None:
        self.path, self.free = Path(path), free
        super().__init__(errno.ENOSPC, f"{path} could not be written: no space left on its device ({free // 1024} KiB "
                                       "free); free some space and run the same command again: the job resumes "
                                       "from its last checkpoint")

    def __str__(self) -> str:
        return self.strerror


#: A failed write on a device with less than this free is taken as a full device (torch.save
#: reports it as ``RuntimeError: ... unexpected pos``, without the system's words).
FULL_BELOW_BYTES = 1 << 20


def as_disk_full(path: str | os.PathLike, error: BaseException) -> BaseException:
    """``error`` as a :class:`DiskFullError` if it came from a full device (``ENOSPC``, or any
    failed write with less than :data:`FULL_BELOW_BYTES` left), else ``error`` itself.

    Examples:
        >>> import tempfile
        >>> type(as_disk_full(tempfile.mkdtemp(), OSError(errno.ENOSPC, "No space left on device"))).__name__
        'DiskFullError'
    """
    if isinstance(error, DiskFullError) or not isinstance(error, Exception):
        return error
    path = Path(path)
    try:
        free = shutil.disk_usage(path if path.is_dir() else path.parent).free
    except OSError:
        return error
    if getattr(error, "errno", None) == errno.ENOSPC or free < FULL_BELOW_BYTES:
        return DiskFullError(path, free)
    return error


def tmp_path(path: Path) -> Path:
    """The temporary name ``path`` is written under before being renamed."""
    return path.with_name(path.name + ".tmp")


def write_atomically(path: str | os.PathLike, write: Callable[[IO[bytes]], Any]) -> None:
    """Calls ``write`` on a temporary binary file, makes it durable and renames it over ``path``.

    Args:
        path: the file to (re)place.
        write: writes the whole content to the open file it is given.

    Examples:
        >>> import tempfile
        >>> target = Path(tempfile.mkdtemp()) / "a.txt"
        >>> write_atomically(target, lambda f: f.write(b"done\\n"))
        >>> target.read_bytes()
        b'done\\n'
    """
    path = Path(path)
    tmp = tmp_path(path)
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
    except BaseException as error:
        tmp.unlink(missing_ok=True)  # the old file stays as it was; no half-written leftover
        full = as_disk_full(path, error)
        if full is not error:
            raise full from error
        raise
    os.replace(tmp, path)
    _sync_directory(path.parent)


def write_json_atomic(path: str | os.PathLike, data: dict) -> None:
    """Writes ``data`` as indented, strict JSON (NaN and infinity raise ``ValueError``), atomically."""

    def write(f: IO[bytes]) -> None:
        text = io.TextIOWrapper(f, encoding="utf-8")
        json.dump(data, text, indent=2, allow_nan=False)
        text.flush()
        text.detach()  # leave the binary file open for write_atomically to sync

    write_atomically(path, write)


def _sync_directory(directory: Path) -> None:
    """Makes a rename in ``directory`` durable, where directories can be opened."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # not everywhere; the rename itself is still atomic
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
