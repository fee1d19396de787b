"""Small linear-algebra kernels on batch-last arrays (an m x m matrix over N rows is
an (m, m, N) array): the closed-form symmetric eigen-decomposition for d <= 3 and the
LDL' inverse and solve, entry by entry. tests/reference/estimation.py holds their
textbook forms.
"""

from __future__ import annotations

import numpy as np

from . import scratch
from .batch import einsum


def eigh(cov: np.ndarray, d: int) -> tuple[list, list]:
    """Eigenvalues (d arrays of N) and unit eigenvectors (d arrays (d, N)) of
    symmetric PSD matrices cov (d, d, N) (batch axis last; the upper triangle is read),
    those of `np.linalg.eigh` up to order and signs (and the choice of basis of a repeated
    eigenvalue), in closed form for d <= 3.

    A Jacobi rotation by 0.5 atan2(2 a01, a00 - a11) diagonalises a 2 x 2 block (Golub &
    Van Loan 2013, sec. 8.5.2). For d = 3, the eigenvalue farthest from the other two
    (trigonometric solution of the characteristic cubic: Smith, CACM 4(4), 1961) has its
    eigenvector v along the largest cross product of two rows of cov - lambda I (the
    columns of its adjugate), and a Jacobi rotation in the plane orthogonal to v (basis of
    Duff et al., JCGT 6(1), 2017) gives the other two, accurately even when their
    eigenvalues are close. Per-entry arithmetic on (N,) arrays; for d = 3 some of the
    returned arrays are work arrays of this thread (valid until the next call)."""
    n = cov.shape[-1]
    if d > 3:
        vals, vecs = np.linalg.eigh(np.moveaxis(cov, -1, 0))
        return list(vals.T), [vecs[:, :, k].T for k in range(d)]
    a = {(i, j): cov[min(i, j), max(i, j)] for i in range(d) for j in range(d)}
    if d == 1:
        return [a[0, 0]], [np.ones((1, n))]
    if d == 2:
        uw = np.zeros((2, 2, n))
        uw[0, 0] = uw[1, 1] = 1.0
        return _rotate(cov, uw)
    return _eigh3(cov, a, n)


def _eigh3(cov: np.ndarray, a: dict, n: int) -> tuple[list, list]:
    """`eigh` for d = 3 on reused work arrays (the same arithmetic, written with out=)."""
    a00, a01, a02, a11, a12, a22 = a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2]
    e = scratch.buffer("eig", (34,), n)
    q, b00, b11, b22, t, p, t2, det = e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7]
    np.add(a00, a11, out=q)
    q += a22
    q /= 3
    np.subtract(a00, q, out=b00)
    np.subtract(a11, q, out=b11)
    np.subtract(a22, q, out=b22)
    # p = sqrt((b00^2 + b11^2 + b22^2 + 2 (a01^2 + a02^2 + a12^2)) / 6)
    bq, aq = e[1:4], cov[0, 1:]  # (b00, b11, b22) and (a01, a02)
    einsum("kn,kn->n", bq, bq, out=p)
    einsum("kn,kn->n", aq, aq, out=t2)
    t2 += np.multiply(a12, a12, out=t)
    t2 *= 2
    p += t2
    p /= 6
    np.sqrt(p, out=p)
    # det(cov - q I) along its first row
    np.multiply(b11, b22, out=det)
    det -= np.multiply(a12, a12, out=t)
    det *= b00
    np.multiply(a12, a02, out=t2)
    t2 -= np.multiply(a01, b22, out=t)
    t2 *= a01
    det += t2
    np.multiply(a01, a12, out=t2)
    t2 -= np.multiply(b11, a02, out=t)
    t2 *= a02
    det += t2
    half = e[8]
    np.multiply(p, p, out=t)
    t *= p
    t *= 2
    _divide(det, t, half, 0.0)  # det / (2 p^3), 0 where p = 0
    np.clip(half, -1.0, 1.0, out=half)
    np.arccos(half, out=half)
    half /= 3
    cos_phi, sin_phi = cos_sin_into(half, e[9], e[10])
    hi, lo, iso = e[11], e[12], e[13]
    np.multiply(p, 2, out=hi)
    hi *= cos_phi
    hi += q
    np.multiply(sin_phi, np.sqrt(3), out=lo)  # q + 2 p cos(phi + 2 pi / 3)
    lo += cos_phi
    lo *= p
    np.subtract(q, lo, out=lo)
    np.add(hi, lo, out=t)
    q *= 2
    np.copyto(iso, lo)
    np.copyto(iso, hi, where=t > q)  # hi - mid > mid - lo, as mid = 3q - hi - lo
    r00, r11, r22 = b00, b11, b22  # rows of cov - iso I
    np.subtract(a00, iso, out=r00)
    np.subtract(a11, iso, out=r11)
    np.subtract(a22, iso, out=r22)
    # adjugate of cov - iso I: rows 0 x 1 = (u0, u1, d2), 0 x 2 = -(u2, d1, u1),
    # 1 x 2 = (d0, u2, u0)
    d0, d1, d2, u0, u1, u2 = e[14], e[15], e[16], e[17], e[18], e[19]
    for out, (w, x), (y, z) in ((d0, (r11, r22), (a12, a12)), (d1, (r00, r22), (a02, a02)),
                                (d2, (r00, r11), (a01, a01)), (u0, (a01, a12), (a02, r11)),
                                (u1, (a01, a02), (r00, a12)), (u2, (a02, a12), (a01, r22))):
        np.multiply(w, x, out=out)
        out -= np.multiply(y, z, out=t)
    su0, su1, su2, best, c2 = e[20], e[21], e[22], e[23], e[24]
    np.multiply(u0, u0, out=su0)
    np.multiply(u1, u1, out=su1)
    np.multiply(u2, u2, out=su2)
    np.add(su0, su1, out=best)
    best += np.multiply(d2, d2, out=t)
    vec = e[25:28]
    v = list(vec)
    for vi, ci in zip(v, (u0, u1, d2), strict=True):
        np.copyto(vi, ci)
    for cand, (s1, x, s2) in (((u2, d1, u1), (su2, d1, su1)), ((d0, u2, u0), (None, d0, su2))):
        if s1 is None:  # d0^2 + u2^2 + u0^2
            np.multiply(x, x, out=c2)
            c2 += s2
            c2 += su0
        else:  # u2^2 + d1^2 + u1^2
            np.add(s1, np.multiply(x, x, out=t), out=c2)
            c2 += s2
        more = c2 > best
        for vi, ci in zip(v, cand, strict=True):
            np.copyto(vi, ci, where=more)
        np.maximum(best, c2, out=best)
    scale = e[28]
    np.sqrt(best, out=t)
    _divide(1.0, t, scale, 0.0)
    v[0] *= scale
    v[1] *= scale
    v[2] *= scale
    if not best.all():
        np.copyto(v[2], 1.0, where=best == 0)  # any unit vector
    # u, w complete v to an orthonormal basis (Duff et al.)
    sign, k, f = e[29], e[30], e[31]
    np.copysign(1.0, v[2], out=sign)
    np.add(sign, v[2], out=k)
    np.divide(-1.0, k, out=k)
    np.multiply(v[0], v[1], out=f)
    f *= k
    uw = scratch.buffer("eig.uw", (2, 3), n)
    u, w = uw
    np.multiply(v[0], v[0], out=u[0])
    u[0] *= k
    u[0] *= sign
    u[0] += 1.0
    np.multiply(sign, f, out=u[1])
    np.multiply(sign, v[0], out=u[2])
    np.negative(u[2], out=u[2])
    np.copyto(w[0], f)
    np.multiply(v[1], v[1], out=w[1])
    w[1] *= k
    w[1] += sign
    np.negative(v[1], out=w[2])
    pair_vals, pair_vecs = _rotate(cov, uw)
    return [iso, *pair_vals], [vec, *pair_vecs]


def _divide(num: np.ndarray | float, den: np.ndarray, out: np.ndarray, fill: float
            ) -> np.ndarray:
    """num / den into out, `fill` where den is 0 (a masked divide only when one is)."""
    if den.all():
        return np.divide(num, den, out=out)
    out.fill(fill)
    return np.divide(num, den, out=out, where=den != 0)


def cos_sin_into(angle: np.ndarray, cos: np.ndarray, sin: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """`cos_sin` into given arrays (angle is overwritten)."""
    t = np.multiply(angle, 0.5, out=angle)
    np.tan(t, out=t)
    np.multiply(t, t, out=cos)
    cos += 1.0
    np.divide(2.0, cos, out=cos)
    np.multiply(cos, t, out=sin)
    cos -= 1.0
    return cos, sin


def _rotate(cov: np.ndarray, uw: np.ndarray) -> tuple[list, list]:
    """Eigenpairs of symmetric matrices cov (d, d, N) in the planes of the orthonormal
    vectors uw[0] = u, uw[1] = w (2, d, N): a Jacobi rotation of the 2 x 2 projection.
    The results are work arrays of this thread."""
    d, n = uw.shape[1:]
    e = scratch.buffer("rot", (7,), n)
    t, first, cs = e[0], e[1], e[2:4]
    # the projection [[uu, uw], [uw, ww]] = [u w]' (cov [u w])
    cuw = einsum("ijn,ajn->ain", cov, uw, out=scratch.buffer("rot.c", (2, d), n))
    proj = einsum("ain,bin->abn", uw, cuw, out=scratch.buffer("rot.p", (2, 2), n))
    uu, uv, ww = proj[0, 0], proj[0, 1], proj[1, 1]
    # 0.5 atan2(2 uw, uu - ww), cos and sin as cos_sin
    np.subtract(uu, ww, out=t)
    np.multiply(uv, 2, out=first)
    np.arctan2(first, t, out=t)
    t *= 0.5
    c, s = cos_sin_into(t, cs[0], cs[1])
    # Rayleigh quotient c^2 uu + 2 c s uw + s^2 ww
    np.multiply(c, c, out=first)
    first *= uu
    np.multiply(c, 2, out=t)
    t *= s
    t *= uv
    first += t
    np.multiply(s, s, out=t)
    t *= ww
    first += t
    vecs = scratch.buffer("rot.v", (2, d), n)
    einsum("jn,jin->in", cs, uw, out=vecs[0])  # c u + s w
    np.negative(s, out=e[4])
    np.copyto(e[5], c)
    einsum("jn,jin->in", e[4:6], uw, out=vecs[1])  # c w - s u
    uu += ww
    uu -= first
    return [first, uu], [vecs[0], vecs[1]]


def cos_sin(angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin from the half-angle tangent t: with g = 2 / (1 + t^2), cos = g - 1 and
    sin = g t (np.tan is much faster than np.sin and np.cos)."""
    t = np.tan(0.5 * angle)
    g = t * t
    g += 1.0
    np.divide(2.0, g, out=g)
    return g - 1.0, np.multiply(g, t, out=t)


def ldl_inverse(s: np.ndarray, out: np.ndarray, det: np.ndarray, floor: float = 0.0) -> None:
    """(S + floor I)^-1 into out (m, m, N) and its determinant into det, for symmetric S
    (m, m, N), batch axis last (its lower triangle is read); entry by entry for small m:
    S = L D L' (Golub & Van Loan 2013, alg. 4.1.1) without pivoting (S is a covariance),
    then S^-1 = M' D^-1 M with M = L^-1. A row with a zero pivot (singular S) gets NaN,
    flagged by the caller's finiteness mask as in `solve`."""
    m = s.shape[0]
    if m == 2:  # closed form: the adjugate over the determinant (a few passes, not ~25)
        _inverse2(s, out, det, floor)
        return
    low, piv, inv_piv = _ldl(s, floor)
    inv_l: dict = {}  # M = L^-1 below its unit diagonal
    for j in range(m):
        for i in range(j + 1, m):
            v = -low[i, j]
            for q in range(j + 1, i):
                v = v - low[i, q] * inv_l[q, j]
            inv_l[i, j] = v
    for i in range(m):
        for j in range(i, m):  # sum over q >= j of M[q, i] M[q, j] / d_q
            acc = out[i, j]
            np.multiply(inv_piv[j], 1.0 if i == j else inv_l[j, i], out=acc)
            for q in range(j + 1, m):
                mi = inv_l[q, i] if q != i else 1.0
                acc += inv_piv[q] * (mi * inv_l[q, j])
            if i != j:
                out[j, i] = acc
    np.copyto(det, piv[0])
    for pj in piv[1:]:
        det *= pj


def _inverse2(s: np.ndarray, out: np.ndarray, det: np.ndarray, floor: float) -> None:
    """`ldl_inverse` of 2 x 2 matrices: det = a c - b^2 with a, c the floored diagonal
    and b the lower entry; the inverse [c -b; -b a] / det (NaN where det is 0)."""
    a, c, b = out[0, 0], out[1, 1], out[0, 1]
    np.add(s[1, 1], floor, out=a)  # a and c swapped: the adjugate's diagonal
    np.add(s[0, 0], floor, out=c)
    np.multiply(a, c, out=det)
    np.negative(s[1, 0], out=b)
    det -= np.square(b)
    inv = np.divide(1.0, det) if np.count_nonzero(det) == len(det) else \
        np.divide(1.0, det, out=np.full_like(det, np.nan), where=det != 0)
    np.copyto(out[1, 0], b)
    out *= inv


def _ldl(s: np.ndarray, floor: float) -> tuple[dict, list, list]:
    """L (below its unit diagonal), D and D^-1 of S + floor I = L D L' (lower triangle of
    s (m, m, N) read); D^-1 is NaN where a pivot is zero."""
    m = s.shape[0]
    low, piv, inv_piv = {}, [], []
    for j in range(m):
        pj = s[j, j] + floor
        for q in range(j):
            pj -= low[j, q] ** 2 * piv[q]
        piv.append(pj)
        if np.count_nonzero(pj) == pj.size:
            inv_piv.append(np.divide(1.0, pj))
        else:
            inv_piv.append(np.divide(1.0, pj, out=np.full_like(pj, np.nan), where=pj != 0))
        for i in range(j + 1, m):
            v = s[i, j].copy()
            for q in range(j):
                v -= low[i, q] * low[j, q] * piv[q]
            low[i, j] = v * inv_piv[j]
    return low, piv, inv_piv


def ldl_solve(s: np.ndarray, b: np.ndarray, det: np.ndarray, floor: float = 0.0) -> None:
    """S^-1 b in place and det S into det, for symmetric S + floor I, S (m, m, N) (its
    lower triangle is read) and right-hand sides b (m, k, N), batch axis last; entry by
    entry for small m: S = L D L' (Golub & Van Loan 2013, alg. 4.1.1), then
    substitution, without pivoting (S is a covariance). A row with a zero pivot (singular
    S) gets NaN, flagged by the caller's finiteness mask as in `solve`."""
    m = s.shape[0]
    low, piv, inv_piv = _ldl(s, floor)
    tmp = scratch.buffer("ldl.tmp", b.shape[1:-1], b.shape[-1])
    for i in range(m):  # L y = b
        for q in range(i):
            b[i] -= np.multiply(b[q], low[i, q], out=tmp)
    for i in reversed(range(m)):  # D L' x = y
        b[i] *= inv_piv[i]
        for q in range(i + 1, m):
            b[i] -= np.multiply(b[q], low[q, i], out=tmp)
    np.copyto(det, piv[0])
    for pj in piv[1:]:
        det *= pj
