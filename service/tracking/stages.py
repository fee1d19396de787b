"""Association stages (`protocols.Stage`) wrapped around the established tracks' step of
`plot_association.ScanAssociator`: the speed gate and the second chance. The second look
is one too (`second_look.SecondLook`). A stage with nothing to do at a hook hands back
what it was given (`Pass`)."""

from __future__ import annotations

import numpy as np

from .gating import Gating
from .plot_association import scores
from .protocols import Scene
from .reach import Reach
from .second_look import SecondLook
from .store import TrackArrays


class Pass:
    """A stage that does nothing at any hook: the base of a stage that acts at one."""

    def before(self, scene: Scene) -> None:
        return None

    def pairs(self, scene: Scene) -> np.ndarray | None:
        return None

    def after(self, scene: Scene, taken: Gating, free: np.ndarray) -> np.ndarray:
        return free

    def settle(self, arrays: TrackArrays, rows: np.ndarray) -> np.ndarray:
        return np.zeros(len(rows), dtype=bool)

    def counts(self) -> dict[str, int]:
        return {}


class SpeedGate(Pass):
    """An established track takes no detection farther from its last position than the
    fastest target flies meanwhile (`Reach.flown`, with both positions' sigmas): the
    widest mode's gate of a track coasting through missed scans reaches kilometres out
    (docs/accuracy.md, "Slow and tight flyers")."""

    def __init__(self, reach: Reach | None = None) -> None:
        self.reach = reach or Reach()

    def pairs(self, scene: Scene) -> np.ndarray | None:
        g, z, r = scene.every, scene.z, scene.r
        a, rows, d = g.arrays, g.rows[g.ti], g.arrays.dim
        dt = scene.t - a.t[rows]
        var = np.trace(r[g.dj], axis1=1, axis2=2) + np.trace(a.p[rows, :d, :d], axis1=1,
                                                             axis2=2)
        far = np.linalg.norm(z[g.dj] - a.x[rows, :d], axis=1) > self.reach.flown(dt, var)
        return ~far if far.any() else None


class SecondChance(Pass):
    """A confirmed track that missed while a free detection in its gate, within reach,
    scored less than the second look's margin below a miss takes it as a branch set aside
    for the next scan (`SecondLook.note(missed=True)`; one track a detection, likeliest
    first). For one-to-one assignments (GNN): JPDA already weighs every gated detection."""

    def __init__(self, look: SecondLook) -> None:
        self.look = look

    def after(self, scene: Scene, taken: Gating, free: np.ndarray) -> np.ndarray:
        look, g, hyp = self.look, taken, scene.hyp
        if look.margin <= 0 or not len(g.ti) or not len(free):
            return free
        score, miss = scores(g, scene.pd, scene.lam)
        lead = score - miss
        open_ = np.zeros(len(g.z), dtype=bool)
        open_[free] = True
        k = np.flatnonzero(~hyp.seen[-1].detected[g.ti] & open_[g.dj] & (lead > -look.margin))
        if not len(k):
            return free
        k = k[~look.far(g.arrays, g.rows[g.ti[k]], scene.z, scene.r, g.dj[k], scene.t)]
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
        look.note(g.arrays, rows, lead[p], scene.t, missed=True)
        return free[open_[free]]
