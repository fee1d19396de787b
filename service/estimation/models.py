"""Kinematic motion models on stacked arrays (no Zenoh, no per-track objects).

State layout (docs/protocol.md): position, velocity[, acceleration], each block `dim` long,
so x = kron(derivative order, axis). A model of `order` 2 is nearly-constant velocity
(CV), order 3 nearly-constant acceleration (CA). Process noise is the continuous-time
white noise of the next derivative (Bar-Shalom, Li & Kirubarajan 2001, sec. 6.2.2-6.2.3:
for CV the acceleration, for CA the jerk) integrated exactly over each step dt, of
spectral density q^2 |dt|: the changes of velocity (CV) or acceleration (CA) over a step
are of the order of sqrt(density x dt) (same book, sec. 6.2.2), here q |dt|, as with the
piecewise-constant noise of std `q` of sec. 6.3.2-6.3.3 that the service used before, so
`q` keeps its unit (m/s^2 for CV, m/s^3 for CA) and its numbers. Not that model itself:
with exact measurements its steady state has the gains alpha = 1, beta = 2 and a
closed-loop eigenvalue at -1, an undamped oscillation that any jitter in the positions
excites; the continuous model's are beta = 3 - sqrt(3) and 0.27, whatever the density
(docs/accuracy.md, "Exact positions").
"""

from __future__ import annotations

import functools
import math

import numpy as np

from . import scratch


def axis_transition(dt: np.ndarray, order: int) -> np.ndarray:
    """Per-axis transition Phi (N, order, order): Phi[i, j] = dt^(j-i) / (j-i)!."""
    dt = np.asarray(dt, dtype=float)
    phi = np.zeros(dt.shape + (order, order))
    for i in range(order):
        for j in range(i, order):
            phi[..., i, j] = dt ** (j - i) / math.factorial(j - i)
    return phi


def noise_terms(dt: np.ndarray, order: int) -> np.ndarray:
    """The process noise per unit q^2, (order, order, N): the continuous white noise of
    density |dt| over the step dt, entry (a, b) = |dt| x |dt|^k / ((o-1-a)! (o-1-b)! k),
    k = 2 o - 1 - a - b, o = order (Bar-Shalom, Li & Kirubarajan 2001, sec. 6.2.2:
    [[T^3/3, T^2/2], [T^2/2, T]] per unit density for CV; sec. 6.2.3 for CA). The
    kernels' and the display's noise all come from here (or repeat it:
    `imm_kernel._predict`, `display.predicted_at`, `frame._draw`)."""
    gain = np.abs(np.asarray(dt, dtype=float))
    out = np.empty((order, order) + gain.shape)
    for a in range(order):
        for b in range(a, order):
            k = 2 * order - 1 - a - b
            den = math.factorial(order - 1 - a) * math.factorial(order - 1 - b) * k
            out[a, b] = np.power(gain, k + 1) / den
            out[b, a] = out[a, b]
    return out


def axis_noise(dt: np.ndarray, order: int, q: float | np.ndarray) -> np.ndarray:
    """Per-axis process noise (N, order, order) = q^2 `noise_terms` at |dt|."""
    c = np.moveaxis(noise_terms(np.atleast_1d(np.asarray(dt, dtype=float)), order), -1, 0)
    return c * np.reshape(np.asarray(q, dtype=float) ** 2, (-1, 1, 1))


def expand(block: np.ndarray, dim: int) -> np.ndarray:
    """kron(block, I_dim) over a leading batch axis: (N, a, b) -> (N, a*dim, b*dim)."""
    n, a, b = block.shape
    out = np.zeros((n, a, dim, b, dim))
    axis = np.arange(dim)
    out[:, :, axis, :, axis] = block  # the `dim` diagonals of every (a, b) block entry
    return out.reshape(n, a * dim, b * dim)


def transition(dt: np.ndarray, order: int, dim: int) -> np.ndarray:
    """Full transition matrices F (N, n, n), n = order * dim."""
    return expand(axis_transition(dt, order), dim)


def process_noise(dt: np.ndarray, order: int, dim: int, q: float | np.ndarray) -> np.ndarray:
    """Full process noise Q (N, n, n) = kron(`axis_noise`, I)."""
    return expand(axis_noise(dt, order, q), dim)


def predict(x: np.ndarray, p: np.ndarray, dt: np.ndarray, order: int, dim: int,
            q: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kalman prediction of every row by its own dt (dt may be negative: extrapolation
    backwards uses |dt| for the noise): x (N, n), P (N, n, n) -> new arrays; `predict_soa`
    on batch-last copies, chunk by chunk."""
    x, p = np.asarray(x, dtype=float), np.asarray(p, dtype=float)
    n_rows, n = x.shape
    dt = np.broadcast_to(np.asarray(dt, dtype=float), (n_rows,))
    q = np.asarray(q, dtype=float)
    xp, pp = np.empty((n_rows, n)), np.empty((n_rows, n, n))
    for lo, hi in scratch.chunks(n_rows):
        xs, ps = scratch.to_soa(x[lo:hi], "pred.x"), scratch.to_soa(p[lo:hi], "pred.p")
        predict_soa(xs, ps, dt[lo:hi], order, dim, q[lo:hi] if q.ndim else q)
        np.copyto(xp[lo:hi].T, xs)
        np.copyto(scratch.batch_last(pp[lo:hi]), ps)
    return xp, pp


def predict_position(x: np.ndarray, p: np.ndarray, dt: np.ndarray, order: int, dim: int,
                     q: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The position part of `predict`: the predicted position (N, dim) and the position
    rows of the predicted covariance (N, dim, n), without the rest (what a gate needs):
    `predict_position_soa` on batch-last copies (the results are views of batch-last
    arrays)."""
    x, p = np.asarray(x, dtype=float), np.asarray(p, dtype=float)
    n_rows, n = x.shape
    mean, rows = np.empty((dim, n_rows)), np.empty((dim, n, n_rows))
    predict_position_soa(np.ascontiguousarray(x.T), scratch.batch_last(p)[:dim * order],
                         np.broadcast_to(np.asarray(dt, dtype=float), (n_rows,)), order, dim,
                         q, mean, rows)
    return mean.T, rows.transpose(2, 0, 1)


def predict_position_soa(x: np.ndarray, p: np.ndarray, dt: np.ndarray, order: int, dim: int,
                         q: float | np.ndarray, mean: np.ndarray, rows: np.ndarray) -> None:
    """The position part of `predict_soa`, batch axis last: x (n, N), P (n, n, N) ->
    the predicted position mean (dim, N) and the position rows of the predicted
    covariance rows (dim, n, N) (contiguous). With F = kron(Phi, I):
    A = sum_c Phi[0, c] P[c, :] (blocks), then block b of the rows is
    sum_e Phi[b, e] A[:, e] + Q[0, b] (Q on the diagonal of each block)."""
    n, n_rows = x.shape
    dt = np.asarray(dt, dtype=float)
    # Phi[0, k] = dt^k / k! (dt^1 / 1! is dt itself)
    coef = [None, dt] + [dt ** k / math.factorial(k) for k in range(2, order)]
    blk = [slice(i * dim, (i + 1) * dim) for i in range(order)]
    if order > 1:
        # dt repeated over the rows of a block row: the products with the (contiguous)
        # block rows of x and P are then plain element-wise passes, not broadcasts
        dts = np.empty((dim * n, n_rows))
        dts[:] = dt
        np.add(x[blk[0]], np.multiply(dts[:dim], x[blk[1]]), out=mean)
        flat_p = p.reshape(n * n, n_rows)
        a = np.add(flat_p[:dim * n], np.multiply(dts, flat_p[dim * n:2 * dim * n]))
        a = a.reshape(dim, n, n_rows)
    else:
        np.copyto(mean, x[blk[0]])
        a = p[blk[0]].copy()
    for c in range(2, order):
        mean += coef[c] * x[blk[c]]
        a += coef[c] * p[blk[c]]
    noise = noise_terms(dt, order)[0] * np.square(q)  # Q[0, b] / ... per unit: row 0
    flat = rows.reshape(dim * n, n_rows)
    for b in range(order):
        acc = rows[:, blk[b]]
        if b + 1 < order:
            np.add(a[:, blk[b]], coef[1] * a[:, blk[b + 1]], out=acc)
        else:
            np.copyto(acc, a[:, blk[b]])
        for e in range(b + 2, order):
            acc += coef[e - b] * a[:, blk[e]]
        # + Q[0, b] on the diagonal of block b: entries (i, b dim + i), a strided view
        flat[b * dim:b * dim + (dim - 1) * (n + 1) + 1:n + 1] += noise[b]


def predict_soa(x: np.ndarray, p: np.ndarray, dt: np.ndarray, order: int, dim: int,
                q: float | np.ndarray) -> None:
    """`predict` in place on batch-last arrays x (n, N) and symmetric P (n, n, N).

    With F = kron(Phi, I_dim), F x adds Phi[a, c] times block c > a to block a (ascending
    a, so every block read is still unmodified). F P F' block by block: the (a, b) block
    (dim x dim) becomes sum over c >= a, e >= b of Phi[a, c] Phi[b, e] P_ce, computed for
    a <= b in ascending order (every block read is still unmodified); the diagonal blocks
    pair P_ce + P_ec, so they stay exactly symmetric, and the blocks below the diagonal
    are copied from above (the blocks below the diagonal are read only before that, as
    the transposes of the input's). + Q = kron(Q_axis, I_dim) on the diagonals of the blocks."""
    n, n_rows = x.shape
    dt = np.asarray(dt, dtype=float)
    powers = [None, dt] + [dt ** k / math.factorial(k) for k in range(2, order)]  # Phi[a, a+k]
    blk = [slice(i * dim, (i + 1) * dim) for i in range(order)]
    tmp = scratch.buffer("pred.tmp", (dim, dim), n_rows)
    for a in range(order):
        for c in range(a + 1, order):
            x[blk[a]] += np.multiply(x[blk[c]], powers[c - a], out=tmp[0])
    for a in range(order):
        for b in range(a, order):
            acc = p[blk[a], blk[b]]
            for c in range(a, order):
                for e in range(b, order):
                    if (c, e) == (a, b) or (a == b and e < c):
                        continue
                    # Phi[a, c] Phi[b, e], a factor Phi[a, a] = 1 left out (x 1 is exact)
                    coef = powers[e - b] if c == a else powers[c - a] if e == b else \
                        powers[c - a] * powers[e - b]
                    if a == b and c != e:  # Phi[a, c] Phi[a, e] (P_ce + P_ec), P_ec = P_ce'
                        term = np.add(p[blk[c], blk[e]], p[blk[c], blk[e]].transpose(1, 0, 2),
                                      out=tmp)
                        term *= coef
                    else:
                        term = np.multiply(p[blk[c], blk[e]], coef, out=tmp)
                    acc += term
    # + Q: q^2 times the continuous white-noise terms (order, order, N) (`noise_terms`)
    qm = noise_terms(dt, order)
    qm *= np.square(q)
    for k in range(dim):  # the entries (a dim + k, b dim + k) of every block
        p[k::dim, k::dim] += qm
    for a in range(order):
        for b in range(a + 1, order):
            p[blk[b], blk[a]] = p[blk[a], blk[b]].transpose(1, 0, 2)


def predict_blocks(x: np.ndarray, p: np.ndarray, dt: np.ndarray, order: int, dim: int,
                   q: float | np.ndarray, out: np.ndarray) -> None:
    """`predict_soa` with P given block by block: p (order, order, dim, dim, N), the
    dim x dim block (a, b) of the covariance contiguous in p[a, b] (from `to_blocks`), so
    that products and sums of whole blocks are plain element-wise passes over contiguous
    memory, and with the loops over blocks planned once per layout (`_block_plan`): at
    20 rows the Python around the passes costs as much as the passes. x (n, N) in place;
    the predicted P into out (n, n, N), the usual batch-last layout. The same operations
    in the same order as `predict_soa`, so the same bits (tests/test_fused.py)."""
    n_rows = x.shape[1]
    dt = np.asarray(dt, dtype=float)
    x_steps, p_steps, mirror = _block_plan(order, dim)
    # Phi[a, a+k] = dt^k / k! repeated over a block's entries (tiles[k]; tiles[0] is
    # work space), so that multiplications by them are plain passes, not broadcasts
    work = scratch.buffer("predb", (order + 2, dim, dim), n_rows)
    tiles, tmp, coefs = work[:order], work[order], work[order + 1]
    tiles[1] = dt
    for k in range(2, order):  # dt^k / k! (a square as np.square: what ** 2 runs)
        np.square(tiles[1], out=tiles[k]) if k == 2 else np.power(tiles[1], k, out=tiles[k])
        tiles[k] /= math.factorial(k)
    for xa, xc, k in x_steps:
        x[xa] += np.multiply(x[xc], tiles[k, 0], out=tmp[0])
    for a, b, c, e, k1, k2, pair in p_steps:
        coef = tiles[k1] if k2 == 0 else np.multiply(tiles[k1], tiles[k2], out=coefs)
        if pair:  # Phi[a, c] Phi[a, e] (P_ce + P_ec), P_ec = P_ce'
            term = np.add(p[c, e], p[c, e].transpose(1, 0, 2), out=tmp)
            term *= coef
        else:
            term = np.multiply(p[c, e], coef, out=tmp)
        p[a, b] += term
    # + Q: q^2 `noise_terms` on the diagonal of every block (a, b)
    qm = noise_terms(dt, order)
    qm *= np.square(q)
    p.reshape(order * order, dim * dim, n_rows)[:, ::dim + 1] += \
        qm.reshape(order * order, 1, n_rows)  # the diagonals of all blocks at once
    for a, b in mirror:
        p[b, a] = p[a, b].transpose(1, 0, 2)
    np.copyto(out.reshape(order, dim, order, dim, n_rows), p.transpose(0, 2, 1, 3, 4))


@functools.lru_cache(maxsize=16)
def _block_plan(order: int, dim: int) -> tuple[tuple, tuple, tuple]:
    """The steps of `predict_soa`'s loops, once per layout: x blocks (a += c times
    Phi[a, c]), P blocks (block (a, b) += P_ce times Phi[a, c] Phi[b, e], as the indices
    k of the two factors Phi[., . + k] (0: a factor 1 left out, exact) and whether the
    term pairs P_ce with P_ce' (a diagonal block)), and the blocks mirrored."""
    blk = [slice(i * dim, (i + 1) * dim) for i in range(order)]
    x_steps = tuple((blk[a], blk[c], c - a) for a in range(order)
                    for c in range(a + 1, order))
    p_steps = []
    for a in range(order):
        for b in range(a, order):
            for c in range(a, order):
                for e in range(b, order):
                    if (c, e) == (a, b) or (a == b and e < c):
                        continue
                    k1, k2 = (e - b, 0) if c == a else (c - a, 0) if e == b else \
                        (c - a, e - b)
                    p_steps.append((a, b, c, e, k1, k2, a == b and c != e))
    mirror = tuple((a, b) for a in range(order) for b in range(a + 1, order))
    return x_steps, tuple(p_steps), mirror


def to_blocks(p: np.ndarray, order: int, dim: int, out: np.ndarray) -> np.ndarray:
    """Row-major covariances p (N, n, n) into out (order, order, dim, dim, N), block by
    block (`predict_blocks`)."""
    np.copyto(out, p.reshape(len(p), order, dim, order, dim).transpose(1, 3, 2, 4, 0))
    return out


def motion(kind: str, dt: np.ndarray, order: int, dim: int, q: float | np.ndarray,
           omega: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """F and Q (N, n, n) of one motion model in a state of `order` (2 or 3).

    "ca" needs order 3. "cv" in an order-3 state holds the acceleration at zero (the
    padding of Bar-Shalom et al. 2001, sec. 11.6.7, for IMMs mixing CV and CA). "ct" is a
    coordinated turn at the known rate `omega` (rad/s, counter-clockwise in the x-y plane;
    same book, sec. 11.7.1), with the other axes nearly-constant velocity (the turn at
    its state's own rate is `turn.turn_model`'s).
    """
    if kind == "ca" or (kind == "cv" and order == 2):
        return transition(dt, order, dim), process_noise(dt, order, dim, q)
    if order != 3 or kind not in ("cv", "ct"):
        raise ValueError(f"no {kind!r} model in an order-{order} state")
    phi = axis_transition(dt, 3)
    phi[..., 2] = 0.0
    phi[..., 2, :] = 0.0
    f = expand(phi, dim)
    qm = np.zeros(np.shape(dt) + (3, 3))
    qm[..., :2, :2] = axis_noise(dt, 2, q)
    qm = expand(qm, dim)
    if kind == "ct":
        w = omega
        wt = w * np.asarray(dt, dtype=float)
        s, c = np.sin(wt), np.cos(wt)
        sw = s / w if w else np.asarray(dt, dtype=float)
        cw = (1 - c) / w if w else np.zeros_like(wt)
        x, y, vx, vy = 0, 1, dim, dim + 1
        f[:, x, vx], f[:, x, vy], f[:, y, vx], f[:, y, vy] = sw, -cw, cw, sw
        f[:, vx, vx], f[:, vx, vy], f[:, vy, vx], f[:, vy, vy] = c, -s, s, c
    return f, qm
