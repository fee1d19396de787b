"""Linear Kalman update on stacked arrays, position-measurement form (H = [I 0 ...])."""

from __future__ import annotations

import numpy as np

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
    solution; entry by entry for small m: S = L D L' (Golub & Van Loan 2013, alg. 4.1.1),
    then substitution, without pivoting (S is a covariance). A row with a zero pivot
    (singular S) gets NaN, flagged by the caller's finiteness mask as in `solve`."""
    m = s.shape[-1]
    low, piv, inv_piv = {}, [], []  # L below its unit diagonal, D, D^-1
    for j in range(m):
        piv.append(s[:, j, j] - sum(low[j, k] ** 2 * piv[k] for k in range(j)))
        inv_piv.append(np.divide(1.0, piv[j], out=np.full_like(piv[j], np.nan),
                                 where=piv[j] != 0))
        for i in range(j + 1, m):
            low[i, j] = inv_piv[j] * (s[:, i, j] - sum(low[i, k] * low[j, k] * piv[k]
                                                       for k in range(j)))
    for i in range(m):  # L y = b
        for k in range(i):
            b[i] -= low[i, k] * b[k]
    for i in reversed(range(m)):  # D L' x = y
        b[i] *= inv_piv[i]
        for k in range(i + 1, m):
            b[i] -= low[k, i] * b[k]
    return b, np.prod(piv, axis=0)


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
    (H = [I 0], the CMKF); an EKF passes the Jacobian `h` (N, m, d) with respect to the
    position and the predicted measurement `hx` (N, m). Joseph-form covariance
    (Bar-Shalom, Li & Kirubarajan 2001, eq. 5.2.3-18), symmetrised. Returns the posterior
    x, P, the normalised innovation squared, a mask of rows whose result is finite
    (the caller keeps the prior of the others) and the Gaussian log-likelihood of the
    innovation (for model probabilities).
    """
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
    with np.errstate(divide="ignore", invalid="ignore"):
        loglik = -0.5 * (nis + np.log(det) + m * np.log(2 * np.pi))
    loglik[~(det > 0)] = -np.inf  # as a non-positive sign from slogdet
    return xn, pn, nis, ok, loglik
