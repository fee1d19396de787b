"""Data association of unlabelled radar scans: what GNN and JPDA share (`ScanAssociator`), and
global nearest neighbour (JPDA: `jpda`).

Both start from the gated pairs (`gating`) and treat each independent cluster alone.
The score of a pair is the log-likelihood ratio of "track i produced detection j" to "j
is clutter": ln(Pd N(nu; 0, S) / lambda), with the sensor's detection probability Pd and
clutter density lambda (`SensorModels`); a track detecting nothing scores ln(1 - Pd)
(Bar-Shalom, Willett & Tian, "Tracking and Data Fusion", 2011, ch. 6-7; Blackman &
Popoli, "Design and Analysis of Modern Tracking Systems", 1999, ch. 6).

- `GNNAssociator`: the most likely joint assignment of each cluster, solved as a
  rectangular assignment with one missed-detection column per track (SciPy's
  `linear_sum_assignment`); a cluster of one track and one detection is decided by
  comparing the two scores, without the solver.
- `JPDAAssociator` (`jpda.py`): the marginal association probabilities beta of every pair over all
  feasible joint events of the cluster, enumerated exactly while a cluster has at most
  `max_events` events, else by Fitzgerald's "cheap JPDA" approximation
  (beta_ij = G_ij / (T_i + S_j - G_ij + 1 - Pd), IEEE AES Magazine 1985, with the
  row sums T and column sums S of the likelihood ratios G). Each track is then updated
  once with the probabilistic data association (PDA) of its detections.

Any filter (single model, IMM, VDF) is the updater: association scores and the PDA
weights use the combined (moment-matched) state of the track predicted by its motion
model of the store's order; an IMM thus enters the association through its mixture
estimate, not through per-mode likelihoods (docs/architecture.md).
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import defaults
from ..wire import TIME_TOL
from .batches import Detections, Unlabelled
from .gating import Gating, convert, gate, gate_threshold, restrict, singles, split
from .hypotheses import Hypotheses, Seen
from .second_look import SecondLook
from .store import TrackStore

UNLIKELY = 1e12  # cost of a pair outside the gate in an assignment matrix
PACK = 32  # tracks of the small clusters solved together as one block-diagonal assignment


@dataclass
class SensorModel:
    pd: float = defaults.PD
    clutter_density: float | None = None  # per m^dim; None: estimated from the scans
    estimate: float = 0.0  # running estimate of the clutter density


@dataclass
class SensorModels:
    """Detection probability and clutter density of each sensor: from configuration
    (`--pd`, `--clutter-density`, or a JSON file {sensor: {pd, clutter_density}}) or,
    for the density, estimated: the detections of a scan that fall in no gate, per unit
    of the volume (area in 2-D) of the box that holds the scan's detections, averaged
    over scans with weight `smoothing`."""

    pd: float = defaults.PD
    clutter_density: float | None = defaults.CLUTTER_DENSITY
    per_sensor: dict[str, SensorModel] = field(default_factory=dict)
    smoothing: float = 0.1

    @classmethod
    def from_file(cls, path: str | Path, pd: float = defaults.PD,
                  clutter_density: float | None = defaults.CLUTTER_DENSITY) -> SensorModels:
        return cls.from_json(Path(path).read_text(), pd, clutter_density)

    @classmethod
    def from_json(cls, text: str, pd: float = defaults.PD,
                  clutter_density: float | None = defaults.CLUTTER_DENSITY) -> SensorModels:
        data = json.loads(text)
        out = cls(pd, clutter_density)
        for name, cfg in data.items():
            out.per_sensor[name] = SensorModel(float(cfg.get("pd", pd)),
                                               cfg.get("clutter_density", clutter_density))
        return out

    def model(self, sensor: str) -> SensorModel:
        m = self.per_sensor.get(sensor)
        if m is None:
            m = self.per_sensor[sensor] = SensorModel(self.pd, self.clutter_density)
        return m

    def density(self, sensor: str, z: np.ndarray, ungated: int) -> float:
        """The clutter density to use for this scan of `sensor` (then updates the
        estimate with it)."""
        m = self.model(sensor)
        if m.clutter_density is not None:
            return float(m.clutter_density)
        if len(z) > 1:
            extent = np.maximum(np.ptp(z, axis=0), 1.0)
            seen = ungated / float(np.prod(extent))
            m.estimate = seen if m.estimate <= 0 else \
                (1 - self.smoothing) * m.estimate + self.smoothing * seen
        return max(m.estimate, 1e-15)


class ScanAssociator:
    """What GNN and JPDA share: one scan (all detections of one sensor and time) against
    the unlabelled tracks of its layout, in two stages. The established (confirmed) tracks
    take their detections first, with this associator; the tentative tracks then share,
    by nearest neighbour, the detections the established ones left (so a tentative track
    born of clutter never pulls on an established one); what is left starts new tracks.
    The clutter density is estimated (when not configured) from the detections outside
    every track's gate."""

    def __init__(self, q: float, sensors: SensorModels | None = None,
                 gate_probability: float = defaults.GATE_PROBABILITY) -> None:
        self.q, self.sensors = q, sensors or SensorModels()
        self.predict = None  # the filter's gate prediction (`gating.gate`), if it has one
        self.gate_probability = gate_probability
        # doubtful assignments of confirmed tracks, kept a scan (the tracker sets it)
        self.second_look = SecondLook(defaults.SECOND_LOOK)
        self.max_speed = defaults.MAX_SPEED  # m/s: the fastest target (the tracker sets it)

    def split(self, scan: Unlabelled) -> list[tuple[list[int], Detections]]:
        """The scan's detections one dimension at a time (2-D and 3-D detections in one
        scan: each with the tracks of its dimension)."""
        if not scan.parts:
            return [([], Detections(scan.sensor, scan.t, None))]
        return [(index, Detections(scan.sensor, scan.t, batch)) for index, batch in scan.parts]

    def associate(self, store: TrackStore, part: Detections) -> Hypotheses:
        batch = part.batch
        if batch is None:
            return self._nothing_seen(store, part.t, part.sensor)
        t, n, dim = float(batch.t[0]), len(batch.t), batch.dim
        arrays = store.layout(dim)
        rows = arrays.rows()
        rows = rows[arrays.plot[rows] & (arrays.t[rows] <= t + TIME_TOL)]
        hyp = Hypotheses(dim)
        z, r = convert(batch)
        gamma = gate_threshold(self.gate_probability, dim)
        every = gate(arrays, rows, z, r, t, self.q, gamma, self.predict)

        def density(g: Gating) -> float:  # the sensor's clutter, from the detections ungated
            ungated = n - np.count_nonzero(np.bincount(g.dj, minlength=n))
            return self.sensors.density(part.sensor, z, ungated)

        lam = density(every)
        pd = self.sensors.model(part.sensor).pd
        score, miss = scores(every, pd, lam)  # once for both stages

        def gate_rows(some: np.ndarray) -> tuple[Gating, np.ndarray]:
            g = gate(arrays, some, z, r, t, self.q, gamma, self.predict)
            return g, scores(g, pd, lam)[0]

        if self.second_look.decide(arrays, every, t, score, miss, gate_rows):
            every = gate_rows(rows)[0]  # a track took its doubtful update after all
            lam = density(every)
        confirmed = arrays.confirmed[rows]
        g = restrict(every, confirmed, pairs=self.reachable(every, z, r, t))
        free = self.resolve(g, np.arange(n), pd, lam, hyp)
        seen = hyp.seen[-1]  # the confirmed tracks': a doubtful detection gets a second look
        taken = seen.rows[seen.detected]
        far = None
        if hyp.index and len(taken):  # where each took its detection (GNN's pairs)
            det = np.full(len(arrays.t), -1, dtype=np.intp)
            det[hyp.rows[-1]] = hyp.index[-1]
            far = self.second_look.far(arrays, taken, z, r, det[taken], t)
        self.second_look.note(arrays, taken, seen.gain[seen.detected] - miss, t, far)
        free = self.second_chance(g, free, z, r, t, pd, lam, hyp)
        free = gnn(restrict(every, ~confirmed, free), free, pd, lam, hyp)
        if len(free):
            hyp.unassociated = free.tolist()
        return hyp

    def reachable(self, g: Gating, z: np.ndarray, r: np.ndarray, t: float
                  ) -> np.ndarray | None:
        """The pairs of `g` the established tracks may take (None: all): not the
        detections farther from a track's last position than the fastest target flies
        meanwhile (`max_speed`, plus 3 sigma of both positions), a speed gate (Blackman
        & Popoli 1999, sec. 4.5). The widest mode's gate of a track coasting through
        missed scans reaches kilometres out: JPDA weighed false detections there into
        the update, GNN took one for a slow helicopter (docs/accuracy.md, "JPDA with
        the IMM", "Slow and tight flyers")."""
        a, rows, d = g.arrays, g.rows[g.ti], g.arrays.dim
        dt = t - a.t[rows]
        var = np.trace(r[g.dj], axis1=1, axis2=2) + np.trace(a.p[rows, :d, :d], axis1=1,
                                                             axis2=2)
        far = np.linalg.norm(z[g.dj] - a.x[rows, :d], axis=1) > \
            self.max_speed * dt + 3.0 * np.sqrt(var)
        return ~far if far.any() else None

    def second_chance(self, g: Gating, free: np.ndarray, z: np.ndarray, r: np.ndarray,
                      t: float, pd: float, lam: float, hyp: Hypotheses) -> np.ndarray:
        """After the established tracks' association `g` (detections `free` left):
        detections a missed track passed over by less than the second look's margin,
        taken as a branch set aside for the next scan (`SecondLook`); the detections
        still free."""
        return free

    def resolve(self, g: Gating, index: np.ndarray, pd: float, lam: float,
                hyp: Hypotheses) -> np.ndarray:
        """Associate the gated pairs of `g` (its detections are scan[index]) into `hyp`;
        returns the indices of the detections left for tentative tracks."""
        raise NotImplementedError

    def _nothing_seen(self, store: TrackStore, now: float, sensor: str) -> Hypotheses:
        """An empty scan: the sensor saw none of the unlabelled tracks (of any layout:
        an empty scan says nothing of its dimension)."""
        hyp = Hypotheses(0)
        miss = miss_score(self.sensors.model(sensor).pd)
        for arrays in store.layouts.values():
            rows = arrays.rows()
            rows = rows[arrays.plot[rows] & (arrays.t[rows] <= now)]
            if len(rows):
                hyp.seen.append(Seen(arrays, rows, np.zeros(len(rows), dtype=bool),
                                     np.full(len(rows), miss), miss))
        return hyp


def scores(g: Gating, pd: float, lam: float) -> tuple[np.ndarray, float]:
    """The log-likelihood ratio of each gated pair, ln(Pd N(nu; 0, S) / lambda), and of a
    track that detected nothing, ln(1 - Pd). Kept in g (and taken by `restrict`)."""
    if g.score is None or g.score[:2] != (pd, lam):
        g.score = (pd, lam, np.log(pd) + g.loglik - np.log(lam))
    return g.score[2], miss_score(pd)


@functools.lru_cache(maxsize=64)
def miss_score(pd: float) -> float:
    return float(np.log1p(-pd)) if pd < 1 else -UNLIKELY


def gnn(g: Gating, index: np.ndarray, pd: float, lam: float, hyp: Hypotheses) -> np.ndarray:
    """Global nearest neighbour on the gated pairs of `g` (detections scan[index]): the
    best joint assignment of each cluster, recorded in `hyp`; returns the indices of the
    detections no track took."""
    score, miss = scores(g, pd, lam)
    single, multi = singles(g)
    pairs = np.concatenate([single[score[single] > miss], *assign(g, multi, score, miss)])
    ti, dj = g.ti[pairs], g.dj[pairs]
    if len(pairs):
        hyp.assign(index[dj], g.rows[ti])
    hit = np.zeros(len(g.rows), dtype=bool)
    hit[ti] = True
    gain = np.empty(len(g.rows))
    gain.fill(miss)
    gain[ti] = score[pairs]
    hyp.seen.append(Seen(g.arrays, g.rows, hit, gain, miss))
    free = np.ones(len(index), dtype=bool)
    free[dj] = False
    return index[free]


def assign(g: Gating, multi: np.ndarray, score: np.ndarray, miss: float) -> list[np.ndarray]:
    """The pairs chosen among the pairs `multi` (clusters of two or more tracks or
    detections): per cluster, the rectangular assignment of its tracks to its detections
    or to a missed-detection column of their own, costs -score and -miss (SciPy's
    `linear_sum_assignment`). Clusters are solved together, as one block-diagonal matrix,
    while they hold at most `PACK` tracks in all: a pair of two clusters costs UNLIKELY,
    never better than a miss, so each block's optimum is its cluster's, and up to PACK
    tracks the clusters need not even be found. tests/reference/association.py solves them
    one by one."""
    from scipy.optimize import linear_sum_assignment  # SciPy only once scans come

    if not len(multi):
        return []
    groups, k, cl = [multi], multi, None
    tpos, nt = _number(g.ti[k], cl, len(g.rows), 1)
    if nt[0] > PACK:  # too many tracks for one block: cut it into clusters
        groups = split(g, multi)
        k = np.concatenate(groups)
        cl = np.repeat(np.arange(len(groups)), [len(x) for x in groups])
        tpos, nt = _number(g.ti[k], cl, len(g.rows), len(groups))
    dpos, nd = _number(g.dj[k], cl, len(g.z), len(groups))
    acc = np.add.accumulate
    t_cum, d_cum = acc(nt), acc(nd)
    if t_cum[-1] <= PACK:  # one block
        t_end, d_end, p_end = t_cum[-1:], d_cum[-1:], [len(k)]
    else:
        pack = (t_cum - nt) // PACK  # clusters packed by their first track
        ends = np.concatenate([(pack[1:] != pack[:-1]).nonzero()[0], [len(pack) - 1]])
        t_end, d_end = t_cum[ends], d_cum[ends]
        p_end = acc([len(x) for x in groups])[ends].tolist()
    out, t0, d0, p0 = [], 0, 0, 0
    for t1, d1, p1 in zip(t_end.tolist(), d_end.tolist(), p_end, strict=True):
        n_t, n_d = t1 - t0, d1 - d0
        ti, dj, kk = tpos[p0:p1], dpos[p0:p1], k[p0:p1]
        if t0:
            ti, dj = ti - t0, dj - d0
        cost = np.empty((n_t, n_d + n_t))
        cost.fill(UNLIKELY)
        cost[ti, dj] = -score[kk]
        cost.reshape(-1)[n_d:n_t * (n_d + n_t):n_d + n_t + 1] = -miss  # the miss columns
        pair = np.empty((n_t, n_d), dtype=np.intp)
        pair.fill(-1)
        pair[ti, dj] = kk
        r, c = linear_sum_assignment(cost)
        hit = c < n_d
        chosen = pair[r[hit], c[hit]]
        out.append(chosen[chosen >= 0])
        t0, d0, p0 = t1, d1, p1
    return out


def _number(node: np.ndarray, cl: np.ndarray | None, n_nodes: int, n_clusters: int
            ) -> tuple[np.ndarray, np.ndarray]:
    """Number the tracks (or detections) `node` of pairs of clusters `cl` (each node in
    one cluster; None: all in one) consecutively in cluster order, then by node: each
    pair's number, and the count of nodes per cluster."""
    if cl is None:  # one cluster: the nodes present, numbered in order
        present = np.zeros(n_nodes, dtype=np.intp)
        present[node] = 1
        number = np.add.accumulate(present)
        return number[node] - 1, number[-1:]
    cluster = np.full(n_nodes, n_clusters)
    cluster[node] = cl
    present = cluster < n_clusters
    order = np.argsort(cluster, kind="stable")[:int(present.sum())]
    number = np.empty(n_nodes, dtype=int)
    number[order] = np.arange(len(order))
    return number[node], np.bincount(cluster[order], minlength=n_clusters)


class GNNAssociator(ScanAssociator):
    """Global nearest neighbour: the best joint assignment of each cluster."""

    def resolve(self, g: Gating, index: np.ndarray, pd: float, lam: float,
                hyp: Hypotheses) -> np.ndarray:
        return gnn(g, index, pd, lam, hyp)

    def second_chance(self, g: Gating, free: np.ndarray, z: np.ndarray, r: np.ndarray,
                      t: float, pd: float, lam: float, hyp: Hypotheses) -> np.ndarray:
        """Of each confirmed track that missed, its likeliest free gated detection within
        the margin below a miss and within an aircraft's reach (one track a detection,
        likeliest first), its branch set aside (`SecondLook.note(missed=True)`)."""
        look = self.second_look
        if look.margin <= 0 or not len(g.ti) or not len(free):
            return free
        score, miss = scores(g, pd, lam)
        lead = score - miss
        open_ = np.zeros(len(g.z), dtype=bool)
        open_[free] = True
        k = np.flatnonzero(~hyp.seen[-1].detected[g.ti] & open_[g.dj] & (lead > -look.margin))
        if not len(k):
            return free
        k = k[~look.far(g.arrays, g.rows[g.ti[k]], z, r, g.dj[k], t)]
        k = k[np.argsort(-lead[k], kind="stable")]
        used_t: set[int] = set()
        pick: list[int] = []
        for kk, ti, dj in zip(k.tolist(), g.ti[k].tolist(), g.dj[k].tolist(), strict=True):
            if ti in used_t or not open_[dj]:
                continue
            used_t.add(ti)
            open_[dj] = False
            pick.append(kk)
        if not pick:
            return free
        p = np.array(pick, dtype=np.intp)
        rows = g.rows[g.ti[p]]
        hyp.assign(g.dj[p], rows)
        look.note(g.arrays, rows, lead[p], t, missed=True)
        return free[open_[free]]
