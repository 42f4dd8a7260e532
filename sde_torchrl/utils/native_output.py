"""Silencing what native libraries print on the process's standard output: pybullet writes an
``argv[0]=`` line whenever a simulator connects, one per env, which would bury a job's progress.
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["native_stdout_silenced"]


@contextmanager
def native_stdout_silenced() -> Iterator[None]:
    """Inside the block, what C code writes to file descriptor 1 is dropped; Python's own
    ``print`` and logging are not affected once the block ends (both are flushed around it).

    Examples:
        >>> with native_stdout_silenced():
        ...     _ = os.write(1, b"dropped")
    """
    sys.stdout.flush()
    try:
        saved = os.dup(1)
    except OSError:  # no standard output to silence
        yield
        return
    libc = ctypes.CDLL(None)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        libc.fflush(None)
        os.dup2(devnull, 1)
        yield
    finally:
        libc.fflush(None)  # C's buffered output goes to /dev/null, not to the restored stdout
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)
