"""The default IMM's update compiled (Numba): the same filter as `IMM.update`'s own code,
its reference (tests/test_imm_jit.py: the same posteriors, NIS, mode probabilities and
finiteness mask to 1e-9 of each row's largest entry), without the fixed cost of ~1,000
NumPy calls a pass. The rows are taken `BLOCK` at a time from the track store into
batch-last work arrays, updated by the kernels of `imm_kernel` (the formulas and their
sources are there) and written back in place; the loop releases the GIL (`nogil`), so
the frame sender and Zenoh's threads run beside it.

Compiled once per machine and cached (`cache=True`: beside the kernels, or in the
user's cache directory where that is not writable); `warm` compiles or loads it. The
service does so in the background (`jit.prepare`) and `IMM.update` calls `step` only once
`jit.ready()`; until then its own NumPy code serves. Importing this module does not import
Numba: the kernels are imported when first used.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults
from .measurements import MeasurementBatch

if TYPE_CHECKING:
    from .filters import Rows
    from .imm import IMM

Result = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
BLOCK = 40  # rows per block of a large pass, as imm_kernel.update_rows (`imm_cost.py`,
# the six modes: 3.7-3.9 us a row; 4.4-4.6 at 32, 4.0-4.2 at 24, 3.7-3.9 at 56, 4.2 at
# 48, 4.8 at 16: a power of two is the worst), SMALL of a pass of fewer rows (update_few)
SMALL = 8
__all__ = ["BLOCK", "SMALL", "applies", "design", "kernel", "step", "warm"]


def kernel(k: int) -> Callable:
    """The compiled update for a pass of k rows: the padding of the last block is
    computed too, so a pass of fewer than `BLOCK` rows takes blocks of `SMALL`."""
    from . import imm_kernel

    return imm_kernel.update_rows if k >= BLOCK else imm_kernel.update_few


def applies(imm: IMM) -> bool:
    """Whether `step` computes this IMM's update: CV, CA, CT and turn modes in the order-3
    state, unbiased mixing (the default's options; R shared or each mode's own)."""
    return (imm.order == 3 and imm.unbiased_mixing
            and all(kind in ("cv", "ca", "turn") or (kind == "ct" and w != 0.0)
                    for _, kind, _, w in imm.modes))


def step(imm: IMM, arrays: Rows, rows: np.ndarray, dt: np.ndarray,
         batch: MeasurementBatch) -> Result:
    """`IMM.update` of `rows` of `arrays` over their own dt with the measurements of
    `batch` (converted by the CMKF): writes the modes' posteriors and probabilities of the
    rows whose result is finite in place and returns the combined x (N, n), P (N, n, n),
    the NIS of the mixture's prediction and the mask of finite rows."""
    k, n = len(rows), arrays.n
    xn, pn = np.empty((k, n)), np.empty((k, n, n))
    nis, ok = np.empty(k), np.empty(k, dtype=np.bool_)
    if k:
        tau, dest, kinds, qs, ws = design(imm)
        kernel(k)(arrays.mode_x, arrays.mode_p, arrays.mode_prob,
                  np.ascontiguousarray(rows, dtype=np.int64),
                  _writable(dt, k),
                  tau, dest, kinds, qs, ws, not imm.mode_conversion,
                  np.ascontiguousarray(batch.polar),
                  np.ascontiguousarray(batch.values.T), np.ascontiguousarray(batch.sigmas.T),
                  np.ascontiguousarray(batch.origin.T), _time_column(batch, k),
                  defaults.TIME_HUBER, xn, pn, nis, ok)
    return xn, pn, nis, ok


def _time_column(batch: MeasurementBatch, k: int) -> np.ndarray:
    """The batch's time noise, s, as a (k,) array (0: none)."""
    return np.zeros(k) if batch.sigma_t is None else _writable(batch.sigma_t, k)


def _writable(dt: np.ndarray | float, k: int) -> np.ndarray:
    """dt as a new writable (k,) array: a read-only one (a broadcast) would be another
    type to Numba, a specialisation `warm` did not make, compiled in the worker."""
    out = np.empty(k)
    out[:] = dt
    return out


_DESIGNS: dict[int, tuple] = {}
KINDS = {"cv": 0, "ca": 1, "ct": 2, "turn": 3}  # as `imm_kernel` reads them


def design(imm: IMM) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The IMM's constants as arrays (as `IMM.transition` reads them): sojourns (M,), the
    normalised destinations of a mode left (M, M), the kinds (`KINDS`), the noise and the
    turn rate (rad/s; a turn's: its cap; a CV mode's: the bound of q |dt|, `dv_cap`) of
    each mode."""
    got = _DESIGNS.get(id(imm))
    if got is None or got[0] is not imm:
        m = len(imm.modes)
        tau = _writable(np.asarray(imm.sojourn, float), m)
        dest = np.ones((m, m)) if imm.leave is None else np.array(imm.leave, dtype=float)
        dest[np.arange(m), np.arange(m)] = 0.0
        dest /= np.maximum(dest.sum(1, keepdims=True), 1e-300)
        kinds = np.array([KINDS.get(kind, 0) for _, kind, _, _ in imm.modes], dtype=np.int64)
        qs = np.array([q for _, _, q, _ in imm.modes], dtype=float)
        ws = np.array([imm.turn_cap if kind == "turn" else imm.dv_cap if kind == "cv" else w
                       for _, kind, _, w in imm.modes], dtype=float)
        got = _DESIGNS[id(imm)] = (imm, tau, dest, kinds, qs, ws)
    return got[1:]


def warm() -> None:
    """Compile the kernel (or load it from the cache) on a tiny problem."""
    from .imm import ModeSet

    imm = ModeSet().imm()
    for d in (2, 3):
        n, m = 3 * d, len(imm.modes)
        mode_x, mode_p = np.zeros((1, m, n)), np.tile(np.eye(n) * 100.0, (1, m, 1, 1))
        for size in (1, BLOCK):  # both kernels
            kernel(size)(mode_x, mode_p, np.full((1, m), 1.0 / m), np.zeros(1, np.int64),
                         np.ones(1), *design(imm), not imm.mode_conversion,
                         np.ones(1, np.bool_), np.full((d, 1), 1e3), np.full((d, 1), 0.01),
                         np.zeros((3, 1)), np.zeros(1), defaults.TIME_HUBER, np.empty((1, n)),
                         np.empty((1, n, n)), np.empty(1), np.empty(1, np.bool_))
