"""Atomic file replacement: a reader (or a resumed job) sees the old complete file or the new one.

Every file a job rewrites (``checkpoint.pt``, ``summary.json``, a ``metrics.csv`` cut back on
resume, the TorchRL logger's CSV files) goes through :func:`write_atomically`: written to
``<name>.tmp``, flushed and fsynced, then renamed over the old file, and the rename made durable.
A write that fails leaves no temporary file and raises a :class:`FileWriteError` naming the file,
the cause and the remedy (:func:`as_write_failure`): :class:`DiskFullError` for a full device,
:class:`FileSizeLimitError` for the process's file-size limit (``ulimit -f``; Python ignores the
``SIGXFSZ`` that would otherwise kill it, so the write fails with ``EFBIG``, which ``torch.save``
reports as ``unexpected pos`` without the system's words).
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


class FileWriteError(OSError):
    """A file could not be written: the message names it, the cause and the remedy.

    Args:
        path: the file.
        cause: why, in words.
        code: the ``errno`` (``EIO`` when the cause had none, as ``torch.save``'s writer).

    Examples:
        >>> str(FileWriteError("run/summary.json", "Input/output error"))
        'run/summary.json could not be written: Input/output error'
    """

    def __init__(self, path: str | os.PathLike, cause: str, code: int = errno.EIO) -> None:
        self.path = Path(path)
        super().__init__(code, f"{path} could not be written: {cause}")

    def __str__(self) -> str:
        return self.strerror


class FileSizeLimitError(FileWriteError):
    """A file could not be written because it reached the process's file-size limit (``ulimit -f``).

    Args:
        path: the file.
        limit: the limit in bytes.

    Examples:
        >>> str(FileSizeLimitError("run/checkpoint.pt", 204800)).split(";")[0]
        "run/checkpoint.pt could not be written: it reached this process's file-size limit (200 KiB, ulimit -f)"
    """

    def __init__(self, path: str | os.PathLike, limit: int) -> None:
        self.limit = limit
        super().__init__(path, f"it reached this process's file-size limit ({limit // 1024} KiB, ulimit -f); raise "
                               "the limit (ulimit -f unlimited) and run the same command again: the job resumes from "
                               "its last checkpoint", errno.EFBIG)


class DiskFullError(FileWriteError):
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
        self.free = free
        super().__init__(path, f"no space left on its device ({free // 1024} KiB free); free some space and run the "
                               "same command again: the job resumes from its last checkpoint", errno.ENOSPC)


#: A failed write on a device with less than this free is taken as a full device (torch.save
#: reports it as ``RuntimeError: ... unexpected pos``, without the system's words).
FULL_BELOW_BYTES = 1 << 20


#: Words of ``torch.save``'s zip writer when a write under it failed (it does not pass the system's on).
TORCH_WRITER_FAILED = ("inline_container.cc", "PytorchStreamWriter")


def file_size_limit() -> int | None:
    """The process's file-size limit in bytes (``ulimit -f``, ``RLIMIT_FSIZE``), or ``None``: none."""
    try:
        import resource
    except ImportError:  # not on this platform
        return None
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    return None if limit == resource.RLIM_INFINITY else limit


def as_write_failure(path: str | os.PathLike, error: BaseException,
                     written: str | os.PathLike | None = None) -> BaseException:
    """``error``, raised while writing ``path``, as a :class:`FileWriteError` naming the file and
    the cause, or ``error`` itself if it was not a failed write:

    - :class:`FileSizeLimitError`: the process has a file-size limit, and the write failed with
      ``EFBIG`` or the file written (``written``, the temporary file written in ``path``'s place;
      default ``path``) reached the limit;
    - :class:`DiskFullError`: ``ENOSPC``, or any failure with less than :data:`FULL_BELOW_BYTES`
      free on the device;
    - :class:`FileWriteError`: another ``OSError`` that does not name its file, or ``torch.save``'s
      writer failing (:data:`TORCH_WRITER_FAILED`).

    Examples:
        >>> import tempfile
        >>> type(as_write_failure(tempfile.mkdtemp(), OSError(errno.ENOSPC, "No space left on device"))).__name__
        'DiskFullError'
        >>> str(as_write_failure("run/metrics.csv", OSError(errno.EIO, "Input/output error")))
        'run/metrics.csv could not be written: Input/output error'
    """
    if isinstance(error, FileWriteError) or not isinstance(error, Exception):
        return error
    path = Path(path)
    limit, size = file_size_limit(), _size(Path(written) if written is not None else path)
    if limit is not None and (getattr(error, "errno", None) == errno.EFBIG or size is not None and size >= limit):
        return FileSizeLimitError(path, limit)
    try:
        free = shutil.disk_usage(path if path.is_dir() else path.parent).free
    except OSError:
        free = None
    if getattr(error, "errno", None) == errno.ENOSPC or free is not None and free < FULL_BELOW_BYTES:
        return DiskFullError(path, free or 0)
    if isinstance(error, OSError) and error.filename is None:
        return FileWriteError(path, error.strerror or str(error), error.errno or errno.EIO)
    if isinstance(error, RuntimeError) and any(words in str(error) for words in TORCH_WRITER_FAILED):
        return FileWriteError(path, f"torch.save's writer failed ({' '.join(str(error).split())})")
    return error


def as_disk_full(path: str | os.PathLike, error: BaseException) -> BaseException:
    """:func:`as_write_failure` of a file written in place (an appended ``metrics.csv``): a full
    device, the file-size limit or another failed write, named."""
    return as_write_failure(path, error)


def _size(path: Path) -> int | None:
    """``path``'s size in bytes, or ``None`` if it cannot be read."""
    try:
        return path.stat().st_size
    except OSError:
        return None


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
        failure = as_write_failure(path, error, written=tmp)  # before the temporary file, and its size, go
        tmp.unlink(missing_ok=True)  # the old file stays as it was; no half-written leftover
        if failure is not error:
            raise failure from error
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
