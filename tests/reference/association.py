"""The textbook form of `plot_association.assign`: one cluster at a time, with
dictionaries."""

from __future__ import annotations

import numpy as np

from zenoh_track.tracking.gating import Gating, split
from zenoh_track.tracking.plot_association import UNLIKELY


def assign_reference(g: Gating, multi: np.ndarray, score: np.ndarray, miss: float
                     ) -> list[np.ndarray]:
    """`assign`, one cluster at a time with dictionaries (the textbook form)."""
    from scipy.optimize import linear_sum_assignment

    out = []
    for k in split(g, multi):
        tracks, ti = np.unique(g.ti[k], return_inverse=True)
        dets, dj = np.unique(g.dj[k], return_inverse=True)
        nt, nd = len(tracks), len(dets)
        cost = np.full((nt, nd + nt), UNLIKELY)
        cost[ti, dj] = -score[k]
        cost[np.arange(nt), nd + np.arange(nt)] = -miss
        r, c = linear_sum_assignment(cost)
        lookup = {(a, b): pair for a, b, pair in zip(ti, dj, k, strict=True)}
        out.append(np.array([lookup[a, b] for a, b in zip(r, c, strict=True)
                             if (a, b) in lookup], dtype=int))
    return out
