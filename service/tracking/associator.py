"""Data association: which measurement updates which track.

`LabelAssociator` serves labelled measurements (`<ns>/meas/<sensor>/<target>`): the
label names the track. Associators for unlabelled detections (GNN, JPDA) take the same
slot in the tracker loop (`tracker.Tracker.step`) and return the same `Hypotheses`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from ..wire import Measurement
from .store import TrackStore

TIME_TOL = 1e-6  # s: measurements this close to the track time count as simultaneous


@dataclass
class Hypotheses:
    """One scan's associations, as indices into the scan's measurements."""

    updates: dict[int, list[int]] = field(default_factory=dict)  # by dimension: track hits
    unassociated: dict[int, list[int]] = field(default_factory=dict)  # by dimension: new
    rejected: dict[int, str] = field(default_factory=dict)  # index -> reason
    missed: list[str] = field(default_factory=list)  # tracks that had no detection


class LabelAssociator:
    """A measurement belongs to the track its label names; a label with no track starts
    one. A measurement for a track of the other dimension, or older than the track's last
    update (labelled tracks are not retrodicted), is rejected. Labelled measurements do
    not say which tracks a sensor missed, so `missed` stays empty: the tracks' status
    follows from their age (`status`)."""

    def scans(self, meas: Sequence[Measurement]) -> list[list[int]]:
        """Split a batch into scans in which each target appears at most once, keeping
        order: a target measured twice in a batch is updated twice, in turn."""
        out: list[list[int]] = []
        pending = list(range(len(meas)))
        while pending:
            seen: set[str] = set()
            now, later = [], []
            for i in pending:
                (later if meas[i].target in seen else now).append(i)
                seen.add(meas[i].target)
            out.append(now)
            pending = later
        return out

    def associate(self, store: TrackStore, scan: Sequence[Measurement]) -> Hypotheses:
        hyp = Hypotheses()
        for i, m in enumerate(scan):
            hit = store.where.get(m.target)
            if hit is None:
                hyp.unassociated.setdefault(m.dim, []).append(i)
                continue
            arrays, row = hit
            if arrays.dim != m.dim:
                hyp.rejected[i] = f"{m.dim}-D measurement for a {arrays.dim}-D track"
            elif m.t < arrays.t[row] - TIME_TOL:
                hyp.rejected[i] = (f"out of sequence: t={m.t:.6f} is before the track's last "
                                   f"update at t={arrays.t[row]:.6f}")
            else:
                hyp.updates.setdefault(m.dim, []).append(i)
        return hyp
