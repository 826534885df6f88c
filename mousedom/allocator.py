"""Keep freed memory for reuse in the commands that stream whole captures.

glibc's malloc hands a block over 128 kB to mmap, and gives the top of its heap back to the
kernel once more than 128 kB of it is free; it raises both thresholds only when it sees a
large mmap'd block freed, and trimming undoes the gain.  A replay allocates and frees
arrays of a few hundred kB for every block it reads, so each block's arrays land on fresh
pages, and every page is a fault when first written.  Measured on this project's 2-vCPU VM
(bench/replay.py's one-minute capture): about 5,000 faults a replay, and the vectorised
floor ran in half the time without them, where a fault costs 2 to 3 us.

``keep_freed_memory`` fixes both thresholds high, so freed arrays are reused from the heap.
It does not raise the peak: memory a replay frees is reused by the next block rather than
returned and asked for again.  Batch commands call it; the daemon does not (it allocates
little, and a service should give memory back).  On a C library without ``mallopt``
(musl) it does nothing.
"""

from __future__ import annotations

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 << 20  # glibc's largest (64-bit): bigger blocks are still mmap'd
TRIM_THRESHOLD = 256 << 20

_done = False


def keep_freed_memory() -> bool:
    """Set malloc's thresholds once per process; True if the C library took them."""
    global _done
    if _done:
        return True
    import ctypes  # here, not at import: every CLI start imports the commands

    try:
        # The process's own symbols (dlopen(NULL)): the C library Python runs on, found
        # without ctypes.util.find_library's subprocesses.
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    _done = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )
    return _done
