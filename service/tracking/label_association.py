"""Association of labelled measurements (`<ns>/meas/<sensor>/<target>`, `scan/`): the
label names the track. The rejections of a labelled measurement are worded here, once.
Unlabelled scans have their associators in `plot_association` (GNN, JPDA); both kinds
take the same slot in the tracker loop (`tracker.Tracker.step`) and return `Hypotheses`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..wire import TIME_TOL
from .batches import Labelled
from .hypotheses import Hypotheses
from .store import TrackStore


def wrong_dimension(dim: int, track_dim: int) -> str:
    return f"{dim}-D measurement for a {track_dim}-D track"


def out_of_sequence(t: float, last: float) -> str:
    return f"out of sequence: t={t:.6f} is before the track's last update at t={last:.6f}"


def duplicate(sensor: str, t: float) -> str:
    return f"duplicate: sensor {sensor} already measured this target at t={t:.6f}"


class LabelAssociator:
    """A measurement belongs to the track its label names; a label with no track starts
    one. A measurement for a track of the other dimension, older than the track's last
    update (labelled tracks are not retrodicted), or a duplicate (the same sensor at the
    same time as the track's last update) is rejected. Labelled measurements do not say
    which tracks a sensor missed, so `seen` stays empty: the tracks' status follows from
    their age. Remembers the sensor of each track's last update (`memory`)."""

    def __init__(self) -> None:
        self.last: dict[str, str] = {}  # track -> the sensor of its last update

    def memory(self) -> dict[str, str]:
        """A copy of what it remembers of the tracks (for a checkpoint)."""
        return dict(self.last)

    def remember(self, last: Mapping[str, str]) -> None:
        """Take back what `memory` gave (a restored checkpoint)."""
        self.last.update(last)

    def forget(self, ids: Sequence[str]) -> None:
        """Tracks deleted: drop what is kept of them."""
        for track_id in ids:
            self.last.pop(track_id, None)

    def split(self, scan: Labelled) -> list[tuple[list[int], Labelled]]:
        """The scan in parts in which each target appears at most once, keeping order: a
        target measured twice is updated twice, in turn."""
        parts = split_repeats(scan.ids)
        if len(parts) == 1:
            return [(parts[0], scan)]
        return [(idx, scan.take(idx)) for idx in parts]

    def associate(self, store: TrackStore, part: Labelled) -> Hypotheses:
        """The rows of `part` (each target at most once) against the store's tracks."""
        ids, sensors, t, dim = part.ids, part.sensors, part.batch.t, part.batch.dim
        where, last = store.where, self.last
        arrays = store.layouts.get(dim)
        hits = list(map(where.get, ids))
        upd: list[int] = []
        rows: list[int] = []
        hyp = Hypotheses(dim)
        new, rejected = hyp.unassociated, hyp.rejected
        if None not in hits and len(store.layouts) == 1 and arrays is not None:
            upd, rows = list(range(len(ids))), [h[1] for h in hits]  # type: ignore[index]
        else:
            for i, hit in enumerate(hits):
                if hit is None:
                    new.append(i)
                elif hit[0] is arrays:
                    upd.append(i)
                    rows.append(hit[1])
                else:
                    rejected[i] = wrong_dimension(dim, hit[0].dim)
        ui, ri = np.array(upd, dtype=np.intp), np.array(rows, dtype=np.intp)
        if len(ri):
            tt, mt = arrays.t[ri], t[ui]  # type: ignore[union-attr]
            late = mt < tt - TIME_TOL
            near = ~late & (mt <= tt + TIME_TOL)
            if late.any() or near.any():
                for j in np.flatnonzero(late | near).tolist():
                    i = upd[j]
                    if late[j]:
                        rejected[i] = out_of_sequence(mt[j], tt[j])
                    elif last.get(ids[i]) == sensors[i]:
                        rejected[i] = duplicate(sensors[i], mt[j])
                keep = np.array([i not in rejected for i in upd], dtype=bool)
                ui, ri = ui[keep], ri[keep]
        if not rejected:
            last.update(zip(ids, sensors, strict=True))
        else:
            last.update((ids[i], sensors[i]) for i in (*ui.tolist(), *new))
        hyp.assign(ui, ri)
        return hyp


def split_repeats(keys: Sequence[str]) -> list[list[int]]:
    """Indices of `keys` split into runs in which each key appears at most once, in order:
    the first occurrence of every key, then the second ones, and so on."""
    if len(set(keys)) == len(keys):
        return [list(range(len(keys)))] if len(keys) else []
    out: list[list[int]] = []
    pending = list(range(len(keys)))
    while pending:
        seen: set[str] = set()
        now, later = [], []
        for i in pending:
            (later if keys[i] in seen else now).append(i)
            seen.add(keys[i])
        out.append(now)
        pending = later
    return out
