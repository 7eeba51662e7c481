"""Keep freed memory for reuse: a speed setting of the C allocator, not of NumPy.

Every NumPy expression allocates its result, and our networks and renderer make many
arrays of 0.1-30 MB per call (a batch of conv patches, a column block of 256 poses).
glibc's malloc, the C allocator on Linux, serves large blocks by mapping fresh pages from
the operating system and, when the top of its heap holds more free memory than a
threshold, hands that memory back. The next call then asks for it again, and the kernel
must fault in and zero every page before NumPy can write to it. With glibc's defaults a
ray cast of 256 poses spends two thirds of its time there; a Q-net training run a few
seconds at its start, until glibc's own adjustment of its thresholds catches up
(docs/results.md, section Speed).

``keep_freed_memory`` raises both thresholds with ``mallopt``, so that blocks up to
``mmap_bytes`` come from the heap and up to ``trim_bytes`` of freed memory stay with the
process for the next call. Results do not change (only where the memory comes from);
the cost is up to ``trim_bytes`` of freed memory held at the top of the heap. ``python -m minid3rqn``
calls it before every command; a script may call it once at its start. On other systems
(macOS, Windows, or Linux with another C library) it does nothing and says so by
returning False; so does it when the environment variable ``MINID3RQN_DEFAULT_MALLOC``
is set to anything but "" or "0" (to compare, or to hand memory back at once):

    MINID3RQN_DEFAULT_MALLOC=1 python -m minid3rqn train-agent ...
"""
from __future__ import annotations

import ctypes
import os
import platform

# The option numbers of mallopt in glibc's <malloc.h>.
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3

MIB = 1 << 20
OPT_OUT = "MINID3RQN_DEFAULT_MALLOC"           # set: leave glibc's defaults


def keep_freed_memory(trim_bytes: int = 128 * MIB, mmap_bytes: int = 32 * MIB) -> bool:
    """Ask glibc to keep up to ``trim_bytes`` of freed memory and to serve blocks up to
    ``mmap_bytes`` from its heap. Returns True when both settings took effect, False
    where there is no glibc or the environment opts out (nothing is changed then). Safe
    to call more than once."""
    for name, value in (("trim_bytes", trim_bytes), ("mmap_bytes", mmap_bytes)):
        if isinstance(value, bool) or not isinstance(value, int) or not 0 < value < 2 ** 31:
            raise ValueError(f"keep_freed_memory: {name} must be an int in (0, 2**31) "
                             f"bytes; got {value!r}")
    if os.environ.get(OPT_OUT, "") not in ("", "0"):
        return False
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    # The mmap threshold first: glibc refuses one above its limit (then nothing has
    # changed), and a raised trim threshold alone would be slower than the defaults (it
    # switches off glibc's own adjustment of the mmap threshold).
    if not mallopt(M_MMAP_THRESHOLD, mmap_bytes):
        return False
    return bool(mallopt(M_TRIM_THRESHOLD, trim_bytes))
