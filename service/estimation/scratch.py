"""Scratch buffers of the filter kernels: kept per thread and reused, batch axis last.

The kernels (`models.predict_soa`, `ucm.cmkf_soa`, `kalman.update_soa`) run on
"structure of arrays" blocks: a covariance of n x n entries over N rows is an (n, n, N)
array, so every entry is a contiguous run of N numbers and the arithmetic is a few
large element-wise operations (and np.einsum contractions over the small leading axes)
instead of many tiny matrix products. The entry points (`models.predict`,
`kalman.update`, `filters.cmkf_step`, ...) take and return the usual row-major (N, n) /
(N, n, n) arrays and process the rows in chunks of at most `CHUNK`, on work arrays
allocated once per thread instead of on every call: large fresh temporaries cost page
faults whenever the allocator has handed their memory back to the system.
"""

from __future__ import annotations

import math
import threading

import numpy as np

# Rows per kernel pass. Every kernel call has a fixed cost of NumPy call overhead per
# chunk, so chunks should be long; beyond ~10,000 rows the per-row arrays (N,) of the
# kernels' temporaries reach glibc's 128 KiB mmap threshold (16,384 float64) and the
# work arrays leave the caches. `python bench/bench_filter.py --sizes 10000 100000`
# compares chunk sizes (5,000 to 10,000 came out best).
CHUNK = 10_000

_local = threading.local()


def buffer(name: str, shape: tuple[int, ...], n: int) -> np.ndarray:
    """The work array `name` of shape (*shape, n), contiguous: the start of a float buffer
    of this thread, kept between calls (its content is whatever the last user left).
    Each kernel uses its own names; a name must not be held across a call that reuses it."""
    try:
        views = _local.views
    except AttributeError:
        views = _local.views = {}
    hit = views.get(name)
    if hit is not None and hit.shape[-1] == n and hit.shape[:-1] == shape:
        return hit  # the same view as last time (most calls)
    bufs: dict[str, np.ndarray] = _local.__dict__.setdefault("bufs", {})
    size = n * math.prod(shape)
    buf = bufs.get(name)
    if buf is None or len(buf) < size:
        buf = bufs[name] = np.empty(max(size, min(n, CHUNK) * math.prod(shape)))
    view = views[name] = buf[:size].reshape(*shape, n)
    return view


def chunks(n: int) -> list[tuple[int, int]]:
    """(start, stop) of the row chunks of a batch of n rows: the fewest chunks of at most
    CHUNK rows, of equal length (to a row)."""
    if n <= 0:
        return []
    k = -(-n // CHUNK)
    edges = [n * i // k for i in range(k + 1)]
    return list(zip(edges[:-1], edges[1:], strict=True))


def batch_last(a: np.ndarray) -> np.ndarray:
    """The view of rows (k, *shape) as (*shape, k) (np.moveaxis(a, 0, -1), without its
    Python-level argument handling: kernels call it on every chunk)."""
    return a.transpose(_LAST[a.ndim]) if a.ndim < len(_LAST) else \
        a.transpose(*range(1, a.ndim), 0)


_LAST = [(), (0,)] + [(*range(1, d), 0) for d in range(2, 6)]  # batch_last's axes by ndim


def to_soa(a: np.ndarray, name: str) -> np.ndarray:
    """Rows (k, *shape) copied into the work array `name` of shape (*shape, k)."""
    out = buffer(name, a.shape[1:], len(a))
    np.copyto(out, batch_last(a))
    return out


def span(rows: np.ndarray) -> slice | np.ndarray:
    """rows as a slice when they are consecutive and ascending (indexing by a slice is a
    view: no gather, no scatter), else rows."""
    k = len(rows)
    if k and rows[-1] - rows[0] == k - 1 and (k == 1 or bool((np.diff(rows) == 1).all())):
        return slice(int(rows[0]), int(rows[0]) + k)
    return rows


BLOCK = 256  # rows per block of a transposing copy: its source and target stay in cache


def gather_soa(a: np.ndarray, rows: np.ndarray | slice, out: np.ndarray) -> np.ndarray:
    """a[rows] (k, *shape) into out (*shape, k), batch axis last, a block of rows at a
    time (each block's rows and columns stay in the cache, which a gather then a
    transposing copy of 10,000 rows of 243 numbers does not; `python bench/imm_cost.py`
    times the kernel that reads through it)."""
    flat, dst = a.reshape(len(a), -1), out.reshape(-1, out.shape[-1])
    k = dst.shape[1]
    base = rows.start if isinstance(rows, slice) else 0
    for lo in range(0, k, BLOCK):
        hi = min(k, lo + BLOCK)
        src = flat[base + lo:base + hi] if isinstance(rows, slice) else flat[rows[lo:hi]]
        np.copyto(dst[:, lo:hi], src.T)
    return out


def scatter_soa(src: np.ndarray, a: np.ndarray, rows: np.ndarray | slice) -> None:
    """a[rows] = src (*shape, k) moved to rows: `gather_soa` backwards."""
    flat, s2 = a.reshape(len(a), -1), src.reshape(-1, src.shape[-1])
    k = s2.shape[1]
    base = rows.start if isinstance(rows, slice) else 0
    for lo in range(0, k, BLOCK):
        hi = min(k, lo + BLOCK)
        if isinstance(rows, slice):
            np.copyto(flat[base + lo:base + hi], s2[:, lo:hi].T)
        else:
            flat[rows[lo:hi]] = s2[:, lo:hi].T
