"""Track life of unlabelled tracks: M-of-N confirmation and the misses that end tracks.

Each scan that could have seen a track counts it as detected or missed
(`hypotheses.Hypotheses.seen`) and adds its log-likelihood ratio to the
track's score (a detection ln(Pd N(nu; 0, S) / lambda), a miss ln(1 - Pd): the
sequential test of Blackman & Popoli 1999, sec. 6.2). A track keeps its last N outcomes
as bits; it is confirmed once M of them are detections and its score has reached the
confirmation threshold (and stays confirmed): M of N alone lets clutter that happens to
line up confirm; the score weighs how well it lined up. `MofNDeleter` ends
tentative tracks that missed N - M + 1 scans in a row (they cannot reach M of the last
N at the next scan), confirmed tracks after K consecutive misses (a detection between
them taking back part of their evidence, not all: a CUSUM), and any of them whose
position sigma exceeds a limit at a scan that missed it (Blackman & Popoli 1999, sec.
6.3; Stone Soup's UpdateTimeStepsDeleter and CovarianceBasedDeleter play the same roles).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .. import defaults
from .hypotheses import Seen
from .stitcher import Stitcher
from .store import Column, TrackArrays, TrackStore

# the life of a track of unlabelled scans, per row of the store, zero for a new track:
# whether it is one, its detections in the last scans as bits (newest lowest), the
# scans that could have seen it, its consecutive misses, its score, whether confirmed,
# and the evidence of its consecutive misses, sum -ln(1 - Pd) (not checkpointed: made
# again from the misses, `restore_lost`)
LIFE_COLUMNS = {"plot": Column(dtype=bool, fresh=True), "hits": Column(dtype=np.int64, fresh=True),
                "scans": Column(dtype=np.int64, fresh=True),
                "misses": Column(dtype=np.int64, fresh=True), "score": Column(fresh=True),
                "confirmed": Column(dtype=bool, fresh=True),
                "lost": Column(fresh=True, saved=False)}


def update_life(seen: Sequence[Seen], m: int, n: int, threshold: float
                ) -> list[tuple[TrackArrays, np.ndarray]]:
    """Record one scan's detections and misses of unlabelled tracks, and add the scan's
    log-likelihood ratio to each track's score; confirm those detected M of the last N
    scans whose score reached `threshold`. The rows confirmed by this scan, per layout."""
    out: list[tuple[TrackArrays, np.ndarray]] = []
    mask = (1 << n) - 1
    by_layout: dict[int, list[Seen]] = {}
    for s in seen:  # one pass per layout (a scan's stages see disjoint tracks)
        by_layout.setdefault(id(s.arrays), []).append(s)
    for group in by_layout.values():
        a = group[0].arrays
        if len(group) == 1:
            rows, hit, gain = group[0].rows, group[0].detected, group[0].gain
            weight: float | np.ndarray = -group[0].miss
        else:
            rows = np.concatenate([s.rows for s in group])
            hit = np.concatenate([s.detected for s in group])
            gain = np.concatenate([s.gain for s in group])
            weight = np.concatenate([np.full(len(s.rows), -s.miss) for s in group])
        hits = ((a.hits[rows] << 1) | hit) & mask
        a.hits[rows] = hits
        a.scans[rows] += 1
        a.misses[rows] = np.where(hit, 0, a.misses[rows] + 1)
        # a CUSUM of the detections (Page 1954): a miss adds -ln(1 - Pd), a detection
        # takes back ln(Pd / P0), P0 the chance a false track takes a detection at a scan
        # (none for a sensor stated to detect less often than that)
        back = np.maximum(np.log(-np.expm1(-np.asarray(weight)) / defaults.DELETE_FALSE_HIT),
                          0.0)
        a.lost[rows] = np.where(hit, np.maximum(a.lost[rows] - back, 0.0),
                                a.lost[rows] + weight)
        score = a.score[rows] + gain
        a.score[rows] = score
        was = a.confirmed[rows]
        now = was | ((np.bitwise_count(hits) >= m) & (score >= threshold))
        a.confirmed[rows] = now
        if (now & ~was).any():
            out.append((a, rows[now & ~was]))
    return out


class MofNLife:
    """Tracks of unlabelled scans confirmed M of N with a track score of at least
    `threshold` (`update_life`); a track confirmed where a lost one could have gone
    continues it (`stitcher`; None: never)."""

    def __init__(self, m: int = defaults.CONFIRM_M, n: int = defaults.CONFIRM_N,
                 threshold: float = defaults.CONFIRM_SCORE, stitcher: Stitcher | None = None
                 ) -> None:
        self.m, self.n, self.threshold, self.stitcher = m, n, threshold, stitcher

    def start(self, arrays: TrackArrays, rows: np.ndarray) -> None:
        """New tracks detected once: confirmed at birth only by a rule that asks no more."""
        arrays.plot[rows], arrays.hits[rows], arrays.scans[rows] = True, 1, 1
        arrays.confirmed[rows] = self.m <= 1 and self.threshold <= 0

    def count(self, store: TrackStore, seen: Sequence[Seen]) -> dict[str, tuple[str, int]]:
        """A scan's detections and misses counted; the tracks it confirmed that continue
        a lost one, {new id: (old id, its updates)}."""
        out: dict[str, tuple[str, int]] = {}
        for arrays, rows in update_life(seen, self.m, self.n, self.threshold):
            if self.stitcher is not None:
                out.update(self.stitcher.join(store, arrays, rows))
        return out

    def counts(self) -> dict[str, int]:
        """Lost tracks continued under their id since start (`status`)."""
        return {"continued": 0 if self.stitcher is None else self.stitcher.joined}


def restore_lost(arrays: TrackArrays, rows: np.ndarray) -> None:
    """The evidence of restored tracks' misses (their consecutive ones, as if at the
    reference Pd: the CUSUM itself is not saved)."""
    arrays.lost[rows] = arrays.misses[rows] * -np.log1p(-defaults.PD)


class MofNDeleter:
    """Deletes unlabelled tracks that cannot be confirmed any more, that missed scans once
    confirmed as unlikely for a target still there as `misses` misses in a row at the
    reference Pd (`defaults.PD`, 0.9; the sum of -ln(1 - Pd) over the misses, each at its
    sensor's Pd: 6 misses at 0.9 are 12 at 0.7 and 20 at 0.5: the track score's drop,
    Blackman & Popoli 1999, sec. 6.3; a detection takes back ln(Pd / P0) of it,
    `update_life`), or whose position sigma exceeds `sigma` at a scan that missed
    them."""

    def __init__(self, m: int, n: int, misses: int, sigma: float) -> None:
        self.m, self.n, self.misses, self.sigma = m, n, misses, sigma
        # the evidence of `misses` at the reference Pd, less a rounding's worth
        self.lost = misses * -np.log1p(-defaults.PD) * (1.0 - 1e-9)

    def delete_tracks(self, store: TrackStore, now: float) -> list[str]:
        out: list[str] = []
        for arrays in store.layouts.values():
            if not np.any(arrays.plot, where=arrays.alive):  # no track of unlabelled scans
                continue  # (every frame asks: one pass, no gather)
            rows, ids = arrays.live()
            plot = arrays.plot[rows]
            misses, confirmed = arrays.misses[rows], arrays.confirmed[rows]
            d, n = arrays.dim, arrays.n
            pr = arrays.p.reshape(len(arrays.p), n * n)[rows]
            var = np.add.reduce(pr[:, :d * (n + 1):n + 1], axis=1)  # the trace of the
            # position block (its diagonal, a strided view)
            gone = np.where(confirmed, arrays.lost[rows] >= self.lost,
                            misses > self.n - self.m)
            # too uncertain to hold anything: once it misses (an update by weighted
            # detections, JPDA's, may spread a track that was detected over kilometres)
            gone |= (var > self.sigma**2) & (misses > 0)
            out += [ids[i] for i in (plot & gone).nonzero()[0].tolist()]
        return out
