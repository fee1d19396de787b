"""The IMM's update on batch-last arrays: the filter core (`filters.cmkf_step`'s
prediction, conversion and Joseph update) run once per mode, with the mixing and the
mode probabilities as element-wise passes over the rows.

The same filter as `imm.IMM.update` (Blom & Bar-Shalom 1988; Bar-Shalom, Li &
Kirubarajan 2001, sec. 11.6.6, with the unbiased mixing of Granstrom, Willett &
Bar-Shalom, IEEE TAES 51(4), 2015 and each mode's R averaged over its own prediction),
which stays the reference it is tested against (tests/test_imm_soa.py). What makes it
fast:

- A CV mode in the padded order-3 state holds the acceleration at zero: its transition
  zeroes the acceleration column, so its prediction, conversion and update are the
  order-2 filter core on (position, velocity) alone; its acceleration and the
  covariance's acceleration rows stay exactly zero (H = [I 0 0]: the gain's
  acceleration rows are P[acc, pos] S^-1 = 0). Mixing into a CV mode therefore needs
  only the (position, velocity) part of the mixture.
- Every array is batch-last ((n, N), (n, n, N)): the mixing sums over the M modes are M
  element-wise passes, the kernels those of the single-model core, and a row's result
  does not depend on how many rows share the call (tests/test_batch_invariance.py).

It applies to IMMs of CV and CA modes on converted (CMKF) measurements with the default
options (`applies`); any other IMM (turn modes, ablations) runs `IMM.update`'s own code.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import kalman, models, scratch
from .measurements import MeasurementBatch
from .ucm import cmkf_soa

Result = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
WHOLE = 2048  # rows up to which a mixture's spread is summed a whole matrix per call


def applies(imm: Any) -> bool:
    """Whether `step` computes this IMM's update."""
    return (imm.order == 3 and imm.unbiased_mixing and imm.mode_conversion
            and all(kind in ("cv", "ca") for _, kind, _, _ in imm.modes))


def step(imm: Any, arrays: Any, rows: np.ndarray, dt: np.ndarray,
         batch: MeasurementBatch) -> Result:
    """`IMM.update` of `rows` of `arrays` over their own dt with the measurements of
    `batch` (converted by the CMKF): writes the modes' posteriors and probabilities of the
    rows whose result is finite and returns the combined x (N, n), P (N, n, n), the NIS
    of the mixture's prediction and the mask of finite rows (as `IMM.update`)."""
    n_rows, n = len(rows), arrays.n
    dt = np.broadcast_to(np.asarray(dt, dtype=float), (n_rows,))
    xn, pn = np.empty((n_rows, n)), np.empty((n_rows, n, n))
    nis, ok = np.empty(n_rows), np.empty(n_rows, dtype=bool)
    pi_all = imm.transition(dt)  # (N, M, M)
    for lo, hi in scratch.chunks(n_rows):
        r = rows[lo:hi]
        xu, pu, mu, x, p, nis[lo:hi], ok[lo:hi] = _chunk(
            imm, arrays.dim, _gather(arrays.mode_x, r, "imm.mx"),
            _gather(arrays.mode_p, r, "imm.mp"), _gather(arrays.mode_prob, r, "imm.mu"),
            scratch.to_soa(pi_all[lo:hi], "imm.pi"), dt[lo:hi], batch.rows(lo, hi))
        scratch.scatter_soa(x, xn, slice(lo, hi))
        scratch.scatter_soa(p, pn, slice(lo, hi))
        # the modes of the finite rows (the others keep their prior, as `IMM.update`)
        keep = ok[lo:hi]
        if keep.all():
            good = scratch.span(r)
            for src, dst in ((xu, arrays.mode_x), (pu, arrays.mode_p), (mu, arrays.mode_prob)):
                scratch.scatter_soa(src, dst, good)
        else:
            good = r[keep]
            arrays.mode_x[good] = np.moveaxis(xu, -1, 0)[keep]
            arrays.mode_p[good] = np.moveaxis(pu, -1, 0)[keep]
            arrays.mode_prob[good] = mu.T[keep]
    return xn, pn, nis, ok


def _gather(a: np.ndarray, rows: np.ndarray, name: str) -> np.ndarray:
    """a[rows] batch-last ((*shape, k)) in a reused work array (`scratch.gather_soa`)."""
    return scratch.gather_soa(a, scratch.span(rows), scratch.buffer(name, a.shape[1:],
                                                                     len(rows)))


def _chunk(imm: Any, d: int, mx: np.ndarray, mp: np.ndarray, mu: np.ndarray,
           pi: np.ndarray, dt: np.ndarray, batch: MeasurementBatch) -> tuple:
    """One chunk, batch axis last: mx (M, n, k), mp (M, n, n, k), mu (M, k), pi (M, M, k).
    Returns the modes' posteriors xu (M, n, k), pu (M, n, n, k), probabilities (M, k), the
    combined x (n, k), P (n, n, k), NIS (k,) and the mask of finite rows."""
    m, n, k = mx.shape
    kinds = [kind for _, kind, _, _ in imm.modes]
    acc = slice(2 * d, 3 * d)
    # predicted mode probabilities c_j = sum_i pi_ij mu_i, mixing weights pi_ij mu_i / c_j
    c = scratch.buffer("imm.c", (m,), k)
    w = scratch.buffer("imm.w", (m, m), k)
    np.multiply(pi, mu[:, None], out=w)  # pi_ij mu_i
    for j in range(m):
        np.copyto(c[j], w[0, j])
        for i in range(1, m):
            c[j] += w[i, j]
    w /= np.maximum(c, 1e-300)[None]
    xu = scratch.buffer("imm.xu", (m, n), k)
    pu = scratch.buffer("imm.pu", (m, n, n), k)
    # each mode's predicted position and its covariance, mode-major columns (j k + row):
    # the conversion's input for all modes in one call
    pos = scratch.buffer("imm.cpos", (d, m), k)
    cov = scratch.buffer("imm.ccov", (d, d, m), k)
    lik = scratch.buffer("imm.lik", (m,), k)
    ok = np.ones(k, dtype=bool)
    groups = []  # the modes of one kind run the filter core together, mode-major columns
    for kind, members in _groups(kinds, k):
        ca, g = kind == "ca", len(members)
        s = n if ca else 2 * d  # a CV mode's filter runs on (position, velocity)
        xg = scratch.buffer(f"imm.xg.{members[0]}", (s,), g * k)
        pg = scratch.buffer(f"imm.pg.{members[0]}", (s, s), g * k)
        for a, j in enumerate(members):  # each mode's mixed initial condition
            cols = slice(a * k, (a + 1) * k)
            _mixed(mx, mp, w, j, acc, [ca and kd != "ca" for kd in kinds], xg[:, cols],
                   pg[:, :, cols])
        qs = [imm.modes[j][2] for j in members]
        q = qs[0] if g == 1 else np.repeat(np.asarray(qs, dtype=float), k)
        models.predict_soa(xg, pg, dt if g == 1 else np.tile(dt, g), 3 if ca else 2, d, q)
        for a, j in enumerate(members):
            np.copyto(pos[:, j], xg[:d, a * k:(a + 1) * k])
            np.copyto(cov[:, :, j], pg[:d, :d, a * k:(a + 1) * k])
        groups.append((members, xg, pg, s))
    # the converted measurement (the same for every mode) and each mode's R averaged over
    # its own prediction, mode-major columns
    zz, rr = _convert(batch, pos.reshape(d, m * k), cov.reshape(d, d, m * k))
    for members, xg, pg, s in groups:
        g, lo = len(members), members[0] * k
        cols = slice(lo, lo + g * k) if members == list(range(members[0], members[0] + g)) \
            else np.concatenate([np.arange(j * k, (j + 1) * k) for j in members])
        direct = g == 1 and s == n  # a lone CA mode: its posterior straight into pu
        po = pu[members[0]] if direct else scratch.buffer(f"imm.po.{s}", (s, s), g * k)
        nis_g, det_g = scratch.buffer("imm.nis", (), g * k), scratch.buffer("imm.det", (), g * k)
        kalman.update_soa(xg, pg, zz[:, cols], rr[:, :, cols], po, nis_g, det_g)
        ok_g = kalman.finite(xg, po, nis_g, d)
        lik_g = kalman.loglik(nis_g, det_g, d)
        for a, j in enumerate(members):
            c_ = slice(a * k, (a + 1) * k)
            np.copyto(xu[j, :s], xg[:, c_])
            if not direct:
                np.copyto(pu[j, :s, :s], po[:, :, c_])
            if s < n:  # a CV mode: no acceleration, none in its covariance
                xu[j, s:] = 0.0
                pu[j, s:] = 0.0
                pu[j, :s, s:] = 0.0
            ok &= ok_g[c_]
            lik[j] = lik_g[c_]
    # mode probabilities: c_j times the likelihood, normalised (logs, largest first)
    with np.errstate(invalid="ignore"):  # a non-finite row is flagged below
        logw = np.log(np.maximum(c, 1e-300)) + lik
        logw -= logw.max(0)
        mu_new = np.exp(logw)
        mu_new /= mu_new.sum(0)
    ok &= np.isfinite(mu_new).all(0)
    x, p = _moments(xu, pu, np.where(np.isfinite(mu_new), mu_new, 0.0), "imm.comb")
    nis = _mixture_nis(pos.transpose(1, 0, 2), cov.transpose(2, 0, 1, 3),
                       rr.reshape(d, d, m, k).transpose(2, 0, 1, 3), c, zz[:, :k])
    return xu, pu, mu_new, x, p, nis, ok


def _groups(kinds: list[str], k: int) -> list[tuple[str, list[int]]]:
    """The modes that run the filter core together, [(kind, [mode indices])]: those of one
    kind while their columns (modes x k rows) stay within WHOLE (fewer NumPy calls for
    small chunks; beyond, one mode at a time keeps the work arrays in the cache: 5 %
    faster at 10,000 rows), else each mode alone. Either way a row gets the same bits."""
    out: dict[str, list[int]] = {}
    for j, kind in enumerate(kinds):
        out.setdefault(kind, []).append(j)
    return [(kind, group) for kind, members in out.items()
            for group in ([members] if len(members) * k <= WHOLE else [[j] for j in members])]


def _convert(batch: MeasurementBatch, pos: np.ndarray, cov: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """The converted measurements z (d, M k) and R (d, d, M k) of the M modes' predicted
    positions pos (d, M k) with covariances cov (d, d, M k), mode-major columns: each
    mode's R averaged over its own prediction, in one call of the conversion (M copies of
    the batch; a row's result does not depend on the others, so it is the same as one
    call per mode)."""
    d, mk = pos.shape
    zz = scratch.buffer("imm.cz", (d,), mk)
    rr = scratch.buffer("imm.cr", (d, d), mk)
    cmkf_soa(batch.tiled(mk // len(batch.t)), pos, cov, zz, rr)
    return zz, rr


def _mixed(mx: np.ndarray, mp: np.ndarray, w: np.ndarray, j: int, acc: slice,
           padded: list[bool], x0: np.ndarray, p0: np.ndarray) -> None:
    """The mixed initial condition of mode j, its first s components: x0 = sum_i w_ij x_i,
    P0 = sum_i w_ij (P_i + (x_i - x0)(x_i - x0)'), where for a padded pair (i without an
    acceleration mixed into j with one) x_i's acceleration is j's and P_i's acceleration
    block is j's, its cross terms zero (Granstrom et al. 2015). Into x0 (s, k),
    p0 (s, s, k)."""
    m, n, k = mx.shape
    s = len(x0)
    xi = scratch.buffer(f"imm.xi.{s}", (s,), k)
    pi_ = scratch.buffer(f"imm.pi.{s}", (s, s), k)
    dv = scratch.buffer(f"imm.dv.{s}", (s,), k)
    tmp = scratch.buffer(f"imm.tmp.{s}", (s, s), k)

    def source(i: int) -> tuple[np.ndarray, np.ndarray]:
        if not padded[i]:
            return mx[i, :s], mp[i, :s, :s]
        np.copyto(xi, mx[i, :s])
        xi[acc] = mx[j, acc]
        np.copyto(pi_, mp[i, :s, :s])
        pi_[acc] = 0.0
        pi_[:, acc] = 0.0
        pi_[acc, acc] = mp[j, acc, acc]
        return xi, pi_

    np.multiply(source(0)[0], w[0, j], out=x0)
    for i in range(1, m):
        x0 += np.multiply(source(i)[0], w[i, j], out=dv)
    p0.fill(0.0)
    for i in range(m):
        xs, ps = source(i)
        _spread(p0, xs, ps, x0, w[i, j], dv, tmp)
    _mirror(p0)


def _moments(x: np.ndarray, p: np.ndarray, w: np.ndarray, name: str
             ) -> tuple[np.ndarray, np.ndarray]:
    """Mean (n, k) and covariance (n, n, k) of the mixtures x (M, n, k), P (M, n, n, k)
    with weights w (M, k) (`filters.moments`, batch axis last)."""
    m, n, k = x.shape
    mean = scratch.buffer(name + ".x", (n,), k)
    cov = scratch.buffer(name + ".p", (n, n), k)
    dv = scratch.buffer(name + ".dv", (n,), k)
    tmp = scratch.buffer(name + ".tmp", (n, n), k)
    np.multiply(x[0], w[0], out=mean)
    for j in range(1, m):
        mean += np.multiply(x[j], w[j], out=dv)
    cov.fill(0.0)
    for j in range(m):
        _spread(cov, x[j], p[j], mean, w[j], dv, tmp)
    _mirror(cov)
    return mean, cov


def _spread(acc: np.ndarray, x: np.ndarray, p: np.ndarray, mean: np.ndarray,
            w: np.ndarray, dv: np.ndarray, tmp: np.ndarray) -> None:
    """acc += w (P + (x - mean)(x - mean)'), batch axis last, its upper triangle (the
    caller mirrors it into the lower one); every entry of it gets the same operations
    whatever the number of rows."""
    np.subtract(x, mean, out=dv)
    if dv.shape[-1] <= WHOLE:  # few rows: four calls on the whole matrix
        np.multiply(dv[:, None], dv[None, :], out=tmp)
        tmp += p
        tmp *= w
        acc += tmp
        return
    for a in range(len(dv)):  # many: the upper triangle only, row by row (less memory)
        t = tmp[a, a:]
        np.multiply(dv[a:], dv[a], out=t)
        t += p[a, a:]
        t *= w
        acc[a, a:] += t


def _mirror(a: np.ndarray) -> None:
    """Copy the upper triangle of a (s, s, k) into its lower one."""
    for i in range(len(a) - 1):
        a[i + 1:, i] = a[i, i + 1:]


def _mixture_nis(xpos: np.ndarray, ppos: np.ndarray, rs: np.ndarray, c: np.ndarray,
                 z: np.ndarray) -> np.ndarray:
    """NIS of z against the mixture of the modes' predicted positions (weights c), with
    R averaged the same way: sum_j c_j R_j (as `IMM.update`)."""
    d, k = z.shape
    mean, cov = _moments(xpos, ppos, c, "imm.nis")
    rbar = scratch.buffer("imm.rbar", (d, d), k)
    np.multiply(rs[0], c[0], out=rbar)
    for j in range(1, len(rs)):
        rbar += rs[j] * c[j]
    nis = np.empty(k)
    kalman.nis_soa(mean, cov, z, rbar, nis)
    return nis
