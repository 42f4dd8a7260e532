"""sde_torchrl.jobs.heap: glibc's mmap threshold fixed, so that freed update tensors leave the heap."""

from __future__ import annotations

import ctypes
import subprocess
import sys
import textwrap

import pytest

from sde_torchrl.jobs.heap import fix_mmap_threshold

GLIBC = sys.platform.startswith("linux") and hasattr(ctypes.CDLL(None), "mallinfo2")

#: Frees a 20 MiB mapping (glibc then raises its dynamic threshold to 20 MiB), allocates 2 MiB and
#: prints how many mapped bytes that added: 0 when the 2 MiB came from the heap.
PROBE = textwrap.dedent("""
    import ctypes, sys
    from sde_torchrl.jobs.heap import fix_mmap_threshold
    libc = ctypes.CDLL(None)
    class MallInfo2(ctypes.Structure):
        _fields_ = [(name, ctypes.c_size_t) for name in
                    ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks",
                     "keepcost")]
    libc.mallinfo2.restype = MallInfo2
    libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    if sys.argv[1] == "fixed":
        assert fix_mmap_threshold()
    libc.free(libc.malloc(20 << 20))
    before = libc.mallinfo2().hblkhd
    block = libc.malloc(2 << 20)
    print(libc.mallinfo2().hblkhd - before)
""")


def _mapped_bytes_of_a_2_mib_request(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True)
    return int(out.stdout)


@pytest.mark.skipif(not GLIBC, reason="needs glibc >= 2.33 (mallinfo2) on Linux")
def test_a_fixed_threshold_keeps_megabyte_requests_out_of_the_heap():
    # the dynamic threshold, raised by a freed 20 MiB mapping, serves 2 MiB from the heap ...
    assert _mapped_bytes_of_a_2_mib_request("dynamic") == 0
    # ... the fixed one maps it, and free() will give it back to the system
    assert _mapped_bytes_of_a_2_mib_request("fixed") >= 2 << 20


@pytest.mark.parametrize("threshold", [0, -1, 1.5, "1M"])
def test_a_threshold_that_is_not_a_positive_byte_count_is_refused(threshold):
    with pytest.raises(ValueError, match="positive number of bytes"):
        fix_mmap_threshold(threshold)


def test_without_a_c_library_nothing_is_changed():
    assert fix_mmap_threshold(library="libdoes-not-exist.so.0") is False
