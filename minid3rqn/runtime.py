"""Process-wide speed settings for the command line and the benchmarks.

NumPy allocates a fresh buffer for every temporary array. With glibc's defaults, any
buffer above 128 KiB is mapped from the kernel and unmapped when freed, so the next
op of the same size faults every page in again: for ops on images of a few hundred
KiB this costs more than the arithmetic. ``keep_freed_memory()`` raises glibc's mmap
and trim thresholds so that freed buffers stay in the process and are reused. It only
changes speed, never results, and it does nothing on systems without glibc.
"""
from __future__ import annotations

import ctypes
import ctypes.util

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_done = False


def keep_freed_memory(mmap_threshold: int = 256 * 2**20,
                      trim_threshold: int = 1024 * 2**20) -> bool:
    """Ask glibc to keep freed buffers for reuse; True if it took effect."""
    global _done
    if _done:
        return True
    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    ok = bool(mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold)))
    ok = bool(mallopt(_M_TRIM_THRESHOLD, int(trim_threshold))) and ok
    _done = ok
    return ok
