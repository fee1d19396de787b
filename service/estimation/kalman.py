"""Linear Kalman update on stacked arrays, position-measurement form (H = [I 0 ...]):
the fast batch-last kernel `update_soa` (textbook form: `joseph_update` in
tests/reference/estimation.py) and the EKF's linearised update.
"""

from __future__ import annotations

import numpy as np

from . import scratch
from .batch import einsum
from .linalg import ldl_inverse, ldl_solve

# Floor added to the innovation covariance so an exact measurement of an exactly known
# position (R = 0, P = 0) gives a zero gain instead of a division by zero (m^2).
S_FLOOR = 1e-9


def symmetrise(p: np.ndarray) -> np.ndarray:
    return 0.5 * (p + p.transpose(0, 2, 1))


def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched solve of a x = b; a row whose matrix is singular gets NaN (flagged by the
    caller's finiteness mask) instead of failing the whole batch."""
    try:
        return np.linalg.solve(a, b)
    except np.linalg.LinAlgError:
        out = np.full(np.broadcast_shapes(a.shape[:-2], b.shape[:-2]) + b.shape[-2:], np.nan)
        for i in range(len(a)):
            try:
                out[i] = np.linalg.solve(a[i], b[i])
            except np.linalg.LinAlgError:
                pass
        return out


def solve_symmetric(s: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """S^-1 b and det S for symmetric (N, m, m) S (its lower triangle is read) and
    right-hand sides b (m, k, N) with the batch axis last, which are overwritten by the
    solution (`ldl_solve`)."""
    det = np.empty(len(s))
    ldl_solve(s.transpose(1, 2, 0), b, det)
    return b, det


def update(x: np.ndarray, p: np.ndarray, z: np.ndarray, r: np.ndarray,
           h: np.ndarray | None = None, hx: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`update_full` without the likelihood."""
    return update_full(x, p, z, r, h, hx)[:4]


def update_full(x: np.ndarray, p: np.ndarray, z: np.ndarray, r: np.ndarray,
                h: np.ndarray | None = None, hx: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Update rows (N, n) / (N, n, n) with measurements z (N, m) of covariance R (N, m, m).

    The measurement depends on position only: by default it is the position itself
    (H = [I 0], the CMKF: `update_soa` on batch-last copies, chunk by chunk); an EKF
    passes the Jacobian `h` (N, m, d) with respect to the position and the predicted
    measurement `hx` (N, m). Joseph-form covariance (Bar-Shalom, Li & Kirubarajan 2001,
    eq. 5.2.3-18), symmetric. Returns the posterior x, P, the normalised innovation
    squared, a mask of rows whose result is finite (the caller keeps the prior of the
    others) and the Gaussian log-likelihood of the innovation (for model probabilities).
    """
    if h is not None or hx is not None:
        return _update_linearised(x, p, z, r, h, hx)
    x, p = np.asarray(x, dtype=float), np.asarray(p, dtype=float)
    n_rows, n = x.shape
    m = z.shape[1]
    xn, pn = np.empty((n_rows, n)), np.empty((n_rows, n, n))
    nis, det, ok = np.empty(n_rows), np.empty(n_rows), np.empty(n_rows, dtype=bool)
    for lo, hi in scratch.chunks(n_rows):
        xs, pout = scratch.to_soa(x[lo:hi], "upda.x"), scratch.buffer("upda.pn", (n, n), hi - lo)
        update_soa(xs, scratch.to_soa(p[lo:hi], "upda.p"), scratch.to_soa(z[lo:hi], "upda.z"),
                   scratch.to_soa(r[lo:hi], "upda.r"), pout, nis[lo:hi], det[lo:hi])
        ok[lo:hi] = finite(xs, pout, nis[lo:hi], m)
        np.copyto(xn[lo:hi].T, xs)
        np.copyto(scratch.batch_last(pn[lo:hi]), pout)
    return xn, pn, nis, ok, loglik(nis, det, m)


def finite(x: np.ndarray, p: np.ndarray, nis: np.ndarray, m: int = 0) -> np.ndarray:
    """Rows (batch axis last) whose state, covariance and NIS are all finite: a sum is
    finite if and only if all its terms are (short of an overflow). With m > 0, P is
    known symmetric and only its rows :m and its lower-right block are summed."""
    add = np.add.reduce  # the C reduction itself: this runs on every chunk
    tot = add(x, axis=0)
    if m > 0:
        tot += add(p[:m], axis=(0, 1))
        tot += add(p[m:, m:], axis=(0, 1))
    else:
        tot += add(p, axis=(0, 1))
    tot += nis
    return np.isfinite(tot)


def loglik(nis: np.ndarray, det: np.ndarray, m: int) -> np.ndarray:
    """Gaussian log-likelihood of innovations of dimension m, from NIS and det S."""
    with np.errstate(divide="ignore", invalid="ignore"):
        out = -0.5 * (nis + np.log(det) + m * np.log(2 * np.pi))
    out[~(det > 0)] = -np.inf  # as a non-positive sign from slogdet
    return out


def nis_soa(pos: np.ndarray, cov: np.ndarray, z: np.ndarray, r: np.ndarray,
            nis: np.ndarray) -> None:
    """The NIS of z (m, N) against a predicted position pos (m, N) with covariance
    cov (m, m, N) and measurement noise R (m, m, N), batch axis last, into nis (N,):
    nu' S^-1 nu with S = cov + R (+ S_FLOOR I), as `update_soa` computes it, without the
    update."""
    m, k = z.shape
    nu = np.subtract(z, pos, out=scratch.buffer("nis.nu", (m,), k))
    s0 = np.add(cov, r, out=scratch.buffer("nis.s", (m, m), k))
    sinv = scratch.buffer("nis.si", (m, m), k)
    ldl_inverse(s0, sinv, scratch.buffer("nis.det", (), k), S_FLOOR)
    sn = einsum("abn,bn->an", sinv, nu, out=scratch.buffer("nis.sn", (m,), k))
    einsum("an,an->n", nu, sn, out=nis)


def update_soa(x: np.ndarray, p: np.ndarray, z: np.ndarray, r: np.ndarray, p_out: np.ndarray,
               nis: np.ndarray, det: np.ndarray) -> None:
    """The CMKF update (H = [I 0]) with the batch axis last: x (n, N) in place, symmetric
    P (n, n, N) -> p_out (another array, exactly symmetric), z (m, N), R (m, m, N) ->
    NIS and det S into nis, det (N,).

    S = P[:m, :m] + R (+ S_FLOOR I) is inverted through S = L D L' (`ldl_inverse`); the
    transposed gain is K' = S^-1 P[:m]. The Joseph form (I - KH) P (I - KH)' + K R K'
    with H = [I 0] is evaluated from the n x m gain without forming I - KH:
    G = (I - KH) P = P - K P[:m], E = G H' - K R = P[:, :m] - K (P[:m, :m] + R), and then
    (I - KH) P (I - KH)' + K R K' = G - G H' K' + K R K' = G - E K' = P - [K E] [P[:m]; K']
    (an identity for any K, not only the optimal one); its upper triangle is computed
    and mirrored. The products run as np.einsum contractions over the small leading
    axes (batch axis last), which keep each accumulation in one pass over the batch."""
    n, k = x.shape
    m = z.shape[0]
    # one buffer [P[:m] nu; K' S^-1 nu; E' .]: the Joseph operands [P[:m]; K'] and
    # [K'; E'] are two overlapping slices of it, and K' and S^-1 nu come from one
    # contraction S^-1 [P[:m] nu]
    ops = scratch.buffer("upd.ops", (3 * m, n + 1), k)
    work = scratch.buffer("upd.w", (2 * m * m + n,), k)  # S0, S^-1 and dx, one buffer
    s0, sinv = work[:m * m].reshape(m, m, k), work[m * m:2 * m * m].reshape(m, m, k)
    nu = np.subtract(z, x[:m], out=ops[:m, n])
    np.add(p[:m, :m], r, out=s0)  # S without the floor
    ldl_inverse(s0, sinv, det, S_FLOOR)
    up, lk = ops[:2 * m, :n], ops[m:, :n]
    kt, et = ops[m:2 * m, :n], ops[2 * m:, :n]  # K' and E' (m, n)
    ops[:m, :n] = p[:m]
    einsum("abn,bin->ain", sinv, ops[:m], out=ops[m:2 * m])  # [K' S^-1 nu]
    sn = ops[m:2 * m, n]
    einsum("an,an->n", nu, sn, out=nis)
    x += einsum("ain,an->in", kt, nu, out=work[2 * m * m:])
    einsum("ban,bin->ain", s0, kt, out=et)  # E' = P[:m] - S0 K'
    np.subtract(p[:m], et, out=et)
    # P - [K E] [P[:m]; K'] in one contraction, its upper triangle mirrored
    joseph = einsum("ain,ajn->ijn", lk, up, out=p_out)
    np.subtract(p, joseph, out=p_out)
    for i in range(n - 1):
        p_out[i + 1:, i] = p_out[i, i + 1:]


def _update_linearised(x: np.ndarray, p: np.ndarray, z: np.ndarray, r: np.ndarray,
                       h: np.ndarray | None, hx: np.ndarray | None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`update_full` with H = [h 0] (the EKF baseline), on row-major arrays."""
    m = z.shape[1]
    n, d = x.shape[1], m if h is None else h.shape[2]
    nu = z - (x[:, :d] if hx is None else hx)
    pht = p[:, :, :d] if h is None else p[:, :, :d] @ h.transpose(0, 2, 1)  # (N, n, m)
    s = r + (pht[:, :d] if h is None else h @ pht[:, :d])
    s += S_FLOOR * np.eye(m)
    # S^-1 [H P, nu], batch axis last: the transposed gain K' = S^-1 H P and S^-1 nu
    sol = np.empty((m, n + 1, len(x)))
    sol[:, :n], sol[:, n] = pht.transpose(2, 1, 0), nu.T
    sol, det = solve_symmetric(s, sol)
    nis = (nu.T * sol[:, n]).sum(0)
    gain_t = sol[:, :n].transpose(2, 0, 1).copy()  # (N, m, n)
    gain = gain_t.transpose(0, 2, 1).copy()
    xn = x + (gain @ nu[:, :, None])[:, :, 0]
    # Joseph form (I - KH) P (I - KH)' + K R K', H = [h 0]; contiguous operands for matmul
    ikh_t = np.broadcast_to(np.eye(n), p.shape).copy()
    ikh_t[:, :d] -= gain_t if h is None else h.transpose(0, 2, 1) @ gain_t
    ikh = ikh_t.transpose(0, 2, 1).copy()
    ikh_p = ikh @ p  # the three (N, n, n) buffers are reused for the sums below
    pn = np.matmul(ikh_p, ikh_t, out=ikh)
    pn += np.matmul(gain, r @ gain_t, out=ikh_t)
    pn = np.multiply(np.add(pn, pn.transpose(0, 2, 1), out=ikh_p), 0.5, out=ikh_p)
    # a sum is finite if and only if all its terms are (short of an overflow)
    ok = np.isfinite(xn @ np.ones(n) + pn.reshape(len(pn), -1) @ np.ones(n * n) + nis)
    return xn, pn, nis, ok, loglik(nis, det, m)
