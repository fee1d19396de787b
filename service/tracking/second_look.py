"""A second look before a confirmed track is committed to a doubtful detection: a
one-scan window of a track-oriented multiple-hypothesis tracker (Reid, IEEE TAC 24(6),
1979; Blackman, IEEE AES Magazine 19(1), 2004), for the one case where global nearest
neighbour's choice of a scan alone is often wrong.

- `note` (after the established tracks took their detections): a confirmed track whose
  detection beats a miss by less than `margin` (ln of a likelihood ratio), or lies
  beyond an aircraft's reach of its own extrapolation (`far`: a wide manoeuvre mode's
  Gaussian tails overstate what an aircraft does), keeps its row before the update: the
  miss branch.
- `settle` (once updated): an update that moved the track beyond reach of where its miss
  branch predicts is set aside and the miss branch put back, so the track is shown and
  published as if missed until the next scan; a nearer one is shown at once, its miss
  branch aside. A far detection that scored well is weighed only while it stays beyond
  reach, its lead counted as a doubt's at most.
- `before` (the next scan part of its layout): each branch scored by its best gated
  detection (or a miss), taken (the margin plus its best) against missed; the better is
  put in the row, and the scan is associated from there. Either way the doubt ends.

`stages.SecondChance` feeds it the other way round (a miss by a hair). The track's life
counters keep the first scan's detection; doubts are not checkpointed. docs/accuracy.md
gives the cases that set the margin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import defaults
from ..wire import TIME_TOL
from .gating import Gating
from .label_association import LABEL_COLUMNS
from .life import LIFE_COLUMNS
from .plot_association import scores
from .protocols import Scene
from .reach import Reach, extrapolated
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
    """The doubtful assignments of confirmed tracks, kept one scan: an association stage
    (`protocols.Stage`) with the `margin` below which a detection is doubtful and an
    aircraft's `reach`."""

    def __init__(self, margin: float = defaults.SECOND_LOOK, reach: Reach | None = None
                 ) -> None:
        self.margin, self.reach = margin, reach or Reach()
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
        if self.margin <= 0 or self.reach.accel <= 0 or not ok.any():
            return out
        rows, det = rows[ok], det[ok]
        dt = t - arrays.t[rows]
        pred = extrapolated(arrays.x[rows].T, arrays.dim, arrays.order, dt).T
        out[ok] = np.linalg.norm(z[det] - pred, axis=1) > \
            self.reach.strayed(dt, np.trace(r[det], axis1=1, axis2=2))
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
            pred = extrapolated(miss, d_, o, dt)
            # beyond reach, the updated position's sigma (the measurement's noise in it)
            beyond = np.linalg.norm(arrays.x[row, :d_] - pred) > \
                self.reach.strayed(dt, np.trace(arrays.p[row, :d_, :d_]))
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
        return out

    def before(self, scene: Scene) -> None:
        """At a scan part of the doubted tracks' layout: each takes the branch that scores
        better on it; the scan is gated again when any changed."""
        if self.decide(scene):
            scene.regate()  # a track took its doubtful update after all

    def decide(self, scene: Scene) -> bool:
        """Each doubted track of the scene's layout takes its better branch (the rows put
        back are told to the display: `scene.hyp.moved`); whether any changed."""
        arrays, t = scene.arrays, scene.t
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
        score, miss = scores(scene.every, scene.pd, scene.lam)
        here = _best(scene.every, score, miss, rows)  # the branch in the row
        now = {name: getattr(arrays, name)[rows].copy() for name in _kept(arrays)}
        _put(arrays, rows, [d.row for _, d in live])
        g = scene.gate(rows)
        aside = _best(g, scores(g, scene.pd, scene.lam)[0], miss, np.arange(len(rows)),
                      local=True)
        taken, missed = np.where(deferred, aside, here), np.where(deferred, here, aside)
        back = missed > taken + np.array([d.margin for _, d in live])  # the miss branch
        swap = back != deferred  # the branch set aside is the better
        for name, values in now.items():  # the row's own branch where it stays
            getattr(arrays, name)[rows[~swap]] = values[~swap]
        self.reverted += int(back.sum())
        self.retaken += int((swap & np.array([d.missed for _, d in live])).sum())
        scene.hyp.moved.append((arrays, rows))
        return bool(swap.any())

    def pairs(self, scene: Scene) -> None:
        return None

    def after(self, scene: Scene, taken: Gating, free: np.ndarray) -> np.ndarray:
        """The established tracks' doubtful detections noted (their miss branches kept):
        below the margin, or beyond reach (GNN's pairs; JPDA's weighted updates are
        weighed by their margins alone)."""
        arrays, hyp = scene.arrays, scene.hyp
        seen = hyp.seen[-1]
        rows = seen.rows[seen.detected]
        far = None
        if hyp.index and len(rows):  # where each took its detection
            det = np.full(len(arrays.t), -1, dtype=np.intp)
            det[hyp.rows[-1]] = hyp.index[-1]
            far = self.far(arrays, rows, scene.z, scene.r, det[rows], scene.t)
        self.note(arrays, rows, seen.gain[seen.detected] - seen.miss, scene.t, far)
        return free

    def counts(self) -> dict[str, int]:
        """How often it acted since start (`status`)."""
        return {"deferred": self.deferred, "reverted": self.reverted,
                "chances": self.chances, "retaken": self.retaken}





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
    """The columns a branch restores: all but the track's life (M of N, score) and the
    labelled association's (an unlabelled track's branches do not touch it)."""
    return [name for name in arrays.shapes
            if name not in LIFE_COLUMNS and name not in LABEL_COLUMNS and name != "alive"]


def _put(arrays: TrackArrays, rows: np.ndarray, saved: list[dict[str, np.ndarray]]) -> None:
    for name in saved[0]:
        column = getattr(arrays, name)
        for row, s in zip(rows.tolist(), saved, strict=True):
            column[row] = s[name]
