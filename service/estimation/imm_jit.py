"""The default IMM's update compiled (Numba): the same filter as `IMM.update`'s own code,
its reference (tests/test_imm_jit.py: the same posteriors, NIS, mode probabilities and
finiteness mask to 1e-9 of each row's largest entry), without the fixed cost of ~1,000
NumPy calls a pass. The rows are taken `BLOCK` at a time from the track store into
batch-last work arrays, updated by the kernels of `imm_kernel` (the formulas and their
sources are there) and written back in place; the loop releases the GIL (`nogil`), so
the frame sender and Zenoh's threads run beside it.

Compiled once per machine and cached (`cache=True`: beside the kernels, or in the
user's cache directory where that is not writable); `warm` compiles or loads it. The
service does so in the background (`jit.prepare`); the filter catalogue builds the
default IMM as a `CompiledIMM`, whose update calls `step` once `jit.ready()` and the
reference's NumPy code until then. Importing this module does not import Numba: the
kernels are imported when first used.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults
from . import blocks, gate_jit, jit
from .imm import IMM
from .measurements import MeasurementBatch
from .ucm import CMKFConversion

if TYPE_CHECKING:
    from .filters import Convert, Rows

Result = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
BLOCK, SMALL = defaults.IMM_BLOCK, defaults.IMM_SMALL  # rows per block, as the kernels'
# the time noise's mixture (`timing.mixture_update`): (probability, variance scale) rows
MIXTURE = np.array(defaults.TIME_MIXTURE, dtype=float)
__all__ = ["BLOCK", "SMALL", "CompiledIMM", "applies", "design", "kernel", "step", "warm"]


@dataclass(frozen=True)
class CompiledIMM(IMM):
    """The IMM whose update runs compiled (`step`) once the kernels are ready and when
    it applies (`applies`, measurements converted by the CMKF); `IMM.update`, its
    reference, otherwise."""

    def update(self, arrays: Rows, rows: np.ndarray, dt: np.ndarray, convert: Convert
               ) -> Result:
        if jit.ready() and isinstance(convert, CMKFConversion) and applies(self):
            return step(self, arrays, rows, dt, convert.batch)
        return super().update(arrays, rows, dt, convert)

    def gate_moments(self, arrays: Rows, rows: np.ndarray, dt: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """`IMM.gate_moments` (what the association gates with), compiled once ready."""
        if jit.ready() and applies(self):
            return gate_moments(self, arrays, rows, dt)
        return super().gate_moments(arrays, rows, dt)

    def pair_likelihood(self, loglik: np.ndarray, ti: np.ndarray, nu: np.ndarray,
                        r: np.ndarray, narrow: np.ndarray, w: np.ndarray) -> np.ndarray:
        """`IMM.pair_likelihood`, compiled once ready (`gate_jit.mixture`)."""
        if jit.ready() and len(ti):
            return gate_jit.mixture(loglik, ti, nu, r, narrow, w)
        return super().pair_likelihood(loglik, ti, nu, r, narrow, w)


def kernel(k: int) -> Callable:
    """The compiled update for a pass of k rows: the padding of the last block is
    computed too, so a pass of fewer than `BLOCK` rows takes blocks of `SMALL`."""
    from . import imm_kernel

    return imm_kernel.update_rows if k >= BLOCK else imm_kernel.update_few


def applies(imm: IMM) -> bool:
    """Whether `step` computes this IMM's update: CV, CA, CT and turn modes in the order-3
    state, with `IMM`'s own mixing (R shared or each mode's own)."""
    return (imm.order == 3 and type(imm).mix is IMM.mix
            and all(kind in ("cv", "ca", "turn") or (kind == "ct" and w != 0.0)
                    for _, kind, _, w in imm.modes))


def step(imm: IMM, arrays: Rows, rows: np.ndarray, dt: np.ndarray,
         batch: MeasurementBatch, threads: int | None = None) -> Result:
    """`IMM.update` of `rows` of `arrays` over their own dt with the measurements of
    `batch` (converted by the CMKF): writes the modes' posteriors and probabilities of the
    rows whose result is finite in place and returns the combined x (N, n), P (N, n, n),
    the NIS of the mixture's prediction and the mask of finite rows. A large pass runs
    in parts on `threads` threads (default: `blocks.cores()`), the same bits."""
    k, n = len(rows), arrays.n
    xn, pn = np.empty((k, n)), np.empty((k, n, n))
    nis, ok = np.empty(k), np.empty(k, dtype=np.bool_)
    if not k:
        return xn, pn, nis, ok
    tau, dest, kinds, qs, ws = design(imm)
    update = kernel(k)  # one kernel for every part: each block the same rows, the same bits
    rows, dt = np.ascontiguousarray(rows, dtype=np.int64), _writable(dt, k)
    polar, values = np.ascontiguousarray(batch.polar), batch.values.T
    sigmas, origin, sigma_t = batch.sigmas.T, batch.origin.T, _time_column(batch, k)

    def part(lo: int, hi: int) -> None:  # rows lo..hi, distinct store rows from the others'
        update(arrays.mode_x, arrays.mode_p, arrays.mode_prob, rows[lo:hi], dt[lo:hi],
               tau, dest, kinds, qs, ws, not imm.mode_conversion, polar[lo:hi],
               np.ascontiguousarray(values[:, lo:hi]), np.ascontiguousarray(sigmas[:, lo:hi]),
               np.ascontiguousarray(origin[:, lo:hi]), sigma_t[lo:hi], MIXTURE,
               xn[lo:hi], pn[lo:hi], nis[lo:hi], ok[lo:hi])

    blocks.over_rows(k, BLOCK, part, threads)
    return xn, pn, nis, ok


def predicted(imm: IMM, arrays: Rows, rows: np.ndarray, dt: np.ndarray | float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`IMM.predicted` of `rows` over their own dt by the compiled kernels (the store is
    not written): c (N, M) and the modes' predictions x (N, M, n), P (N, M, n, n)."""
    from . import imm_kernel

    k, m, n = len(rows), len(imm.modes), arrays.n
    c, xs, ps = np.empty((k, m)), np.empty((k, m, n)), np.empty((k, m, n, n))
    if k:
        predict = imm_kernel.predict_rows if k >= BLOCK else imm_kernel.predict_few
        predict(arrays.mode_x, arrays.mode_p, arrays.mode_prob,
                np.ascontiguousarray(rows, dtype=np.int64), _writable(dt, k), *design(imm),
                c, xs, ps)
    return c, xs, ps


def gate_moments(imm: IMM, arrays: Rows, rows: np.ndarray, dt: np.ndarray | float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`IMM.gate_moments` by the compiled kernels."""
    from . import imm_kernel

    c, xs, ps = predicted(imm, arrays, rows, dt)
    k, d, n = len(rows), arrays.n // 3, arrays.n
    mean, cross, narrow, c_wide = (np.empty((k, d)), np.empty((k, d, n)), np.empty((k, d, d)),
                                   np.empty(k))
    if k:
        imm_kernel.gate_moments(c, xs, ps, d, mean, cross, narrow, c_wide)
    return mean, cross, narrow, c_wide


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
        dest = imm.destinations()
        kinds = np.array([KINDS.get(kind, 0) for _, kind, _, _ in imm.modes], dtype=np.int64)
        qs = np.array([q for _, _, q, _ in imm.modes], dtype=float)
        ws = np.array([imm.turn_cap if kind == "turn" else imm.dv_cap if kind == "cv" else w
                       for _, kind, _, w in imm.modes], dtype=float)
        got = _DESIGNS[id(imm)] = (imm, tau, dest, kinds, qs, ws)
    return got[1:]


def warm() -> None:
    """Compile the kernel (or load it from the cache) on a tiny problem."""
    from .imm import ModeSet

    imm = ModeSet().imm(CompiledIMM)
    for d in (2, 3):
        n, m = 3 * d, len(imm.modes)
        mode_x, mode_p = np.zeros((1, m, n)), np.tile(np.eye(n) * 100.0, (1, m, 1, 1))
        for size in (1, BLOCK):  # both kernels
            kernel(size)(mode_x, mode_p, np.full((1, m), 1.0 / m), np.zeros(1, np.int64),
                         np.ones(1), *design(imm), not imm.mode_conversion,
                         np.ones(1, np.bool_), np.full((d, 1), 1e3), np.full((d, 1), 0.01),
                         np.zeros((3, 1)), np.zeros(1), MIXTURE, np.empty((1, n)),
                         np.empty((1, n, n)), np.empty(1), np.empty(1, np.bool_))
            gate_moments(imm, _Rows(mode_x, mode_p, np.full((1, m), 1.0 / m), n),
                         np.zeros(size, np.int64), np.ones(size))


@dataclass
class _Rows:
    """The track store's IMM columns, as `warm` hands them to `predicted`."""

    mode_x: np.ndarray
    mode_p: np.ndarray
    mode_prob: np.ndarray
    n: int
