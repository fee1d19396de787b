"""Gating of unlabelled detections: which (track, detection) pairs may belong together.

The gate is the chi-square test on the innovation of the converted measurement,
nu' S^-1 nu <= gamma with S = H P H' + R, where the track is predicted to the scan time
and R is the detection's UCM covariance at its converted point (the same conversion the
filters use; the update itself then averages R over the prediction). A KD-tree over the
detections (SciPy's `cKDTree`) proposes for each track only the detections within a
radius that bounds its gate, so no tracks x detections matrix is built (except for
small scans, `DENSE_PAIRS`, where the tree costs more than the matrix); the pairs
that pass are split into independent clusters (connected components of the bipartite
gate graph), which the associators resolve one at a time. SciPy is imported when a scan
first needs it: a service fed only labelled measurements never loads it (about 40 MB).
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

from ..estimation import gate_jit, jit, models, scratch
from ..estimation.batch import einsum_as_is
from ..estimation.gate_jit import at_point
from ..estimation.linalg import ldl_inverse
from ..estimation.measurements import MeasurementBatch
from .store import TrackArrays

LOG_2PI = np.log(2 * np.pi)
DENSE_PAIRS = 16_384  # tracks x detections below which `near` skips the KD-tree


class Gating:
    """The gated pairs of one scan in one layout. Tracks are `rows` of `arrays`
    (predicted to the scan time: position `mean`, position rows of the covariance
    `cross`, its position block `cov`), detections the scan's converted points
    `z` with covariances `r`. Pair k joins track `ti[k]` and detection `dj[k]`, with
    squared Mahalanobis distance `d2[k]`, log-likelihood `loglik[k]` and innovation
    `nu[k]`. A gating made by `restrict` takes mean, cross, r, d2, nu (which GNN never
    reads) from the gating it was cut from on first use only."""

    def __init__(self, arrays: TrackArrays, rows: np.ndarray, mean: np.ndarray,
                 cross: np.ndarray, z: np.ndarray, r: np.ndarray, ti: np.ndarray,
                 dj: np.ndarray, d2: np.ndarray, loglik: np.ndarray, nu: np.ndarray) -> None:
        self.arrays, self.rows, self.z, self.ti, self.dj = arrays, rows, z, ti, dj
        # (T, d), (T, d, n), (D, d, d), (K,) x 2, (K, d)
        self.__dict__.update(mean=mean, cross=cross, r=r, d2=d2, loglik=loglik, nu=nu)
        self._cut: tuple | None = None  # restrict's (source, tracks, pairs, dets)
        self.score: tuple | None = None  # `association.scores` of the pairs: (pd, lam, score)

    @classmethod
    def cut(cls, g: Gating, tracks: np.ndarray, z: np.ndarray, ti: np.ndarray,
            dj: np.ndarray, pairs: np.ndarray, dets: np.ndarray | None) -> Gating:
        """The gating of the tracks `tracks` (mask over g.rows) and pairs `pairs` (mask)
        of g, and of its detections `dets` (None: all): the rest on first use."""
        out = cls.__new__(cls)
        out.arrays, out.rows, out.z, out.ti, out.dj = g.arrays, g.rows[tracks], z, ti, dj
        out._cut = (g, tracks, pairs, dets)
        out.score = None if g.score is None else (*g.score[:2], g.score[2][pairs])
        return out

    @functools.cached_property
    def loglik(self) -> np.ndarray:
        return self._cut[0].loglik[self._cut[2]]

    @functools.cached_property
    def mean(self) -> np.ndarray:
        return self._cut[0].mean[self._cut[1]]

    @functools.cached_property
    def cross(self) -> np.ndarray:
        return self._cut[0].cross[self._cut[1]]

    @functools.cached_property
    def r(self) -> np.ndarray:
        g, dets = self._cut[0], self._cut[3]
        return g.r if dets is None else g.r[dets]

    @functools.cached_property
    def d2(self) -> np.ndarray:
        return self._cut[0].d2[self._cut[2]]

    @functools.cached_property
    def nu(self) -> np.ndarray:
        return self._cut[0].nu[self._cut[2]]

    @property
    def cov(self) -> np.ndarray:
        """(T, d, d) predicted position covariances."""
        return self.cross[:, :, :self.arrays.dim]


@functools.lru_cache(maxsize=64)
def gate_threshold(probability: float, dim: int) -> float:
    """The chi-square gate gamma with P(d2 <= gamma) = probability for a true pair (the
    inverse of the chi-square survival function)."""
    from scipy.special import chdtri

    return float(chdtri(dim, 1.0 - probability))


def convert(batch: MeasurementBatch) -> tuple[np.ndarray, np.ndarray]:
    """The detections' converted points z (D, d) and covariances R at those points."""
    return at_point(batch)


def gate(arrays: TrackArrays, rows: np.ndarray, z: np.ndarray, r: np.ndarray, t: float,
         q: float, gamma: float, predict: Callable | None = None) -> Gating:
    """Predict the tracks `rows` to `t` and find their pairs with the converted detections
    z, R (`convert`) within the gate `gamma`. `predict(arrays, rows, t)`: the filter's
    own prediction to gate with (an IMM's: `IMM.gate_prediction`): position mean (T, d),
    position rows of the covariance (T, d, n), and a function that turns the pairs'
    log-likelihoods under that covariance into the filter's own (or None); None: the
    store's state by the motion model of its order with white noise q."""
    d, o, n = arrays.dim, arrays.order, arrays.n
    # the prediction batch axis last (long inner loops), into new arrays: the Gating
    # keeps them, as row-major views
    index, k = scratch.span(rows), len(rows)
    mean_s, cross_s = np.empty((d, k)), np.empty((d, n, k))
    mixture = None  # the filter's second component for the likelihood, if it has one
    if k and predict is not None:
        got = predict(arrays, rows, t)
        mean_s, cross_s = np.ascontiguousarray(got[0].T), np.ascontiguousarray(
            got[1].transpose(1, 2, 0))
        mixture = got[2]
    elif k:
        xs, ps = scratch.to_soa(arrays.x[index], "gate.x"), scratch.to_soa(arrays.p[index],
                                                                         "gate.p")
        models.predict_position_soa(xs, ps, t - arrays.t[index], o, d, q, mean_s, cross_s)
    mean, cross = mean_s.T, cross_s.transpose(2, 0, 1)  # (T, d), (T, d, n)
    empty = np.zeros(0, dtype=int)
    if not k or not len(z):
        return Gating(arrays, rows, mean, cross, z, r, empty, empty, np.zeros(0), np.zeros(0),
                      np.zeros((0, d)))
    # the gate's largest semi-axis is sqrt(gamma lambda_max(S)) <= sqrt(gamma (tr P + tr R))
    # (the traces as sums over strided views of the diagonals)
    m = len(z)
    tr_r = np.maximum.reduce(np.add.reduce(r.reshape(m, d * d)[:, ::d + 1], axis=1))
    tr_p = np.add.reduce(cross_s.reshape(d * n, k)[:d * (n + 1):n + 1], axis=0)
    radius = np.sqrt(gamma * (tr_p + tr_r))
    ti, dj = near(mean, z, radius)
    if jit.ready():
        nu, d2, det = gate_jit.gate_pairs(ti, dj, z, mean_s, cross_s, r)
    else:
        nu, d2, det = pair_distances(ti, dj, z, mean_s, cross_s, r)
    keep = (d2 <= gamma) & (det > 0)
    ti, dj, d2, nu, det = ti[keep], dj[keep], d2[keep], nu[keep], det[keep]
    loglik = -0.5 * (d2 + np.log(det) + d * LOG_2PI)
    if mixture is not None:  # the likelihood of the filter's two-component mixture
        loglik = mixture(loglik, ti, nu, r[dj])
    return Gating(arrays, rows, mean, cross, z, r, ti, dj, d2, loglik, nu)


def pair_distances(ti: np.ndarray, dj: np.ndarray, z: np.ndarray, mean_s: np.ndarray,
                   cross_s: np.ndarray, r: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pairs' innovations nu (K, d), squared Mahalanobis distances under
    S = P_pos + R and det S (mean_s (d, T), cross_s (d, n, T), batch axis last): the
    NumPy form of `gate_kernel.gate_pairs`."""
    d = z.shape[1]
    nu = np.empty((len(ti), d))  # (K, d), read through its transpose
    nut = nu.T
    np.subtract(z.T.take(dj, 1), mean_s.take(ti, 1), out=nut)
    s = np.add(cross_s[:, :d].take(ti, 2), r.transpose(1, 2, 0).take(dj, 2))  # (d, d, K)
    # S^-1 and det S of every pair at once, batch axis last (`linalg.ldl_inverse`)
    sinv, det = np.empty((d, d, len(ti))), np.empty(len(ti))
    ldl_inverse(s, sinv, det)
    return nu, einsum_as_is("in,ijn,jn->n", nut, sinv, nut), det


def near(mean: np.ndarray, z: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pairs (track i, detection j) with |z_j - mean_i| <= radius_i, tracks in
    ascending order: from a KD-tree over the detections (SciPy's `cKDTree`), or, while
    tracks x detections stays under `DENSE_PAIRS`, from the dense distance matrix (the
    same pairs; building and querying the tree costs more than the whole matrix then)."""
    if len(mean) * len(z) <= DENSE_PAIRS:
        d2 = np.square(np.subtract.outer(mean[:, 0], z[:, 0]))
        for k in range(1, z.shape[1]):  # axis by axis: long inner loops, not runs of d
            diff = np.subtract.outer(mean[:, k], z[:, k])
            d2 += np.square(diff, out=diff)
        ti, dj = (d2 <= np.square(radius)[:, None]).nonzero()
        return ti, dj
    from scipy.spatial import cKDTree

    found = cKDTree(z).query_ball_point(mean, radius, return_sorted=False)
    counts = np.fromiter(map(len, found), int, len(found))
    ti = np.repeat(np.arange(len(mean)), counts)
    dj = np.fromiter((j for js in found for j in js), int, int(counts.sum()))
    return ti, dj


def clusters(ti: np.ndarray, dj: np.ndarray, n_tracks: int, n_dets: int) -> np.ndarray:
    """Cluster label of each pair: connected components of the graph whose nodes are the
    tracks and the detections and whose edges are the pairs, by label propagation (each
    node takes the smallest track index it is connected to; a few vectorised sweeps, as
    many as the widest cluster is long). `clusters_reference` is the textbook search."""
    if not len(ti):
        return np.zeros(0, dtype=int)
    track = np.arange(n_tracks)
    det = np.full(n_dets, n_tracks)
    while True:
        np.minimum.at(det, dj, track[ti])
        new = track.copy()
        np.minimum.at(new, ti, det[dj])
        if np.array_equal(new, track):
            return track[ti]
        track = new


def clusters_reference(ti: np.ndarray, dj: np.ndarray, n_tracks: int,
                       n_dets: int) -> np.ndarray:
    """`clusters` by SciPy's connected components of the sparse bipartite graph."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if not len(ti):
        return np.zeros(0, dtype=int)
    n = n_tracks + n_dets
    graph = coo_matrix((np.ones(len(ti)), (ti, n_tracks + dj)), shape=(n, n))
    return connected_components(graph, directed=False)[1][ti]


def restrict(g: Gating, tracks: np.ndarray, dets: np.ndarray | None = None,
             pairs: np.ndarray | None = None) -> Gating:
    """The gating of a subset of the tracks (boolean mask over g.rows) and of the
    detections (ascending indices into g.z; None: all of them) of `g`, of its pairs
    `pairs` (boolean mask; None: all), its pairs renumbered."""
    t_new = np.add.accumulate(tracks, dtype=np.intp)  # 1 + the new index of a kept track
    keep = tracks[g.ti]
    if pairs is not None:
        keep &= pairs
    if dets is not None:
        d_new = np.zeros(len(g.z), dtype=np.intp)
        d_new[dets] = np.arange(1, len(dets) + 1)
        dj = d_new[g.dj]
        keep &= dj > 0
        dj = dj[keep]
        dj -= 1
        z = g.z[dets]
    else:
        dj, z = g.dj[keep], g.z
    ti = t_new[g.ti[keep]]
    ti -= 1
    return Gating.cut(g, tracks, z, ti, dj, keep, dets)


def singles(g: Gating) -> tuple[np.ndarray, np.ndarray]:
    """The pairs that are a cluster on their own (their track gates no other detection
    and their detection no other track), and the others."""
    if not len(g.ti):
        return g.ti, g.ti
    alone = (np.bincount(g.ti)[g.ti] == 1) & (np.bincount(g.dj)[g.dj] == 1)
    return alone.nonzero()[0], (alone == 0).nonzero()[0]


def split(g: Gating, multi: np.ndarray) -> list[np.ndarray]:
    """The pairs `multi` (the non-singleton ones of `singles`) by cluster: a list of
    pair indices per cluster, in cluster order."""
    if not len(multi):
        return []
    label = clusters(g.ti[multi], g.dj[multi], len(g.rows), len(g.z))
    order = np.argsort(label, kind="stable")
    return np.split(multi[order], np.flatnonzero(np.diff(label[order])) + 1)
