"""Labelled measurements in one pass over their columns: a batched scan
(`<ns>/scan/<sensor>`), or the single messages the service's worker takes together.

The same steps as `Tracker.track` on the scan's rows as single measurements (label
association, update, deletion, initiation; a target measured twice in the scan is updated
twice, in turn), each step once for all the rows instead of once per measurement record:
the rows are matched to tracks through the store's id index in one pass, the tracks are
updated with one call of the filter per step, new ids start their tracks together
(`TrackStore.add_many`), and the outcomes are counts, (row, reason) pairs and blocks of
states instead of one record per measurement. tests/test_scan_batch.py checks that the
tracks come out identical to those of the single measurements.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..estimation.measurements import MeasurementBatch
from .associator import split_repeats
from .store import States, TrackArrays

if TYPE_CHECKING:
    from .tracker import Tracker

NON_FINITE = "update gave a non-finite state"  # as Tracker.update words it
# rows of an update between two pauses: a realtime frame due meanwhile waits for one
# part (~8 ms of CPU on this 2-core machine, idle-equivalent, with the default IMM)
PART = 1024
Want = Callable[[list[str]], "list[int] | None"]  # ids -> indices wanted (None: all)


def all_states(ids: list[str]) -> None:
    """Every track's state is wanted."""
    return None


@dataclass
class Rows:
    """Labelled measurements of one dimension as columns, waiting to be applied: each
    row's sensor and target id, and the measurements."""

    sensors: list[str]
    ids: list[str]
    batch: MeasurementBatch

    def __len__(self) -> int:
        return len(self.ids)

    def rows(self, lo: int, hi: int) -> Rows:
        """Rows lo to hi - 1."""
        return Rows(self.sensors[lo:hi], self.ids[lo:hi], self.batch.rows(lo, hi))

    @staticmethod
    def joined(parts: list[Rows]) -> list[Rows]:
        """`parts` in order, consecutive ones of one dimension joined into one."""
        out: list[list[Rows]] = []
        for r in parts:
            if out and out[-1][0].batch.dim == r.batch.dim:
                out[-1].append(r)
            else:
                out.append([r])
        return [g[0] if len(g) == 1 else
                Rows([s for r in g for s in r.sensors], [k for r in g for k in r.ids],
                     MeasurementBatch.joined([r.batch for r in g])) for g in out]


@dataclass
class BatchOutcome:
    """What became of a batch's rows: how many were applied, why the others were not,
    the tracks deleted on the way and (when asked) the states of the tracks updated or
    started, one block per step, in order."""

    accepted: int = 0
    rejected: list[tuple[int, str]] = field(default_factory=list)  # (row, reason), in order
    deleted: list[str] = field(default_factory=list)
    states: list[States] = field(default_factory=list)


def track_columns(tracker: Tracker, ids: Sequence[str], sensor: str | Sequence[str],
                  batch: MeasurementBatch, want: Want | None = all_states,
                  pause: Callable[[BatchOutcome], None] | None = None) -> BatchOutcome:
    """Apply the measurements `batch`, row i labelled ids[i], in order (`sensor`: the
    sensor of every row, or of each).
    `want`: which of the tracks updated (given their ids) to return the states of, for
    the `tracks/` and `states` outputs (None: none). `pause`: called between parts of
    `PART` rows of an update with the outcome so far (a realtime service puts the states
    of the part done and a due frame there; a row's update does not depend on the
    others, so the parts give the same result)."""
    out = BatchOutcome()

    def keep(arrays: TrackArrays, rows: np.ndarray) -> None:
        if want is None or not len(rows):
            return
        names = arrays.ids
        pick = want([names[r] for r in rows.tolist()])  # type: ignore[misc]
        if pick is None or len(pick):
            out.states.append(tracker.states(arrays, rows if pick is None else rows[pick]))

    store, dim = tracker.store, batch.dim
    for idx in split_repeats(ids):
        whole = len(idx) == len(ids)
        sub_ids = ids if whole else [ids[i] for i in idx]
        sub = batch if whole else batch.take(idx)
        sub_sensor = sensor if whole or isinstance(sensor, str) else [sensor[i] for i in idx]
        upd, rows, new, bad = tracker.associator.associate_columns(store, sub_ids, sub_sensor,
                                                                   sub.t, dim)
        if len(upd):
            arrays = store.layout(dim)
            order = np.argsort(rows, kind="stable")  # the rows in store order: a row's
            upd, rows = upd[order], rows[order]  # result does not depend on the others
            cut = len(rows) if pause is None else PART
            for lo in range(0, len(rows), cut):
                if lo:
                    pause(out)  # type: ignore[misc]
                part = upd[lo:lo + cut]
                good, ok, _ = tracker.update_rows(arrays, rows[lo:lo + cut], sub.take(part),
                                                  sub_sensor if isinstance(sub_sensor, str)
                                                  else [sub_sensor[i] for i in part])
                for j in np.flatnonzero(~ok).tolist():
                    bad[int(part[j])] = NON_FINITE
                keep(arrays, good)
        out.deleted += tracker.delete(float(sub.t.max()))
        if new:
            arrays, made, reasons = tracker.initiator.initiate(
                store, dim, sub if len(new) == len(sub_ids) else sub.take(new),
                [sub_ids[i] for i in new])
            tracker.updater.initiate(arrays, made)
            tracker.display.initiate(arrays, made)
            for i, reason in zip(new, reasons, strict=True):
                if reason is not None:
                    bad[i] = reason
            keep(arrays, made)
        out.rejected += [(idx[i], reason) for i, reason in bad.items()]
        out.accepted += len(idx) - len(bad)
    out.rejected.sort()
    return out
