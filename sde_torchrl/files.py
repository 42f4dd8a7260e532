"""Atomic file replacement: a reader (or a resumed job) sees the old complete file or the new one.

Every file a job rewrites (``checkpoint.pt``, ``summary.json``, a ``metrics.csv`` cut back on
resume, the TorchRL logger's CSV files) goes through :func:`write_atomically`: written to
``<name>.tmp``, flushed and fsynced, then renamed over the old file, and the rename made durable.
"""

from __future__ import annotations

import io
import json
import os
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
    except BaseException:
        tmp.unlink(missing_ok=True)  # the old file stays as it was; no half-written leftover
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
