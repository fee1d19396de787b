"""A second look before a confirmed track is committed to a doubtful detection.

Global nearest neighbour decides each scan alone. When a confirmed track is not detected
and a false detection lies in its widest gate (an unseen manoeuvre's), taking it can beat
a miss by a hair (log-likelihood ratios -2.16 against -2.30 in the case traced in
docs/accuracy.md): the track jumps kilometres and the aircraft starts a new one. A
multiple-hypothesis tracker keeps both branches and lets the next scan choose (Reid,
IEEE TAC 24(6), 1979; the track-oriented form, Blackman, IEEE AES Magazine 19(1), 2004,
with an N-scan window). This is that window of one scan, for that one case:

- When a confirmed track takes a detection whose score beats its missed-detection score
  by less than `margin` (ln of a likelihood ratio), its row before the update is kept:
  the miss branch (`note`).
- At the next scan part of its layout (any sensor, later in time), the two branches are
  scored on that scan alone, each by its best gated detection (or a miss):
  taken (the margin plus its best) against missed (its best). If the miss branch wins,
  the row is put back as it was before the doubtful update, and the scan is associated
  as usual from there (`decide`). Either way the doubt ends.

The branches are compared track by track, before the joint assignment of the second
scan (which then resolves any detection two tracks want). The track's life counters
(M of N, score) keep the first scan's detection. Doubts are not checkpointed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..wire import TIME_TOL
from .gating import Gating
from .life import LIFE_COLUMNS
from .store import TrackArrays


@dataclass
class Doubt:
    """One confirmed track's miss branch: its row's columns before the doubtful update
    at time `t`, and by how much taking the detection beat missing it."""

    track_id: str
    t: float
    margin: float
    row: dict[str, np.ndarray]


class SecondLook:
    """The doubtful assignments of confirmed tracks, kept one scan (`note`, `decide`)."""

    def __init__(self, margin: float) -> None:
        self.margin = margin
        self.doubts: dict[tuple[int, int], Doubt] = {}  # (layout's dim, row) -> doubt
        self.reverted = 0  # tracks put back on their miss branch, since start

    def note(self, arrays: TrackArrays, rows: np.ndarray, margins: np.ndarray,
             t: float) -> None:
        """Tracks `rows` take a detection at `t` that beats missing by `margins`: keep the
        rows (before their update) of those below the margin."""
        if self.margin <= 0:
            return
        doubtful = margins < self.margin
        kept = _kept(arrays)
        for row, m in zip(rows[doubtful].tolist(), margins[doubtful].tolist(), strict=True):
            self.doubts[arrays.dim, row] = Doubt(
                arrays.ids[row], t, m, {name: getattr(arrays, name)[row].copy() for name in kept})

    def decide(self, arrays: TrackArrays, every: Gating, t: float, score: np.ndarray,
               miss: float, gate_rows: Callable[[np.ndarray], tuple[Gating, np.ndarray]]
               ) -> bool:
        """At a scan part of `arrays`' layout at `t` gated as `every` (pair scores `score`,
        a miss `miss`): put back each doubted track whose miss branch scores better on it;
        `gate_rows(rows)` gates rows of the store against the same detections (the
        gating and its pairs' scores). Whether any was put back (the scan must then be
        gated again)."""
        mine = [(key, d) for key, d in self.doubts.items() if key[0] == arrays.dim
                and arrays.ids[key[1]] == d.track_id and t > d.t + TIME_TOL]
        if not mine:
            return False
        for key, _ in mine:
            del self.doubts[key]
        # still as the doubtful update left them (no other update since, not rejected)
        live = [(key[1], d) for key, d in mine if abs(arrays.t[key[1]] - d.t) <= TIME_TOL]
        if not live:
            return False
        rows = np.array([row for row, _ in live], dtype=np.intp)
        taken = _best(every, score, miss, rows)
        now = {name: getattr(arrays, name)[rows].copy() for name in _kept(arrays)}
        _put(arrays, rows, [d.row for _, d in live])
        missed = _best(*gate_rows(rows), miss, np.arange(len(rows)), local=True)
        back = missed > taken + np.array([d.margin for _, d in live])
        for name, values in now.items():  # the taken branch where it stays
            getattr(arrays, name)[rows[~back]] = values[~back]
        self.reverted += int(back.sum())
        return bool(back.any())


def _best(g: Gating, score: np.ndarray, miss: float, rows: np.ndarray,
          local: bool = False) -> np.ndarray:
    """Each track's best score in `g` (its best gated detection, or a miss): of the
    store rows `rows` (or, `local`, of g's own track indices `rows`)."""
    best = np.full(len(g.rows), miss)
    if len(g.ti):
        np.maximum.at(best, g.ti, score)
    if local:
        return best[rows]
    where = {row: i for i, row in enumerate(g.rows.tolist())}
    return np.array([best[where[r]] if r in where else miss for r in rows.tolist()])


def _kept(arrays: TrackArrays) -> list[str]:
    """The columns a branch restores: all but the track's life (M of N, score)."""
    return [name for name in arrays.shapes if name not in LIFE_COLUMNS and name != "alive"]


def _put(arrays: TrackArrays, rows: np.ndarray, saved: list[dict[str, np.ndarray]]) -> None:
    for name in saved[0]:
        column = getattr(arrays, name)
        for row, s in zip(rows.tolist(), saved, strict=True):
            column[row] = s[name]
