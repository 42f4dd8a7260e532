"""Keep a long job's heap from growing: glibc's mmap threshold fixed for the job's process.

glibc's ``malloc`` serves a request above its *mmap threshold* with a fresh mapping that ``free``
returns to the system, and anything smaller from its heap. The threshold is dynamic: each freed
mapping raises it (up to 32 MB on 64-bit), so after a few updates the megabyte-sized tensors an
update makes and frees come from the heap, where they fragment it and the process's resident
memory climbs update after update although the tensors are freed. GPOMDP's per-step scores
(``[runs, N, T, K]`` and their partial sums) are such tensors: a 25-run ball-catching job
climbed by about 15 MB per update with the dynamic threshold and stayed flat with it fixed at
1 MiB. Setting the threshold with ``mallopt(M_MMAP_THRESHOLD, ...)`` fixes it (glibc turns the
dynamic adjustment off), as the environment variable ``MALLOC_MMAP_THRESHOLD_`` would from
outside. Elsewhere (macOS, musl, Windows) nothing is changed.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

#: glibc's ``M_MMAP_THRESHOLD`` parameter of ``mallopt`` (``malloc.h``).
M_MMAP_THRESHOLD = -3
#: Requests from 1 MiB up are mapped and unmapped: the tensors of an update, not the small objects.
MMAP_THRESHOLD_BYTES = 1 << 20


def fix_mmap_threshold(threshold: int = MMAP_THRESHOLD_BYTES, library: str | None = None) -> bool:
    """Fix glibc's mmap threshold for this process (see the module docstring).

    Args:
        threshold: requests of at least this many bytes get their own mapping.
        library: the C library to load (``None``: the process's own, on Linux).

    Returns:
        Whether the threshold was set: ``False`` off Linux, or where the C library has no
        ``mallopt`` (not glibc).

    Raises:
        ValueError: for a threshold that is not a positive number of bytes.

    Examples:
        >>> import sys
        >>> fix_mmap_threshold() == sys.platform.startswith("linux")  # glibc here
        True
    """
    if not isinstance(threshold, int) or threshold <= 0:
        raise ValueError(f"threshold must be a positive number of bytes, got {threshold!r}")
    if library is None and not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(library if library is not None else ctypes.util.find_library("c"))
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return mallopt(M_MMAP_THRESHOLD, threshold) == 1
