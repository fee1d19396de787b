"""A pass of rows split over threads, for kernels that release the GIL.

The rows are cut into contiguous parts at multiples of the kernel's block, so every
block holds the same rows whatever the number of threads and each row's result is the
same to the bit (tests/test_imm_jit.py); a pass of fewer than `PARALLEL_ROWS` rows stays
on the caller's thread. A pass on several threads is cut into `SHARES` parts a thread,
each taken by whichever thread is free: a thread the machine's other work holds back
does fewer of them, and the caller does not wait for its fixed share.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from itertools import count

from .. import defaults

_pool: tuple[int, ThreadPoolExecutor] | None = None  # (its threads, the pool)
SHARES = 4  # parts a thread of a pass on several threads (each at least PARALLEL_ROWS)


def cores() -> int:
    """The threads a pass may use: `KERNEL_THREADS`, or the cores this process may run on."""
    if defaults.KERNEL_THREADS > 0:
        return defaults.KERNEL_THREADS
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def parts(k: int, block: int, threads: int) -> list[tuple[int, int]]:
    """[lo, hi) ranges covering 0..k, each starting at a multiple of `block`, at most
    `threads` of them and none below PARALLEL_ROWS rows (but the only one)."""
    blocks = -(-k // block)
    n = max(1, min(threads, k // defaults.PARALLEL_ROWS, blocks))
    edges = [min(k, (blocks * j // n) * block) for j in range(n + 1)]
    return [(lo, hi) for lo, hi in zip(edges, edges[1:], strict=False) if hi > lo]


def over_rows(k: int, block: int, work: Callable[[int, int], None],
              threads: int | None = None) -> None:
    """`work(lo, hi)` for every part of a pass of k rows: on one thread when it has one
    part, else the parts taken in turn by this thread and up to `threads` - 1 others."""
    global _pool
    threads = cores() if threads is None else threads
    ranges = parts(k, block, threads * SHARES if threads > 1 else 1)
    helpers = min(threads, len(ranges)) - 1
    if helpers < 1:
        for lo, hi in ranges:
            work(lo, hi)
        return
    if _pool is None or _pool[0] < helpers:
        size = max(helpers, cores() - 1)
        _pool = (size, ThreadPoolExecutor(max_workers=size, thread_name_prefix="rows"))
    taken = count()  # its next() is atomic: each part goes to one thread

    def share() -> None:
        while (i := next(taken)) < len(ranges):
            work(*ranges[i])

    futures = [_pool[1].submit(share) for _ in range(helpers)]
    share()
    for future in futures:
        future.result()
