"""Work arrays of the filter kernels: kept per thread and reused, batch axis last.

The kernels (`models.predict_soa`, `convert.cmkf_soa`, `kalman.update_soa`) run on
"structure of arrays" blocks: a covariance of n x n entries over N rows is an (n, n, N)
array, so every entry is a contiguous run of N numbers and the arithmetic is a few
large element-wise operations instead of many tiny matrix products. The entry points
(`models.predict`, `kalman.update`, `filters.cmkf_step`, ...) take and return the usual
row-major (N, n) / (N, n, n) arrays and process the rows in chunks of at most `CHUNK`,
so the work arrays of a chunk stay in the processor's L2 cache and are allocated once
per thread instead of on every call (large fresh temporaries cost page faults when the
allocator hands their memory back to the system after each step).
"""

from __future__ import annotations

import math
import threading

import numpy as np

CHUNK = 4096  # rows per kernel pass
CONTIG = 0
EVEN = 0
PAD = 8  # buffer rows are CHUNK + PAD long: a power-of-two row stride would map the
# rows of a block to the same cache sets (many conflict misses)

_local = threading.local()


def work(name: str, shape: tuple[int, ...], n: int) -> np.ndarray:
    """The work array `name` of shape (*shape, n): a view of a float buffer of this
    thread, kept between calls (its content is whatever the last user left). Each
    kernel uses its own names; a name must not be held across a call that reuses it."""
    bufs: dict[str, np.ndarray] = _local.__dict__.setdefault("bufs", {})
    if CONTIG:
        size = n * math.prod(shape)
        buf = bufs.get(name)
        if buf is None or len(buf) < size:
            buf = bufs[name] = np.empty(max(size, CHUNK * math.prod(shape)))
        return buf[:size].reshape(*shape, n)
    buf = bufs.get(name)
    if buf is None or buf.shape[:-1] != shape or buf.shape[-1] < n:
        buf = bufs[name] = np.empty((*shape, max(n, CHUNK) + PAD))
    return buf[..., :n]


def chunks(n: int) -> list[tuple[int, int]]:
    """(start, stop) of the row chunks of a batch of n rows."""
    if EVEN:
        k = -(-n // CHUNK)
        edges = [n * i // k for i in range(k + 1)]
        return list(zip(edges[:-1], edges[1:], strict=True))
    return [(lo, min(n, lo + CHUNK)) for lo in range(0, n, CHUNK)]


def to_soa(a: np.ndarray, name: str) -> np.ndarray:
    """Rows (k, *shape) copied into the work array `name` of shape (*shape, k)."""
    out = work(name, a.shape[1:], len(a))
    np.copyto(out, np.moveaxis(a, 0, -1))
    return out
