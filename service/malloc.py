"""glibc's allocator set up for the service, on import, before any thread starts (the
service program imports this first; NumPy's import starts one, and glibc fixes its number
of arenas when a second thread first allocates).

One arena for every thread (M_ARENA_MAX), whose freed blocks up to `KEEP_FREED` stay in
the heap between two of the worker's trims (M_MMAP_THRESHOLD, M_TRIM_THRESHOLD). The
blocks of a frame and of a large pass (megabytes, made 30 times a second by the worker,
copied by Zenoh's threads) are then used again instead of being mapped afresh each time,
every page faulted in and zeroed by the kernel: at 100,000 tracks about 120,000 page
faults a second in the worker and the frame sender with glibc's arena per thread, none
with one (docs/performance.md). Elsewhere than glibc nothing is changed.
"""

from __future__ import annotations

import ctypes
import ctypes.util

KEEP_FREED = 32 << 20  # bytes: glibc's largest mmap threshold
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD, M_ARENA_MAX = -1, -3, -8  # glibc's malloc.h


def tune() -> bool:
    """Set the three options; whether glibc took them."""
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return all([mallopt(M_ARENA_MAX, 1), mallopt(M_MMAP_THRESHOLD, KEEP_FREED),
                mallopt(M_TRIM_THRESHOLD, 2 * KEEP_FREED)])


TUNED = tune()
