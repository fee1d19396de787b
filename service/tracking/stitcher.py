"""Track continuation: a new track confirmed where a lost one could have gone keeps the
lost track's id.

A confirmed track that misses several scans in a row while its aircraft manoeuvres
(two misses in a 4 g turn at 5 s put it kilometres off any extrapolation) coasts away,
and the aircraft's detections start a new track: one aircraft, two ids. Track segment
association joins such segments (Yeom, Kirubarajan & Bar-Shalom, IEEE TAES 40(1),
2004): the old segment ends, a new one begins within what the target could have done
meanwhile, and the two are one track. Here, when a track of unlabelled scans is
confirmed (`life.update_life`), it is compared with every confirmed track of its layout
that has missed every scan since the oldest detection in the new one's M-of-N window and
was not updated by this scan (so the two never took the same scan: not two targets side
by side):

- its position within an aircraft's reach of the old track's extrapolation, and its
  velocity within the change an aircraft makes meanwhile (`reach.Reach.strayed`,
  `Reach.turned`, with the sigmas of both tracks).

A pair joins only when each has no other candidate (where several lost tracks or
several new ones could match, as where targets cross, nothing is joined). The new
track's state takes the old track's id (its updates counted on from the old track's,
its first update the old one's); the old row is removed and the new id announced
deleted, like a tentative track that ended (docs/protocol.md, "Track life"). Stone
Soup's `TrackStitcher` joins segments offline; this does it online, at confirmation.
"""

from __future__ import annotations

import numpy as np

from ..wire import TIME_TOL
from .reach import Reach
from .store import TrackArrays, TrackStore


class Stitcher:
    """Joins each newly confirmed track to the one lost track it continues, within an
    aircraft's `reach`."""

    def __init__(self, reach: Reach | None = None) -> None:
        self.reach = reach or Reach()
        self.joined = 0  # tracks continued under an old id, since start

    def pairs(self, arrays: TrackArrays, new: np.ndarray) -> list[tuple[int, int]]:
        """(new row, old row) of the rows `new` just confirmed that continue a lost
        track."""
        if not len(new):
            return []
        rows, _ = arrays.live()
        old = rows[arrays.plot[rows] & arrays.confirmed[rows]]
        old = old[~np.isin(old, new)]
        if not len(old):
            return []
        d = arrays.dim
        # lost before the new track's detections: the old one missed every scan since
        # the oldest of them in its window (the bits of its last N scans, newest lowest)
        since = np.floor(np.log2(np.maximum(arrays.hits[new], 1))).astype(np.int64) + 1
        # (and not updated by this scan: a JPDA track counted missed may still have taken
        # a weighted update)
        lost = (arrays.misses[old][None, :] >= since[:, None]) & \
            (arrays.t[old][None, :] < arrays.t[new][:, None] - TIME_TOL)  # (N, O)
        if not lost.any():
            return []
        dt = np.maximum(arrays.t[new][:, None] - arrays.t[old][None, :], 0.0)
        xo, po = arrays.x[old], arrays.p[old]
        xn, pn = arrays.x[new], arrays.p[new]
        pos_o, vel_o = xo[:, :d], xo[:, d:2 * d]
        pred = pos_o[None] + vel_o[None] * dt[..., None]  # (N, O, d)
        tr = np.trace  # the sigmas: traces of the position and velocity blocks
        var_pp, var_vv = tr(po[:, :d, :d], axis1=1, axis2=2), tr(po[:, d:2 * d, d:2 * d],
                                                                  axis1=1, axis2=2)
        var_pv = tr(po[:, :d, d:2 * d], axis1=1, axis2=2)
        var_old = var_pp[None] + 2.0 * dt * var_pv[None] + dt * dt * var_vv[None]
        var_new = tr(pn[:, :d, :d], axis1=1, axis2=2)[:, None]
        near = np.linalg.norm(xn[:, None, :d] - pred, axis=2) <= \
            self.reach.strayed(dt, np.maximum(var_old + var_new, 0.0))
        var_v = var_vv[None] + tr(pn[:, d:2 * d, d:2 * d], axis1=1, axis2=2)[:, None]
        same = np.linalg.norm(xn[:, None, d:2 * d] - vel_o[None], axis=2) <= \
            self.reach.turned(dt, np.maximum(var_v, 0.0))
        ok = lost & near & same
        one = ok & (ok.sum(axis=1, keepdims=True) == 1) & (ok.sum(axis=0, keepdims=True) == 1)
        j, i = np.nonzero(one)
        return [(int(new[a]), int(old[b])) for a, b in zip(j.tolist(), i.tolist(), strict=True)]

    def join(self, store: TrackStore, arrays: TrackArrays, new: np.ndarray
             ) -> dict[str, tuple[str, int]]:
        """Continue lost tracks by the rows `new` just confirmed: {new id: (old id, its
        updates)} of those joined (the old rows removed, the new rows renamed)."""
        out: dict[str, tuple[str, int]] = {}
        for n, o in self.pairs(arrays, new):
            new_id, old_id = arrays.ids[n], arrays.ids[o]
            assert new_id is not None and old_id is not None
            updates, first = arrays.updates[o], arrays.t_first[o]
            store.remove([old_id])
            store.rename(new_id, old_id)
            arrays.updates[n] += updates
            arrays.t_first[n] = first
            out[new_id] = (old_id, int(updates))
        self.joined += len(out)
        return out
