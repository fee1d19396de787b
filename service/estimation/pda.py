"""The probabilistic data association (PDA) update of Gaussian predictions by several
weighted detections each, vectorised over tracks; with a plain per-track reference.

A track's prediction x, P (position first, H = [I 0]) and its gated detections k, each
z_k with covariance R_k and association probability beta_k (b = sum beta_k, the
probability that the track was detected, from JPDA or PDA): with R = sum beta_k R_k / b,
S = H P H' + R, K = P H' S^-1, nu_k = z_k - H x and nu = sum beta_k nu_k,

    x+ = x + K nu
    P+ = P - b K S K' + K (sum beta_k nu_k nu_k' - nu nu') K'

(Bar-Shalom, Willett & Tian, "Tracking and Data Fusion", 2011, sec. 6.4). For a model of
an IMM the likelihood of the scan is the PDAF's, relative to the clutter density lambda:

    Lambda = (1 - Pd) + Pd / lambda * sum_k N(nu_k; 0, H P H' + R_k)

(the IMM-PDAF of Houles & Bar-Shalom, IEEE TAES 25(2), 1989): a far detection with a small
beta moves a mode's probability only as much as it is likely under that mode, and each
mode takes the spread of its own gain.
"""

from __future__ import annotations

import numpy as np

from .batch import einsum
from .kalman import symmetrise

LOG_2PI = float(np.log(2 * np.pi))


def pda_update(x: np.ndarray, p: np.ndarray, ti: np.ndarray, z: np.ndarray, r: np.ndarray,
               beta: np.ndarray, pd: float, lam: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Update predictions x (N, n), P (N, n, n) with pairs k of track ti[k], detection
    z[k] (K, d), covariance r[k] (K, d, d) and probability beta[k]: the posteriors, the
    log of each track's scan likelihood Lambda, and a mask of the finite ones."""
    n_tracks, d = len(x), z.shape[1]
    b = np.bincount(ti, beta, n_tracks)
    r_sum = np.zeros((n_tracks, d, d))
    np.add.at(r_sum, ti, beta[:, None, None] * r)
    r_bar = r_sum / np.where(b > 0, b, 1.0)[:, None, None]
    hp = p[:, :d, :]  # H P (N, d, n)
    s = hp[:, :, :d] + r_bar
    gain = np.linalg.solve(s, hp).transpose(0, 2, 1)  # K = P H' S^-1 (N, n, d)
    nu_k = z - x[ti, :d]  # (K, d)
    nu = np.zeros((n_tracks, d))
    np.add.at(nu, ti, beta[:, None] * nu_k)
    second = np.zeros((n_tracks, d, d))
    np.add.at(second, ti, beta[:, None, None] * nu_k[:, :, None] * nu_k[:, None, :])
    xn = x + einsum("nid,nd->ni", gain, nu)
    spread = second - nu[:, :, None] * nu[:, None, :]
    pn = p - b[:, None, None] * (gain @ s @ gain.transpose(0, 2, 1)) \
        + gain @ spread @ gain.transpose(0, 2, 1)
    # the scan's likelihood ratio: a miss, or one of the detections
    s_k = hp[ti, :, :d] + r  # each pair's own S
    sign, logdet = np.linalg.slogdet(s_k)
    d2 = einsum("ka,ka->k", nu_k, np.linalg.solve(s_k, nu_k[:, :, None])[:, :, 0])
    ll = np.where(sign > 0, -0.5 * (d2 + logdet + d * LOG_2PI), -np.inf)
    detected = np.zeros(n_tracks)
    np.add.at(detected, ti, np.exp(ll - np.log(lam)))
    with np.errstate(divide="ignore"):
        loglam = np.log((1.0 - pd) + pd * detected)
    pn = symmetrise(pn)
    ok = np.isfinite(xn).all(1) & np.isfinite(pn).all((1, 2)) & np.isfinite(loglam)
    return xn, pn, loglam, ok


def pda_update_reference(x: np.ndarray, p: np.ndarray, ti: np.ndarray, z: np.ndarray,
                         r: np.ndarray, beta: np.ndarray, pd: float, lam: float
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`pda_update` written plainly, track by track and detection by detection (the
    reference the vectorised one is tested against)."""
    d = z.shape[1]
    xs, ps, lls = [], [], []
    for t in range(len(x)):
        ks = [k for k in range(len(ti)) if ti[k] == t]
        h = np.eye(d, x.shape[1])
        b = sum(beta[k] for k in ks)
        r_bar = sum(beta[k] * r[k] for k in ks) / b if b > 0 else np.zeros((d, d))
        s = h @ p[t] @ h.T + r_bar
        gain = p[t] @ h.T @ np.linalg.inv(s)
        nus = [z[k] - h @ x[t] for k in ks]
        nu = sum((beta[k] * v for k, v in zip(ks, nus, strict=True)), np.zeros(d))
        second = sum((beta[k] * np.outer(v, v) for k, v in zip(ks, nus, strict=True)),
                     np.zeros((d, d)))
        xs.append(x[t] + gain @ nu)
        ps.append(p[t] - b * gain @ s @ gain.T + gain @ (second - np.outer(nu, nu)) @ gain.T)
        like = 1.0 - pd
        for k, v in zip(ks, nus, strict=True):
            sk = h @ p[t] @ h.T + r[k]
            dens = np.exp(-0.5 * v @ np.linalg.solve(sk, v)) / np.sqrt(
                np.linalg.det(2 * np.pi * sk))
            like += pd * dens / lam
        lls.append(np.log(like))
    return np.array(xs), np.array(ps), np.array(lls)
