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
  the miss branch (`note`). So it is for a detection beyond an aircraft's reach of the
  track's own extrapolation (`far`: 0.5 reach dt^2, plus 3 sigma of the measurement),
  however well it scores: a wide manoeuvre mode's Gaussian tails overstate what an
  aircraft does (a false detection 1.7 km off at 4 s beat a miss by ln 7.1 in the case
  of docs/accuracy.md). Its update is shown at once, and kept aside only while it stays
  beyond reach once made, its lead then counted as `margin` at most.
- Once updated (`settle`), a track whose update moved it farther from where its miss
  branch predicts than an aircraft reaches at `reach` m/s^2 (0.5 reach dt^2, plus 3
  sigma of its updated position) is not committed to it: the updated row (the taken
  branch) is set aside and the row before is put back, so the track is shown and
  published as if missed at that scan (no tracks/ state for that update; its frames
  coast) while the doubt lasts. A nearer one (a hard turn's) is shown at once, its
  miss branch aside.
- At the next scan part of its layout (any sensor, later in time), the two branches are
  scored on that scan alone, each by its best gated detection (or a miss): taken (the
  margin plus its best) against missed (its best). The better is put in the row, and
  the scan is associated as usual from there (`decide`). Either way the doubt ends.

- The other way round (`GNNAssociator.second_chance`): a confirmed track that
  missed while a free detection in its gate, within reach, scored less than `margin`
  below a miss is updated with it as a branch set aside at once (`note(missed=True)`:
  `settle` always defers it), its score's shortfall counted against it at the next scan.

The branches are compared track by track, before the joint assignment of the second
scan (which then resolves any detection two tracks want). The track's life counters
(M of N, score) keep the first scan's detection. Doubts are not checkpointed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .. import defaults
from ..wire import TIME_TOL
from .gating import Gating
from .life import LIFE_COLUMNS
from .store import TrackArrays


@dataclass
class Doubt:
    """One confirmed track's doubtful update at time `t`, by how much taking the
    detection beat missing it; `row`: the columns of the branch not in the store's row
    (`note`: the miss branch; `settle` may swap), `deferred`: whether that is the taken
    branch, and `at`: the time of the row as `settle` left it."""

    track_id: str
    t: float
    margin: float
    row: dict[str, np.ndarray]
    deferred: bool = False
    at: float = float("nan")
    far: bool = False  # noted for its distance alone (no doubt by its score)
    missed: bool = False  # a miss by a hair: the detection's branch set aside (`chance`)


class SecondLook:
    """The doubtful assignments of confirmed tracks, kept one scan (`note`, `settle`,
    `decide`). `moved(arrays, rows)` is told of rows whose columns were put back here
    (the display's cache of them is stale)."""

    def __init__(self, margin: float, reach: float = defaults.SECOND_LOOK_REACH,
                 moved: Callable[[TrackArrays, np.ndarray], None] | None = None) -> None:
        self.margin, self.reach, self.moved = margin, reach, moved
        self.noted: dict[tuple[int, int], Doubt] = {}  # (layout's dim, row) -> doubt
        self.doubts: dict[tuple[int, int], Doubt] = {}  # settled, for the next scan
        self.reverted = 0  # doubts decided for the miss branch, since start
        self.deferred = 0  # doubtful updates not shown until the next scan, since start
        self.chances = 0  # misses by a hair whose detection's branch waited a scan
        self.retaken = 0  # ... decided for that branch

    def far(self, arrays: TrackArrays, rows: np.ndarray, z: np.ndarray, r: np.ndarray,
            det: np.ndarray, t: float) -> np.ndarray:
        """Of confirmed tracks `rows` taking detections `det` of a scan at `t` (its
        converted points `z`, covariances `r`; -1: none): those whose detection lies
        beyond an aircraft's reach of their own extrapolation (0.5 reach dt^2, plus 3
        sigma of the measurement)."""
        out = np.zeros(len(rows), dtype=bool)
        ok = det >= 0
        if self.margin <= 0 or self.reach <= 0 or not ok.any():
            return out
        rows, det = rows[ok], det[ok]
        dt = t - arrays.t[rows]
        pred = _extrapolated(arrays.x[rows].T, arrays.dim, arrays.order, dt).T
        noise = 3.0 * np.sqrt(np.trace(r[det], axis1=1, axis2=2))
        out[ok] = np.linalg.norm(z[det] - pred, axis=1) > 0.5 * self.reach * dt * dt + noise
        return out

    def note(self, arrays: TrackArrays, rows: np.ndarray, margins: np.ndarray,
             t: float, far: np.ndarray | None = None, missed: bool = False) -> None:
        """Tracks `rows` take a detection at `t` that beats missing by `margins`: keep the
        rows (before their update) of those below the margin, and of those `far`
        (`SecondLook.far`)."""
        if self.margin <= 0:
            return
        doubtful = margins < self.margin
        if far is not None:
            doubtful |= far
        kept = _kept(arrays)
        for i in np.flatnonzero(doubtful).tolist():
            row = int(rows[i])
            self.noted[arrays.dim, row] = Doubt(
                arrays.ids[row], t, float(margins[i]),
                {name: getattr(arrays, name)[row].copy() for name in kept},
                far=bool(margins[i] >= self.margin), missed=missed)

    def settle(self, arrays: TrackArrays, rows: np.ndarray) -> np.ndarray:
        """Rows of `arrays` were just updated: of those noted as doubtful, the ones that
        moved beyond reach set their taken branch aside and take their miss branch back
        (the mask of those, over rows); the others keep their update."""
        out = np.zeros(len(rows), dtype=bool)
        if not self.noted:
            return out
        d_, o = arrays.dim, arrays.order
        chances = 0
        for i, row in enumerate(rows.tolist()):
            d = self.noted.pop((d_, row), None)
            if d is None or arrays.ids[row] != d.track_id:
                continue
            miss, dt = d.row["x"], d.t - float(d.row["t"])
            pred = _extrapolated(miss, d_, o, dt)
            # beyond reach: farther than the acceleration takes it, plus 3 sigma of the
            # updated position (the measurement's noise in it)
            noise = 3.0 * np.sqrt(np.trace(arrays.p[row, :d_, :d_]))
            beyond = np.linalg.norm(arrays.x[row, :d_] - pred) > 0.5 * self.reach * dt * dt \
                + noise
            if d.far:  # no doubt by its score: weighed by the next scan only while beyond
                if beyond:  # reach, shown meanwhile, its lead counted as a doubt's at most
                    d.margin, d.at = self.margin, float(arrays.t[row])
                    self.doubts[d_, row] = d
                continue
            if beyond or d.missed:
                chances += d.missed
                taken = {name: getattr(arrays, name)[row].copy() for name in d.row}
                _put(arrays, np.array([row]), [d.row])
                d.row, d.deferred = taken, True
                out[i] = True
            d.at = float(arrays.t[row])
            self.doubts[d_, row] = d
        self.chances += chances
        self.deferred += int(out.sum()) - chances
        if out.any() and self.moved is not None:
            self.moved(arrays, rows[out])
        return out

    def decide(self, arrays: TrackArrays, every: Gating, t: float, score: np.ndarray,
               miss: float, gate_rows: Callable[[np.ndarray], tuple[Gating, np.ndarray]]
               ) -> bool:
        """At a scan part of `arrays`' layout at `t` gated as `every` (pair scores `score`,
        a miss `miss`): each doubted track takes the branch that scores better on it;
        `gate_rows(rows)` gates rows of the store against the same detections (the
        gating and its pairs' scores). Whether any changed (the scan must then be gated
        again)."""
        self.noted.clear()  # noted but never updated (a non-finite result): no doubt
        for key in [key for key, d in self.doubts.items() if key[0] == arrays.dim
                    and arrays.ids[key[1]] != d.track_id]:
            del self.doubts[key]  # the track was deleted meanwhile
        mine = [(key, d) for key, d in self.doubts.items() if key[0] == arrays.dim
                and t > d.t + TIME_TOL]
        if not mine:
            return False
        for key, _ in mine:
            del self.doubts[key]
        # still as settle left them (no other update since, not rejected)
        live = [(key[1], d) for key, d in mine if abs(arrays.t[key[1]] - d.at) <= TIME_TOL]
        if not live:
            return False
        rows = np.array([row for row, _ in live], dtype=np.intp)
        deferred = np.array([d.deferred for _, d in live])
        here = _best(every, score, miss, rows)  # the branch in the row
        now = {name: getattr(arrays, name)[rows].copy() for name in _kept(arrays)}
        _put(arrays, rows, [d.row for _, d in live])
        aside = _best(*gate_rows(rows), miss, np.arange(len(rows)), local=True)
        taken, missed = np.where(deferred, aside, here), np.where(deferred, here, aside)
        back = missed > taken + np.array([d.margin for _, d in live])  # the miss branch
        swap = back != deferred  # the branch set aside is the better
        for name, values in now.items():  # the row's own branch where it stays
            getattr(arrays, name)[rows[~swap]] = values[~swap]
        self.reverted += int(back.sum())
        self.retaken += int((swap & np.array([d.missed for _, d in live])).sum())
        if self.moved is not None:
            self.moved(arrays, rows)
        return bool(swap.any())


def _extrapolated(x: np.ndarray, d: int, order: int, dt: float | np.ndarray) -> np.ndarray:
    """A state's position `dt` later by its own motion (velocity, acceleration); states
    as columns of x, one dt each, too."""
    pred = x[:d] + x[d:2 * d] * dt
    return pred + 0.5 * x[2 * d:3 * d] * dt * dt if order == 3 else pred


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
