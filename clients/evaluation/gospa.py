"""GOSPA: the generalized optimal sub-pattern assignment metric, and track-level counts.

García-Fernández, Rahmathullah & Svensson, "Generalized optimal sub-pattern assignment
metric", FUSION 2017 (arXiv:1601.05585). For estimates X and truths Y at one time, with
cut-off c, exponent p and alpha = 2,

    d(X, Y) = ( min over assignments g of  sum_{(i, j) in g} d(x_i, y_j)^p
                + c^p / 2 (|X| + |Y| - 2 |g|) )^(1/p),

the assignments holding only pairs closer than c. It splits into localisation (the sum
of d^p over the assigned pairs), missed (c^p / 2 per unassigned truth) and false
(c^p / 2 per unassigned estimate), reported as Stone Soup's `GOSPAMetric` reports them
(the parts in units of m^p; `total` = (localisation + missed + false)^(1/p)), so the
numbers are comparable. The minimum is found exactly by one rectangular assignment on
min(d, c)^p (SciPy's `linear_sum_assignment`): a pair at c costs as much as leaving
both unassigned. Points that have no partner within c are left out of the assignment
first (they are missed or false whatever the assignment), which keeps the problem
small where the sets are spread out.

`evaluate` runs GOSPA over the scans of a run and counts, from its assignments, the
track-level events of the evaluation literature (Blackman & Popoli, "Design and Analysis
of Modern Tracking Systems", 1999, sec. 13.6; Ristic, Vo, Clark & Vo, "A metric for
performance evaluation of multi-target tracking algorithms", IEEE TSP 2011): identity
switches, track breaks, false tracks and their lifetimes, and the time to confirm each
truth.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

ALPHA = 2.0  # the decomposition into localisation, missed and false holds for alpha = 2


@dataclass(frozen=True)
class Gospa:
    """GOSPA of one time: the total and its parts (parts in m^p, as Stone Soup's), the
    counts of missed truths and false estimates, and the assignment of each truth (the
    index of its estimate, -1 when missed)."""

    total: float
    localisation: float
    missed: float
    false: float
    n_missed: int
    n_false: int
    assignment: np.ndarray  # (len(truths),) int


def gospa(estimates: np.ndarray, truths: np.ndarray, c: float = 100.0,
          p: float = 2.0) -> Gospa:
    """GOSPA (alpha = 2) between estimates (N, d) and truths (M, d) of one time."""
    if c <= 0 or p < 1:
        raise ValueError(f"GOSPA needs c > 0 and p >= 1, got c={c}, p={p}")
    x, y = _points(estimates), _points(truths)
    n, m = len(x), len(y)
    assignment = np.full(m, -1, dtype=int)
    pairs_cost = 0.0
    if n and m:
        if x.shape[1] != y.shape[1]:
            raise ValueError(f"estimates of dimension {x.shape[1]}, truths of {y.shape[1]}")
        d = np.sqrt(((y[:, None, :] - x[None, :, :]) ** 2).sum(-1))  # (M, N)
        near = d < c
        rows, cols = np.flatnonzero(near.any(1)), np.flatnonzero(near.any(0))
        if len(rows):
            cost = np.minimum(d[np.ix_(rows, cols)], c) ** p
            r, k = linear_sum_assignment(cost)
            keep = near[rows[r], cols[k]]
            assignment[rows[r[keep]]] = cols[k[keep]]
            pairs_cost = float(cost[r[keep], k[keep]].sum())
    matched = int((assignment >= 0).sum())
    dummy = c**p / ALPHA
    loc, missed, false = pairs_cost, dummy * (m - matched), dummy * (n - matched)
    return Gospa(float((loc + missed + false) ** (1 / p)), loc, missed, false,
                 m - matched, n - matched, assignment)


def _points(a: np.ndarray) -> np.ndarray:
    """(N, d) float points; an empty input of any shape gives N = 0."""
    a = np.asarray(a, dtype=float)
    return a.reshape(len(a), -1) if a.size else np.zeros((len(a), a.shape[-1] if a.ndim > 1
                                                         else 0))


# ---------------------------------------------------------------- track level
@dataclass
class Evaluation:
    """GOSPA of every scan and the track-level counts of a run.

    - switches: a truth assigned to a track other than the one it was last assigned to
      (also across a gap);
    - breaks: a truth unassigned after having been assigned at the scan before;
    - false_tracks: the tracks never assigned to any truth -> their lifetime (s, last
      minus first time present);
    - confirm_time: truth -> time from its first scan to its first assignment (None if
      never assigned);
    - assigned: truth -> the track id assigned at each of its scans (None: missed).
    """

    times: list[float] = field(default_factory=list)
    scans: list[Gospa] = field(default_factory=list)
    switches: int = 0
    breaks: int = 0
    false_tracks: dict[Hashable, float] = field(default_factory=dict)
    confirm_time: dict[Hashable, float | None] = field(default_factory=dict)
    assigned: dict[Hashable, list[Hashable | None]] = field(default_factory=dict)

    def mean(self) -> dict[str, float]:
        """GOSPA and its parts averaged over the scans (NaN for no scan)."""
        keys = ("total", "localisation", "missed", "false", "n_missed", "n_false")
        if not self.scans:
            return dict.fromkeys(keys, float("nan"))
        return {k: float(np.mean([getattr(g, k) for g in self.scans])) for k in keys}


def evaluate(scans: Iterable[tuple[float, Mapping[Hashable, np.ndarray],
                                   Mapping[Hashable, np.ndarray]]],
             c: float = 100.0, p: float = 2.0) -> Evaluation:
    """Evaluate a run: `scans` yields (t, estimates: track id -> position, truths:
    truth id -> position) in time order. Each scan's GOSPA assignment (pairs within c)
    says which track, if any, holds each truth."""
    ev = Evaluation()
    last: dict[Hashable, Hashable] = {}  # truth -> the track it was last assigned to
    prev: dict[Hashable, Hashable | None] = {}  # truth -> its track at the previous scan
    first_truth: dict[Hashable, float] = {}
    span: dict[Hashable, list[float]] = {}  # track -> [first, last] time present
    real: set[Hashable] = set()  # tracks assigned to a truth at least once
    for t, est, tru in scans:
        tids, yids = list(est), list(tru)
        g = gospa(np.array([est[k] for k in tids], dtype=float),
                  np.array([tru[k] for k in yids], dtype=float), c, p)
        ev.times.append(float(t))
        ev.scans.append(g)
        for k in tids:
            span.setdefault(k, [t, t])[1] = t
        for j, truth in enumerate(yids):
            first_truth.setdefault(truth, float(t))
            ev.confirm_time.setdefault(truth, None)
            track = tids[g.assignment[j]] if g.assignment[j] >= 0 else None
            ev.assigned.setdefault(truth, []).append(track)
            if track is None:
                if prev.get(truth) is not None:
                    ev.breaks += 1
            else:
                real.add(track)
                if truth in last and last[truth] != track:
                    ev.switches += 1
                last[truth] = track
                if ev.confirm_time[truth] is None:
                    ev.confirm_time[truth] = float(t) - first_truth[truth]
            prev[truth] = track
        for truth in set(prev) - set(yids):  # a truth gone from the scene
            prev[truth] = None
    ev.false_tracks = {k: s[1] - s[0] for k, s in span.items() if k not in real}
    return ev
