"""Unlabelled scans through the tracker (no Zenoh): gating against a dense reference,
clusters, GNN and JPDA against brute force and the textbook PDA update, M-of-N track
life and track ids."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from reference.association import assign_reference
from reference.record import Outcome, scan_step

import zenoh_track.tracking.tracker as tracker_module
from zenoh_track.estimation import models
from zenoh_track.estimation.catalog import FilterSpec
from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.tracking import gating
from zenoh_track.tracking import plot_association as association
from zenoh_track.tracking.batches import Detections
from zenoh_track.tracking.hypotheses import Hypotheses
from zenoh_track.tracking.jpda import JPDAAssociator
from zenoh_track.tracking.plot_association import GNNAssociator, ScanAssociator, SensorModels
from zenoh_track.tracking.stages import Pass
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import Measurement

SIGMA = 25.0


def det(t: float, pos, sensor: str = "r1", sigma: float = SIGMA) -> Measurement:
    pos = tuple(float(v) for v in pos)
    return Measurement(sensor, "", float(t), len(pos), False, pos, (sigma,) * len(pos),
                       (0.0, 0.0, 0.0), None)


def scan(tracker: Tracker, t: float, positions, sensor: str = "r1") -> list[Outcome]:
    outcomes = [Outcome(det(t, p, sensor)) for p in positions]
    scan_step(tracker, outcomes, t)
    return outcomes


def make(associator: str = "gnn", **kw) -> Tracker:
    sensors = SensorModels(pd=kw.pop("pd", 0.9), clutter_density=kw.pop("density", 1e-8))
    return Tracker.from_config(TrackerConfig(filter=FilterSpec("cv", 1.0), associator=associator,
                                 sensors=sensors,
                                 **kw))


def ids_at(tracker: Tracker, status: str | None = None, t: float = 0.0) -> list[str]:
    snap = tracker.snapshot(t)
    return [i for i, s in zip(snap.ids, snap.status, strict=True) if status in (None, s)]


# ---------------------------------------------------------------- gating
def test_gate_equals_the_dense_reference():
    """The KD-tree prefilter finds exactly the pairs of the full tracks x detections
    Mahalanobis matrix."""
    rng = np.random.default_rng(1)
    tracker = make()
    truth = rng.uniform(0, 20_000, (300, 2))
    for k in range(2):  # two scans: tracks with velocity and a spread of covariances
        scan(tracker, float(k), truth + [10.0 * k, 0.0] + rng.normal(0, SIGMA, truth.shape))
    arrays = tracker.store.layout(2)
    rows = arrays.rows()
    dets = np.vstack([truth + [25.0, 0] + rng.normal(0, 60, truth.shape),
                      rng.uniform(0, 20_000, (300, 2))])
    batch = MeasurementBatch.of([det(2.0, p) for p in dets], 2)
    gamma = gating.gate_threshold(0.999, 2)
    g = gating.gate(arrays, rows, *gating.convert(batch), 2.0, 1.0, gamma)
    xp, pp = models.predict(arrays.x[rows], arrays.p[rows], 2.0 - arrays.t[rows], 2, 2, 1.0)
    nu = dets[None, :, :] - xp[:, None, :2]  # (T, D, 2): the dense reference
    s = pp[:, None, :2, :2] + SIGMA**2 * np.eye(2)
    d2 = np.einsum("tdi,tdi->td", nu, np.linalg.solve(s, nu[..., None])[..., 0])
    ref = set(zip(*np.nonzero(d2 <= gamma), strict=True))
    got = set(zip(g.ti.tolist(), g.dj.tolist(), strict=True))
    assert got == {(int(a), int(b)) for a, b in ref}
    assert len(ref) > 250  # the gates hold most true detections: the test is not empty
    np.testing.assert_allclose(g.d2, d2[g.ti, g.dj], rtol=1e-9)


def test_clusters_are_connected_components():
    # tracks 0-1 share detection 1; track 2 alone with 3; track 3 with 4 and 5
    ti = np.array([0, 0, 1, 2, 3, 3])
    dj = np.array([0, 1, 1, 3, 4, 5])
    labels = gating.clusters(ti, dj, 4, 6)
    assert labels[0] == labels[1] == labels[2]
    assert len({labels[0], labels[3], labels[4]}) == 3 and labels[4] == labels[5]


# ---------------------------------------------------------------- GNN
def crossing(tracker: Tracker, scans: int, miss: set[tuple[int, int]] = frozenset(),
             clutter: int = 0, seed: int = 0) -> np.ndarray:
    """Two targets crossing at (0, 0) at scan scans // 2, 100 m/s, 25 m noise."""
    rng = np.random.default_rng(seed)
    half = scans // 2
    for k in range(scans):
        truth = np.array([[-100.0 * (half - k), 0.0], [0.0, -100.0 * (half - k)]])
        pts = [p + rng.normal(0, SIGMA, 2) for i, p in enumerate(truth) if (k, i) not in miss]
        pts += list(rng.uniform(-3000, 3000, (clutter, 2)))
        scan(tracker, float(k), pts)
    return truth


@pytest.mark.parametrize("associator", ["gnn", "jpda"])
def test_two_crossing_targets_keep_their_tracks(associator):
    tracker = make(associator)
    truth = crossing(tracker, 20)
    confirmed = ids_at(tracker, "confirmed", 19.0)
    assert sorted(confirmed) == ["r1-1", "r1-2"]  # no break, no extra track
    for tid, target in (("r1-1", 0), ("r1-2", 1)):  # no identity switch at the crossing
        np.testing.assert_allclose(tracker.state(tid)["pos"][:2], truth[target], atol=60)


def test_gnn_single_pairs_and_clusters_match_brute_force():
    """On random scenes, GNN's assignment has the best total score among all joint
    assignments of each cluster (brute force over the small clusters)."""
    rng = np.random.default_rng(3)
    for trial in range(20):
        tracker = make()
        pts = rng.uniform(0, 1000, (6, 2))
        scan(tracker, 0.0, pts)
        scan(tracker, 1.0, pts + rng.normal(0, SIGMA, pts.shape))
        store = tracker.store
        meas = [det(2.0, p) for p in pts + rng.normal(0, 40, pts.shape)] + \
            [det(2.0, p) for p in rng.uniform(0, 1000, (3, 2))]
        assoc = tracker.scan_associator
        hyp = assoc.associate(store, Detections("r1", 2.0, MeasurementBatch.of(meas, 2)))
        arrays = store.layout(2)  # all tentative: the nearest-neighbour stage
        z, r = gating.convert(MeasurementBatch.of(meas, 2))
        g = gating.gate(arrays, arrays.rows(), z, r, 2.0, 1.0, gating.gate_threshold(0.999, 2))
        pd, lam = 0.9, 1e-8
        score = {(int(a), int(b)): v for a, b, v in
                 zip(g.ti, g.dj, np.log(pd) + g.loglik - np.log(lam), strict=True)}
        miss = np.log1p(-pd)
        row_of = {r: i for i, r in enumerate(g.rows.tolist())}  # store row -> track index
        index, rows = hyp.pairs()
        chosen = {(row_of[k], j) for j, k in zip(index.tolist(), rows.tolist(), strict=True)}

        n_rows = len(g.rows)

        def total(pairs, score=score, miss=miss, n=n_rows):
            return sum(score[p] for p in pairs) + miss * (n - len({t for t, _ in pairs}))

        best = max((sum(([(t, d)] for t, d in zip(range(len(g.rows)), perm, strict=True)
                         if d is not None and (t, d) in score), []) for perm in
                    itertools.product(*[[None, *[d for (t2, d) in score if t2 == t]]
                                        for t in range(len(g.rows))])
                    if len([d for d in perm if d is not None]) ==
                    len({d for d in perm if d is not None})), key=total)
        assert total(sorted(chosen)) == pytest.approx(total(best), abs=1e-9), trial


@pytest.mark.parametrize("tracks,dets", [(20, 30), (400, 300)])
def test_near_pairs_equal_the_distance_matrix(tracks, dets):
    """Both prefilters of the gate (the dense matrix for small scans, the KD-tree beyond
    DENSE_PAIRS) find exactly the pairs within each track's radius."""
    rng = np.random.default_rng(tracks)
    mean, z = rng.uniform(0, 3_000, (tracks, 2)), rng.uniform(0, 3_000, (dets, 2))
    radius = rng.uniform(50, 800, tracks)
    ti, dj = gating.near(mean, z, radius)
    dist = np.linalg.norm(mean[:, None] - z[None], axis=2)
    want = set(zip(*np.nonzero(dist <= radius[:, None]), strict=True))
    assert set(zip(ti.tolist(), dj.tolist(), strict=True)) == want
    assert len(want) > tracks
    assert len(ti) == len(want)  # no pair twice
    assert (tracks * dets > gating.DENSE_PAIRS) == (tracks == 400)  # both paths run


def test_packed_assignment_equals_one_cluster_at_a_time():
    """GNN's block-diagonal packing of small clusters (`assign`) chooses the same pairs
    as solving each cluster alone (`reference.association`), with clusters of every size."""
    rng = np.random.default_rng(7)
    tracker = make(confirm_m=1, confirm_score=-100.0)
    pairs = rng.uniform(0, 50_000, (30, 2))
    truth = np.vstack([pairs, pairs + [60.0, 0.0],  # two close targets: small clusters
                       rng.uniform(0, 1_500, (60, 2))])  # crowded: a large one
    scan(tracker, 0.0, truth)
    scan(tracker, 1.0, truth + rng.normal(0, SIGMA, truth.shape))
    arrays = tracker.store.layout(2)
    dets = np.vstack([truth + rng.normal(0, 40, truth.shape), rng.uniform(0, 50_000, (50, 2))])
    z, r = gating.convert(MeasurementBatch.of([det(2.0, p) for p in dets], 2))
    g = gating.gate(arrays, arrays.rows(), z, r, 2.0, 1.0, gating.gate_threshold(0.999, 2))
    score, miss = association.scores(g, 0.9, 1e-8)
    single, multi = gating.singles(g)
    label = gating.clusters_reference(g.ti, g.dj, len(g.rows), len(g.z))
    np.testing.assert_array_equal(single, np.flatnonzero(np.bincount(label)[label] == 1))
    groups = gating.split(g, multi)
    assert sorted(len(k) for k in groups) == sorted(np.bincount(label[multi])[
        np.unique(label[multi])].tolist())
    sizes = [len(np.unique(g.ti[k])) for k in groups]
    assert min(sizes) == 2 and max(sizes) > association.PACK  # both kinds of pack
    every = [np.concatenate(groups[:n]) for n in (len(groups), 8)]  # and under PACK
    assert len(np.unique(g.ti[every[1]])) <= association.PACK
    for part in every:
        got = np.sort(np.concatenate(association.assign(g, part, score, miss)))
        ref = np.sort(np.concatenate(assign_reference(g, part, score, miss)))
        np.testing.assert_array_equal(got, ref)
        assert len(got) > 8


# ---------------------------------------------------------------- JPDA
def test_jpda_exact_marginals_by_hand():
    """Two tracks, two detections, all four pairs gated: the marginals of the seven joint
    events, written out."""
    jp = JPDAAssociator(1.0)
    g = np.array([2.0, 0.5, 1.0, 3.0])  # G of (t0,d0), (t0,d1), (t1,d0), (t1,d1)
    b = 0.1
    events = {  # (track 0's detection, track 1's): weight
        (None, None): b * b, (0, None): 2.0 * b, (1, None): 0.5 * b, (None, 0): b * 1.0,
        (None, 1): b * 3.0, (0, 1): 2.0 * 3.0, (1, 0): 0.5 * 1.0}
    total = sum(events.values())
    expect = [sum(w for e, w in events.items() if e[0] == 0) / total,
              sum(w for e, w in events.items() if e[0] == 1) / total,
              sum(w for e, w in events.items() if e[1] == 0) / total,
              sum(w for e, w in events.items() if e[1] == 1) / total]
    got = jp._marginals(np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1]), g, b)
    np.testing.assert_allclose(got, expect, rtol=1e-12)
    cheap_jp = JPDAAssociator(1.0, max_events=4)  # 3 x 3 events > 4: the cheap
    cheap = cheap_jp._marginals(np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1]), g, b)
    assert (cheap > 0).all() and np.bincount([0, 0, 1, 1], cheap).max() < 1  # probabilities
    assert not np.allclose(cheap, expect, rtol=1e-3)  # a different computation


def test_pda_update_equals_the_textbook_pdaf():
    """One CV track, three gated detections: the equivalent-measurement update plus the
    spread equals x = x^ + K sum beta_j nu_j, P = beta0 P^ + (1 - beta0) Pc + P~."""
    tracker = make("jpda", density=1e-6, confirm_m=1, confirm_score=-100.0)  # established
    scan(tracker, 0.0, [(0.0, 0.0)])
    scan(tracker, 1.0, [(100.0, 0.0)])
    arrays, row = tracker.store.where["r1-1"]
    x0, p0 = arrays.x[row].copy(), arrays.p[row].copy()
    dets = np.array([[200.0, 10.0], [230.0, -20.0], [180.0, 30.0]])
    meas = [det(2.0, p) for p in dets]
    arrays = tracker.store.layout(2)
    z, r = gating.convert(MeasurementBatch.of(meas, 2))
    g = gating.gate(arrays, arrays.rows(), z, r, 2.0, 1.0, gating.gate_threshold(0.999, 2))
    pd, lam = 0.9, 1e-6
    assert len(g.ti) == 3
    ratio = np.exp(np.log(pd) + g.loglik - np.log(lam))
    beta = ratio / (ratio.sum() + 1 - pd)  # one track: the joint events are single pairs
    scan(tracker, 2.0, dets)
    xp, pp = models.predict(x0[None], p0[None], np.array([1.0]), 2, 2, 1.0)
    h = np.hstack([np.eye(2), np.zeros((2, 2))])
    s = h @ pp[0] @ h.T + SIGMA**2 * np.eye(2)
    k = pp[0] @ h.T @ np.linalg.inv(s)
    nus = dets[g.dj] - xp[0, :2]
    nu = (beta[:, None] * nus).sum(0)
    x_ref = xp[0] + k @ nu
    pc = pp[0] - k @ s @ k.T
    spread = k @ ((beta[:, None, None] * nus[:, :, None] * nus[:, None, :]).sum(0)
                  - np.outer(nu, nu)) @ k.T
    p_ref = (1 - beta.sum()) * pp[0] + beta.sum() * pc + spread
    np.testing.assert_allclose(arrays.x[row], x_ref, rtol=1e-9)
    np.testing.assert_allclose(arrays.p[row], p_ref, rtol=1e-6)


# ---------------------------------------------------------------- track life
def test_m_of_n_confirmation_and_deletion():
    tracker = make(confirm_m=3, confirm_n=4, delete_misses=3)
    p = np.array([0.0, 0.0])
    v = np.array([50.0, 0.0])
    hit = [True, False, True, True, True, False, False, False]
    status = []
    for k, h in enumerate(hit):
        scan(tracker, float(k), [p + v * k] if h else [])
        snap = tracker.snapshot(float(k))
        status.append(snap.status[0] if snap.ids else None)
    # 1 of 1, 1 of 2, 2 of 3, 3 of 4 (confirmed), then three misses delete it
    assert status == ["tentative", "tentative", "tentative", "confirmed", "confirmed",
                      "coasting", "coasting", None]


@pytest.mark.parametrize("pd, misses", [(0.9, 6), (0.7, 12), (0.5, 20)])
def test_a_sensor_that_misses_more_keeps_its_tracks_longer(pd, misses):
    """A confirmed track is deleted after the misses in a row that are as unlikely for a
    target still there as 6 at Pd 0.9 (the default --delete-misses): 12 at Pd 0.7, 20
    at 0.5 (docs/protocol.md §3.2)."""
    tracker = make(pd=pd)
    p, v = np.array([0.0, 0.0]), np.array([50.0, 0.0])
    for k in range(5):
        scan(tracker, float(k), [p + v * k])
    (track,) = tracker.store.where
    gone = None
    for k in range(5, 40):
        scan(tracker, float(k), [])
        if track not in tracker.store.where:
            gone = k - 4
            break
    assert gone == misses


@pytest.mark.parametrize("pd, after", [(0.7, 3), (0.9, 2)])
def test_a_detection_takes_back_part_of_the_misses_not_all(pd, after):
    """A track missed all but once in 12 scans is no target at Pd 0.7 (it gives 8): a
    detection after misses takes back ln(Pd / 0.1) of their evidence (a CUSUM), not all
    of it. At Pd 0.7, 11 misses, one detection, then deleted at the 3rd miss (13.2 - 1.9
    + 3 x 1.2 >= 6 ln 10); at 0.9, 5 misses, one detection, deleted at the 2nd (11.5 -
    2.2 + 2 x 2.3); with a restart at each detection it took 12 and 6 more."""
    tracker = make(pd=pd)
    p, v = np.array([0.0, 0.0]), np.array([50.0, 0.0])
    for k in range(5):
        scan(tracker, float(k), [p + v * k])
    (track,) = tracker.store.where
    first = 11 if pd == 0.7 else 5
    for k in range(5, 5 + first):
        scan(tracker, float(k), [])
    k = 5 + first
    scan(tracker, float(k), [p + v * k])  # the one detection
    gone = None
    for j in range(1, 20):
        scan(tracker, float(k + j), [])
        if track not in tracker.store.where:
            gone = j
            break
    assert gone == after


def test_tentative_track_from_clutter_is_dropped_and_ids_are_not_reused():
    tracker = make(confirm_m=3, confirm_n=4)
    scan(tracker, 0.0, [(0.0, 0.0)])
    scan(tracker, 1.0, [])
    scan(tracker, 2.0, [])  # 2 misses in a row: 3 of 4 is out of reach
    assert len(tracker) == 0
    scan(tracker, 3.0, [(0.0, 0.0)])
    assert ids_at(tracker, t=3.0) == ["r1-2"]


def test_crossing_with_clutter_confirms_every_target():
    """Ten targets crossing near one point, Pd 0.9, 20 clutter detections per scan over
    10 km x 10 km: every target confirmed within 6 scans and no false confirmed track
    at the end."""
    rng = np.random.default_rng(7)
    tracker = make(pd=0.9, density=None)
    angles = np.linspace(0, np.pi, 10, endpoint=False)
    vel = 150.0 * np.stack([np.cos(angles), np.sin(angles)], 1)
    start = -vel * 15
    for k in range(30):
        truth = start + vel * k
        seen = rng.random(10) < 0.9
        pts = list(truth[seen] + rng.normal(0, SIGMA, (seen.sum(), 2)))
        pts += list(rng.uniform(-5000, 5000, (20, 2)))
        scan(tracker, float(k), pts)
        if k == 5:
            assert len(ids_at(tracker, "confirmed", 5.0)) + \
                len(ids_at(tracker, "coasting", 5.0)) >= 10
    snap = tracker.snapshot(29.0)
    est = np.array([snap.pos[i, :2] for i, s in enumerate(snap.status) if s != "tentative"])
    dist = np.linalg.norm(est[:, None] - truth[None], axis=2)
    assert (dist.min(0) < 100).all()  # every target has a track
    assert (dist.min(1) < 100).all()  # every established track is on a target


def test_sensor_models_from_file(tmp_path):
    path = tmp_path / "sensors.json"
    path.write_text('{"r1": {"pd": 0.7, "clutter_density": 1e-7}, "r2": {"pd": 0.95}}')
    models_ = SensorModels.from_file(path)
    assert models_.model("r1").pd == 0.7 and models_.model("r1").clutter_density == 1e-7
    assert models_.model("r2").clutter_density is None
    assert models_.model("r3").pd == association.defaults.PD


def test_gnn_associator_is_the_default():
    assert isinstance(make().scan_associator, GNNAssociator)


@pytest.mark.parametrize("associator", ["gnn", "jpda"])
@pytest.mark.parametrize("kind", ["ca", "imm", "vdf"])
def test_every_filter_tracks_unlabelled_targets(kind, associator):
    """The associators work with every filter as the updater."""
    tracker = Tracker.from_config(TrackerConfig(filter=FilterSpec(kind), associator=associator,
                                    sensors=SensorModels(pd=0.9, clutter_density=1e-7)))
    rng = np.random.default_rng(11)
    vel = np.array([[120.0, 0.0], [0.0, 150.0], [-90.0, 90.0]])
    start = np.array([[-2000.0, 100.0], [150.0, -2500.0], [2000.0, -1800.0]])
    for k in range(25):
        truth = start + vel * k
        seen = rng.random(3) < 0.9
        pts = list(truth[seen] + rng.normal(0, SIGMA, (int(seen.sum()), 2)))
        pts += list(rng.uniform(-4000, 4000, (10, 2)))
        scan(tracker, float(k), pts)
    snap = tracker.snapshot(24.0)
    est = np.array([snap.pos[i, :2] for i, s in enumerate(snap.status) if s != "tentative"])
    dist = np.linalg.norm(est[:, None] - truth[None], axis=2)
    assert (dist.min(0) < 150).all() and (dist.min(1) < 150).all(), dist.min(0)
    assert np.isfinite(snap.pos).all() and np.isfinite(snap.sigma).all()


@pytest.mark.slow
def test_ten_thousand_detections_in_one_scan():
    """10,000 detections per scan (the documented limit is 100,000 per message): two scans
    of 5,000 targets and 5,000 clutter are processed, every detection accounted for."""
    rng = np.random.default_rng(2)
    tracker = make(density=None)
    truth = rng.uniform(-200e3, 200e3, (5000, 2))
    for k in range(2):
        pts = np.vstack([truth + rng.normal(0, SIGMA, truth.shape),
                         rng.uniform(-200e3, 200e3, (5000, 2))])
        outcomes = scan(tracker, float(k), pts)
        assert all(o.reason is None for o in outcomes)
    assert 5000 <= len(tracker) <= 15000
    assert np.isfinite(tracker.snapshot(1.0).pos).all()


def test_cluster_propagation_equals_connected_components():
    rng = np.random.default_rng(4)
    for _ in range(50):
        t, d = rng.integers(1, 40, 2)
        k = rng.integers(0, 3 * max(t, d))
        ti, dj = rng.integers(0, t, k), rng.integers(0, d, k)
        a = gating.clusters(ti, dj, t, d)
        b = gating.clusters_reference(ti, dj, t, d)
        # the same partition of the pairs (labels may differ)
        assert len(set(zip(a.tolist(), b.tolist(), strict=True))) == len(set(a.tolist())) \
            == len(set(b.tolist()))


class EveryDetectionNew(ScanAssociator):
    """The trivial associator of docs/architecture.md's "Where to add": no detection
    updates a track, each starts one (the shared steps of `ScanAssociator` replaced by one
    method; its stages, settle and counts inherited)."""

    def associate(self, store, part) -> Hypotheses:
        return Hypotheses(part.batch.dim if part.batch is not None else 0,
                          unassociated=list(range(len(part))))


class Veto(Pass):
    """A stage of docs/architecture.md's "Where to add": the established tracks may take
    no detection (every pair refused), counted."""

    def __init__(self) -> None:
        self.vetoed = 0

    def pairs(self, scene):
        self.vetoed += len(scene.every.ti)
        return np.zeros(len(scene.every.ti), dtype=bool)

    def counts(self) -> dict[str, int]:
        return {"vetoed": self.vetoed}


def test_a_new_stage_is_one_class_in_the_associators_stages():
    """The stage recipe tried: added to the service's stages, it acts at its one hook and
    its count reaches `Tracker.counts` (status); left out, nothing changes."""
    def run(extra: list) -> Tracker:
        config = TrackerConfig(filter=FilterSpec("cv", 1.0), sensors=SensorModels(0.9, 1e-8))
        a = Tracker.from_config(config).scan_associator
        tracker = Tracker.from_config(config, scan_associator=GNNAssociator(
                                          a.q, a.sensors, a.gate_probability, predict=a.predict,
                                          stages=[*a.stages, *extra]))
        pts = np.array([[0.0, 0.0], [5000.0, 0.0]])
        for k in range(8):
            scan(tracker, float(k), pts + k)
        return tracker

    plain, veto = run([]), Veto()
    vetoed = run([veto])
    assert len(plain) == 2 and all(plain.state(k)["updates"] == 8 for k in plain.ids())
    assert veto.vetoed > 0 and vetoed.counts()["vetoed"] == veto.vetoed
    assert len(vetoed) > 2  # the confirmed tracks took nothing: new tracks began


def test_a_new_associator_is_one_class_and_one_registration(monkeypatch):
    """The recipe tried: registered in `SCAN_ASSOCIATORS`, chosen by name (as
    `--associator` would), it runs the tracker's one loop unchanged."""
    monkeypatch.setitem(tracker_module.SCAN_ASSOCIATORS, "every-new", EveryDetectionNew)
    tracker = make("every-new")
    assert isinstance(tracker.scan_associator, EveryDetectionNew)
    pts = np.array([[0.0, 0.0], [500.0, 0.0], [0.0, 900.0]])
    scan(tracker, 0.0, pts)
    out = scan(tracker, 1.0, pts + 1.0)
    assert all(o.reason is None for o in out)
    assert sorted(tracker.store.where) == [f"r1-{i}" for i in range(1, 7)]
    assert {tracker.state(k)["updates"] for k in tracker.store.where} == {1}
    assert "every-new" in parser_choices(monkeypatch)


def parser_choices(monkeypatch) -> tuple[str, ...]:
    """--associator's choices, read from the registry when the parser is built."""
    from zenoh_track.__main__ import parser

    action = next(a for a in parser()._actions if "--associator" in a.option_strings)
    return tuple(action.choices)
