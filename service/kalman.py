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
    n_rows, n = x.shape
    m = z.shape[1]
    d = m if h is None else h.shape[2]
    nu = z - (x[:, :d] if hx is None else hx)
    pht = p[:, :, :d] if h is None else p[:, :, :d] @ h.transpose(0, 2, 1)  # (N, n, m)
    hph = pht[:, :d] if h is None else h @ pht[:, :d]
    s = hph + r + S_FLOOR * np.eye(m)
    gain = solve(s, pht.transpose(0, 2, 1)).transpose(0, 2, 1)
    xn = x + np.einsum("nij,nj->ni", gain, nu)
    ikh = np.broadcast_to(np.eye(n), (n_rows, n, n)).copy()
    ikh[:, :, :d] -= gain if h is None else gain @ h
    pn = symmetrise(ikh @ p @ ikh.transpose(0, 2, 1) + gain @ r @ gain.transpose(0, 2, 1))
    nis = np.einsum("ni,ni->n", nu, solve(s, nu[:, :, None])[:, :, 0])
    ok = np.isfinite(xn).all(1) & np.isfinite(pn).all((1, 2)) & np.isfinite(nis)
    sign, logdet = np.linalg.slogdet(s)
    loglik = -0.5 * (nis + logdet + m * np.log(2 * np.pi))
    loglik[sign <= 0] = -np.inf
    return xn, pn, nis, ok, loglik
