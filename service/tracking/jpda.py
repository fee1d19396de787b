"""Joint probabilistic data association (`JPDAAssociator`; what it shares with GNN is
`plot_association.ScanAssociator`): the marginal association probabilities of every
gated pair, each established track updated once by the PDA of its detections, beyond
its speed gate none (docs/protocol.md §3.2)."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence

import numpy as np

from .. import defaults
from .gating import Gating, singles, split
from .hypotheses import Hypotheses, Seen, WeightedUpdate
from .plot_association import ScanAssociator, SensorModels, miss_score, scores
from .protocols import Stage


class JPDAAssociator(ScanAssociator):
    """Joint probabilistic data association: each established track updated with all its
    gated detections, weighted by their marginal association probabilities."""

    def __init__(self, q: float, sensors: SensorModels | None = None,
                 gate_probability: float = defaults.GATE_PROBABILITY,
                 predict: Callable | None = None, stages: Sequence[Stage] = (),
                 max_events: int = defaults.JPDA_MAX_EVENTS) -> None:
        super().__init__(q, sensors, gate_probability, predict, stages)
        self.max_events = max_events

    def resolve(self, g: Gating, index: np.ndarray, pd: float, lam: float,
                hyp: Hypotheses) -> np.ndarray:
        ratio = np.exp(scores(g, pd, lam)[0])  # G of each pair
        beta = np.zeros(len(ratio))
        single, multi = singles(g)
        groups = split(g, multi)
        beta[single] = ratio[single] / (ratio[single] + (1 - pd))
        for k in groups:
            beta[k] = self._marginals(g.ti[k], g.dj[k], ratio[k], 1 - pd)
        update, mass = pda(g, beta, pd, lam)
        if len(update.rows):
            hyp.weighted.append(update)
        # M of N counts a track as seen when it was more likely detected than not; the
        # score gains the log of the track's likelihood ratio, detected or not
        gain = np.log(np.bincount(g.ti, ratio, len(g.rows)) + (1 - pd))
        hyp.seen.append(Seen(g.arrays, g.rows, mass >= 0.5, gain, miss_score(pd)))
        # a detection mostly explained as clutter is left to tentative and new tracks
        claimed = np.bincount(g.dj, beta, len(index))
        return index[claimed < 0.5]

    def _marginals(self, ti: np.ndarray, dj: np.ndarray, g: np.ndarray,
                   miss: float) -> np.ndarray:
        """beta of each pair of one cluster: exact over the joint events, or cheap JPDA."""
        tracks, ti = np.unique(ti, return_inverse=True)
        dets, dj = np.unique(dj, return_inverse=True)
        counts = np.bincount(ti, minlength=len(tracks)) + 1
        if float(np.prod(counts.astype(float))) > self.max_events:
            t_sum = np.bincount(ti, g, len(tracks))
            s_sum = np.bincount(dj, g, len(dets))
            return g / (t_sum[ti] + s_sum[dj] - g + miss)
        options = [[(-1, miss)] + [(int(dj[k]), float(g[k])) for k in np.flatnonzero(ti == i)]
                   for i in range(len(tracks))]
        index = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(ti, dj, strict=True))}
        mass = np.zeros(len(g))
        total = 0.0
        for event in itertools.product(*options):
            used = [d for d, _ in event if d >= 0]
            if len(used) != len(set(used)):
                continue  # a detection claimed twice
            w = float(np.prod([v for _, v in event]))
            total += w
            for i, (d, _) in enumerate(event):
                if d >= 0:
                    mass[index[i, d]] += w
        return mass / total if total > 0 else mass


def pda(g: Gating, beta: np.ndarray, pd: float, lam: float
        ) -> tuple[WeightedUpdate, np.ndarray]:
    """The PDA update of every gated track as one equivalent measurement: with
    b = sum_j beta_j and beta_0 = 1 - b, the combined innovation nu = sum_j beta_j nu_j
    equals the update of a Kalman filter by z~ = H x + nu / b with covariance
    R~ = R / b + (beta_0 / b) H P H' (the gain scales by b and P - K~ S~ K~' = P - b K S K'),
    plus the spread of the innovations K (sum_j beta_j nu_j nu_j' - nu nu') K' added to P
    afterwards (Bar-Shalom, Willett & Tian 2011, sec. 6.4). R is the beta-weighted mean of
    the detections' covariances; the gain K of the spread is that of the gating
    prediction. Returns the update of the tracks with any detection mass, and the mass
    (probability of detection) of every gated track."""
    t_count, d = len(g.rows), g.arrays.dim
    b = np.bincount(g.ti, beta, t_count)
    nu = np.zeros((t_count, d))
    np.add.at(nu, g.ti, beta[:, None] * g.nu)
    second = np.zeros((t_count, d, d))
    np.add.at(second, g.ti, beta[:, None, None] * g.nu[:, :, None] * g.nu[:, None, :])
    r = np.zeros((t_count, d, d))
    np.add.at(r, g.ti, beta[:, None, None] * g.r[g.dj])
    some = b > 1e-9
    safe = np.where(some, b, 1.0)
    r_mean = r / safe[:, None, None]
    z = g.mean + nu / safe[:, None]
    s = g.cov + r_mean
    gain = np.linalg.solve(s, g.cross).transpose(0, 2, 1)  # K = P H' S^-1 (n, d)
    spread_d = second - nu[:, :, None] * nu[:, None, :]
    spread = gain @ spread_d @ gain.transpose(0, 2, 1)
    kept = some[g.ti]  # the pairs of the tracks updated, their tracks renumbered
    ti = (np.cumsum(some) - 1)[g.ti[kept]]
    return WeightedUpdate(g.arrays, g.rows[some], z[some], r_mean[some], b[some],
                          spread[some], ti, g.z[g.dj[kept]], g.r[g.dj[kept]], beta[kept],
                          pd, lam), b
