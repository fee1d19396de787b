"""Contractions over a batch of rows whose results do not depend on the batch's size.

NumPy's einsum drops an axis of length one and contracts what is left with another
inner loop, whose last bits differ from those of the loop used for longer axes (it may
fuse a multiply and an add). A track's state would then depend on how many tracks
shared its update: a lockstep service given the same inputs in other batches (a replay)
would publish other bits. `einsum` computes a one-row batch as two copies of the row and
keeps the first, so every row goes through the same loop (tests/test_batch_invariance.py).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy._core.multiarray import c_einsum  # np.einsum's own kernel, without its wrapper

BATCH = "n"  # the subscript of the batch axis in every contraction of the filter kernels


@lru_cache(maxsize=256)
def _axes(subscripts: str) -> tuple[tuple[int, ...], int]:
    """The batch axis of each operand (-1: none) and of the result."""
    inputs, result = subscripts.split("->")
    return tuple(t.find(BATCH) for t in inputs.split(",")), result.find(BATCH)


def einsum(subscripts: str, *operands: np.ndarray, out: np.ndarray | None = None
           ) -> np.ndarray:
    """np.einsum(subscripts, *operands, out=out) over a batch axis named `n` (explicit
    `->` form), the same bits for a row whatever the batch's length. Calls np.einsum's
    C kernel directly (what np.einsum does without `optimize`, without its Python
    wrapper's argument parsing, which small batches would pay for every call)."""
    axes, res = _axes(subscripts)
    first = axes[0]
    if first < 0 or res < 0 or operands[0].shape[first] != 1:
        if out is None:
            return c_einsum(subscripts, *operands)
        return c_einsum(subscripts, *operands, out=out)
    doubled = [op if a < 0 else np.concatenate((op, op), axis=a)
               for a, op in zip(axes, operands, strict=True)]
    row = np.take(c_einsum(subscripts, *doubled), [0], axis=res)
    if out is None:
        return row
    out[...] = row
    return out


def einsum_as_is(subscripts: str, *operands: np.ndarray) -> np.ndarray:
    """np.einsum's C kernel as np.einsum calls it (the loop chosen by the axes' lengths,
    a one-row batch included): for contractions whose bits are not a track's state and
    so need not be the same for every batch length (gating distances, the display's
    covariance sums)."""
    return c_einsum(subscripts, *operands)
