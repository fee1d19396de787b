"""zenoh_track.clients.evaluation.gospa: GOSPA (alpha = 2) on hand-worked cases, against brute
force and
against Stone Soup's `GOSPAMetric` on random sets; the track-level counts of `evaluate`."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from zenoh_track.clients.evaluation.gospa import evaluate, gospa

E = np.zeros((0, 2))


# ---------------------------------------------------------------- hand-worked cases
def test_empty_sets():
    g = gospa(E, E, c=10.0)
    assert (g.total, g.localisation, g.missed, g.false) == (0.0, 0.0, 0.0, 0.0)
    assert g.assignment.shape == (0,)


def test_only_missed_and_only_false():
    truths = np.array([[0.0, 0.0], [50.0, 0.0], [0.0, 70.0]])
    g = gospa(E, truths, c=10.0)  # each truth costs c^p / 2 = 50
    assert g.total == pytest.approx(math.sqrt(150.0))
    assert (g.localisation, g.missed, g.false, g.n_missed, g.n_false) == (0.0, 150.0, 0.0, 3, 0)
    assert g.assignment.tolist() == [-1, -1, -1]
    g = gospa(truths[:2], E, c=10.0)
    assert g.total == pytest.approx(10.0)
    assert (g.localisation, g.missed, g.false, g.n_missed, g.n_false) == (0.0, 0.0, 100.0, 0, 2)


def test_one_pair_inside_outside_and_at_the_cutoff():
    g = gospa(np.array([[3.0, 4.0]]), np.array([[0.0, 0.0]]), c=10.0)  # d = 5 < c
    assert (g.total, g.localisation, g.missed, g.false) == pytest.approx((5.0, 25.0, 0.0, 0.0))
    assert g.assignment.tolist() == [0]
    for d in (15.0, 10.0):  # beyond, and at, the cut-off: one missed and one false
        g = gospa(np.array([[d, 0.0]]), np.array([[0.0, 0.0]]), c=10.0)
        assert (g.total, g.localisation, g.missed, g.false) == pytest.approx(
            (10.0, 0.0, 50.0, 50.0))
        assert g.assignment.tolist() == [-1] and (g.n_missed, g.n_false) == (1, 1)


def test_optimal_not_greedy_and_p_1():
    """Truths at 0 and 10, estimates at 6 and 16 on a line: the nearest pair (10, 6) first
    would cost 16 + 100 (16 beyond c = 12); the optimum pairs (0, 6) and (10, 16)."""
    est, tru = np.array([[6.0, 0.0], [16.0, 0.0]]), np.array([[0.0, 0.0], [10.0, 0.0]])
    g = gospa(est, tru, c=12.0)
    assert g.total == pytest.approx(math.sqrt(72.0)) and g.assignment.tolist() == [0, 1]
    g = gospa(est, tru, c=12.0, p=1.0)  # p = 1: 6 + 6 = 12 against 4 + c / 2 + c / 2 = 16
    assert g.total == pytest.approx(12.0) and g.localisation == pytest.approx(12.0)


def test_permutation_invariance_and_brute_force():
    rng = np.random.default_rng(4)
    for _ in range(30):
        est = rng.uniform(0, 100, (rng.integers(0, 6), 2))
        tru = rng.uniform(0, 100, (rng.integers(0, 6), 2))
        c = float(rng.uniform(10, 60))
        g = gospa(est, tru, c)
        perm_e, perm_t = rng.permutation(len(est)), rng.permutation(len(tru))
        h = gospa(est[perm_e], tru[perm_t], c)
        assert h.total == pytest.approx(g.total, rel=1e-12)
        assert (h.n_missed, h.n_false) == (g.n_missed, g.n_false)
        # brute force: every partial matching of pairs closer than c
        best = (len(est) + len(tru)) * c**2 / 2
        n = min(len(est), len(tru))
        for k in range(1, n + 1):
            for ts in itertools.combinations(range(len(tru)), k):
                for es in itertools.permutations(range(len(est)), k):
                    d = np.linalg.norm(tru[list(ts)] - est[list(es)], axis=1)
                    if (d < c).all():
                        best = min(best, (d**2).sum() + (len(est) + len(tru) - 2 * k)
                                   * c**2 / 2)
        assert g.total == pytest.approx(math.sqrt(best), rel=1e-9)
        assert g.localisation + g.missed + g.false == pytest.approx(g.total**2, rel=1e-9)


def test_large_sets_equal_the_full_assignment():
    """1,000 x 1,000: leaving out the points with no partner within c changes nothing."""
    from scipy.optimize import linear_sum_assignment

    rng = np.random.default_rng(5)
    tru = rng.uniform(0, 20_000, (1000, 2))
    est = np.vstack([tru[:900] + rng.normal(0, 30, (900, 2)), rng.uniform(0, 20_000, (100, 2))])
    c = 100.0
    g = gospa(est, tru, c)
    d = np.linalg.norm(tru[:, None] - est[None], axis=2)
    r, k = linear_sum_assignment(np.minimum(d, c) ** 2)
    inside = d[r, k] < c
    full = (d[r, k][inside] ** 2).sum() + c**2 / 2 * (2000 - 2 * inside.sum())
    assert g.total == pytest.approx(math.sqrt(full), rel=1e-9)
    assert g.n_missed == g.n_false == 1000 - inside.sum()


# ---------------------------------------------------------------- against Stone Soup
def test_equals_stone_soup_gospa_metric():
    import datetime

    from stonesoup.metricgenerator.ospametric import GOSPAMetric
    from stonesoup.types.state import State

    now = datetime.datetime(2024, 1, 1)
    rng = np.random.default_rng(6)
    for trial in range(40):
        c = float(rng.choice([5.0, 20.0, 100.0]))
        p = float(rng.choice([1.0, 2.0]))
        tru = rng.uniform(0, 100, (rng.integers(0, 12), 2))
        kept = tru[: rng.integers(0, len(tru) + 1)]
        est = np.vstack([kept + rng.normal(0, 8, kept.shape),
                         rng.uniform(0, 100, (rng.integers(0, 6), 2))])
        metric = GOSPAMetric(c=c, p=p)
        ss, _ = metric.compute_gospa_metric([State(v[:, None], now) for v in est],
                                            [State(v[:, None], now) for v in tru])
        g = gospa(est, tru, c, p)
        for ours, key in ((g.total, "distance"), (g.localisation, "localisation"),
                          (g.missed, "missed"), (g.false, "false")):
            assert ours == pytest.approx(float(ss.value[key]), rel=1e-9, abs=1e-9), \
                (trial, key)


# ---------------------------------------------------------------- track level
def test_evaluate_counts_switches_breaks_false_tracks_and_confirmation():
    a, b = np.array([0.0, 0.0]), np.array([1000.0, 0.0])
    far = np.array([-5000.0, 0.0])
    scans = [
        (0.0, {"1": a + 1, "9": far}, {"A": a}),              # A held by 1
        (1.0, {"9": far}, {"A": a, "B": b}),                  # A lost: a break
        (2.0, {"2": a, "3": b + 2, "9": far}, {"A": a, "B": b}),  # A by 2: a switch
        (3.0, {"2": a, "3": b}, {"A": a, "B": b}),            # steady
        (4.0, {"3": a, "2": b}, {"A": a, "B": b}),            # 2 and 3 swap: two switches
    ]
    ev = evaluate(scans, c=10.0)
    assert ev.breaks == 1 and ev.switches == 3
    assert ev.false_tracks == {"9": 2.0}
    assert ev.confirm_time == {"A": 0.0, "B": 1.0}
    assert ev.assigned["A"] == ["1", None, "2", "2", "3"]
    assert ev.scans[1].n_missed == 2 and ev.scans[1].n_false == 1
    assert ev.mean()["n_false"] == pytest.approx(3 / 5)  # track 9 in three scans
    never = evaluate([(0.0, {}, {"A": a})])
    assert never.confirm_time == {"A": None} and never.breaks == 0
