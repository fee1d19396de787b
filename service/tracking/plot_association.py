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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import defaults
from ..wire import TIME_TOL
from .batches import Detections, Unlabelled
from .gating import Gating, convert, gate, gate_threshold, restrict, singles, split
from .hypotheses import Hypotheses, Seen
from .protocols import Stage
from .store import TrackArrays, TrackStore

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


@dataclass
class Scene:
    """One part of an unlabelled scan against the unlabelled tracks of its layout, as the
    association and its stages see it (`protocols.Scene`): the tracks in play, the
    detections converted, the sensor's Pd and clutter density, every track gated."""

    arrays: TrackArrays
    rows: np.ndarray
    z: np.ndarray
    r: np.ndarray
    t: float
    pd: float
    lam: float
    every: Gating
    hyp: Hypotheses
    gate: Callable[[np.ndarray], Gating]  # rows of the store gated against the detections
    density: Callable[[Gating], float]  # the clutter density, from the detections ungated

    def regate(self) -> None:
        """Gate every track in play again (the store's rows changed)."""
        self.every = self.gate(self.rows)
        self.lam = self.density(self.every)


class ScanAssociator:
    """One scan part (the detections of one sensor, time and dimension) against the
    unlabelled tracks of its layout, as the textbook's steps: gate every track; the
    established (confirmed) tracks take their detections (`resolve`: GNN's assignment or
    JPDA's weights); the tentative tracks share, by nearest neighbour, what they left (a
    tentative track born of clutter never pulls on an established one); the rest start
    tracks. `stages` (`protocols.Stage`) wrap the established tracks' step: which pairs
    they may take (`stages.SpeedGate`), what happens before (`second_look.SecondLook`)
    and after (`stages.SecondChance`); each can be left out. `predict`: the filter's gate
    prediction (`gating.gate`; None: the store's state). The clutter density is
    estimated (when not configured) from the detections outside every track's gate."""

    def __init__(self, q: float, sensors: SensorModels | None = None,
                 gate_probability: float = defaults.GATE_PROBABILITY,
                 predict: Callable | None = None, stages: Sequence[Stage] = ()) -> None:
        self.q, self.sensors = q, sensors or SensorModels()
        self.gate_probability, self.predict = gate_probability, predict
        self.stages = tuple(stages)

    def split(self, scan: Unlabelled) -> list[tuple[list[int], Detections]]:
        """The scan's detections one dimension at a time (2-D and 3-D detections in one
        scan: each with the tracks of its dimension)."""
        if not scan.parts:
            return [([], Detections(scan.sensor, scan.t, None))]
        return [(index, Detections(scan.sensor, scan.t, batch)) for index, batch in scan.parts]

    def associate(self, store: TrackStore, part: Detections) -> Hypotheses:
        if part.batch is None:
            return self._nothing_seen(store, part.t, part.sensor)
        scene = self.scene(store, part)
        for stage in self.stages:
            stage.before(scene)
        every, n, hyp = scene.every, len(scene.z), scene.hyp
        confirmed = scene.arrays.confirmed[scene.rows]
        g = restrict(every, confirmed, pairs=self._pairs(scene))
        free = self.resolve(g, np.arange(n), scene.pd, scene.lam, hyp)
        for stage in self.stages:
            free = stage.after(scene, g, free)
        free = gnn(restrict(every, ~confirmed, free), free, scene.pd, scene.lam, hyp)
        if len(free):
            hyp.unassociated = free.tolist()
        return hyp

    def scene(self, store: TrackStore, part: Detections) -> Scene:
        """The part's detections converted and every unlabelled track of its layout not
        newer than them gated, with the sensor's Pd and clutter density."""
        batch = part.batch
        assert batch is not None
        t, n = float(batch.t[0]), len(batch.t)
        arrays = store.layout(batch.dim)
        rows = arrays.rows()
        rows = rows[arrays.plot[rows] & (arrays.t[rows] <= t + TIME_TOL)]
        z, r = convert(batch)
        gamma = gate_threshold(self.gate_probability, batch.dim)

        def gate_rows(some: np.ndarray) -> Gating:
            g = gate(arrays, some, z, r, t, self.q, gamma, self.predict)
            scores(g, scene.pd, scene.lam)
            return g

        def density(g: Gating) -> float:
            ungated = n - np.count_nonzero(np.bincount(g.dj, minlength=n))
            return self.sensors.density(part.sensor, z, ungated)

        every = gate(arrays, rows, z, r, t, self.q, gamma, self.predict)
        pd = self.sensors.model(part.sensor).pd
        scene = Scene(arrays, rows, z, r, t, pd, density(every), every, Hypotheses(batch.dim),
                      gate_rows, density)
        scores(every, pd, scene.lam)  # once for every stage
        return scene

    def _pairs(self, scene: Scene) -> np.ndarray | None:
        """The pairs the established tracks may take: those every stage allows."""
        out = None
        for stage in self.stages:
            mask = stage.pairs(scene)
            if mask is not None:
                out = mask if out is None else out & mask
        return out

    def resolve(self, g: Gating, index: np.ndarray, pd: float, lam: float,
                hyp: Hypotheses) -> np.ndarray:
        """Associate the gated pairs of `g` (its detections are scan[index]) into `hyp`;
        returns the indices of the detections left for tentative tracks."""
        raise NotImplementedError

    def settle(self, arrays: TrackArrays, rows: np.ndarray) -> np.ndarray:
        """Rows just updated by this associator's part: those a stage put back (mask)."""
        out = np.zeros(len(rows), dtype=bool)
        for stage in self.stages:
            out |= stage.settle(arrays, rows)
        return out

    def counts(self) -> dict[str, int]:
        """What the stages did since start (`status`)."""
        out: dict[str, int] = {}
        for stage in self.stages:
            out.update(stage.counts())
        return out

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
