"""A pass of rows split over threads, for kernels that release the GIL.

The rows are cut into contiguous parts at multiples of the kernel's block, so every
block holds the same rows whatever the number of threads and each row's result is the
same to the bit (tests/test_imm_jit.py); a pass of fewer than `PARALLEL_ROWS` rows stays
on the caller's thread.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

from .. import defaults

_pool: tuple[int, ThreadPoolExecutor] | None = None  # (its threads, the pool)


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
    """`work(lo, hi)` for every part of a pass of k rows, on as many threads as parts."""
    global _pool
    ranges = parts(k, block, cores() if threads is None else threads)
    if len(ranges) == 1:
        work(*ranges[0])
        return
    if _pool is None or _pool[0] < len(ranges) - 1:
        size = max(len(ranges) - 1, cores() - 1)
        _pool = (size, ThreadPoolExecutor(max_workers=size, thread_name_prefix="rows"))
    futures = [_pool[1].submit(work, lo, hi) for lo, hi in ranges[1:]]
    work(*ranges[0])  # the caller's thread takes the first part
    for future in futures:
        future.result()
