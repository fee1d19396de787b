"""What enters the tracker's one loop (`tracker.Tracker.step`) and what comes out.

Every input is one typed columnar batch:

- `Labelled`: labelled measurements of one dimension (single messages taken together,
  or the rows of batched `scan/` messages), each row's sensor and target id beside the
  measurements' columns;
- `Unlabelled`: one unlabelled radar scan (`plots/`): one sensor, one time, its
  detections as columns, one batch per dimension (an empty scan: no batch, the sensor
  saw none of the tracks);
- `Instant`: a time without a measurement (a display instant): the tracks coast and the
  stale ones are deleted.

The step's outcome is counts, (row, reason) pairs and blocks of states, not a record per
measurement (`StepOutcome`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..estimation.measurements import MeasurementBatch
from ..wire import Measurement
from .store import States

Want = Callable[[list[str]], "list[int] | None"]  # ids -> indices wanted (None: all)


def all_states(ids: list[str]) -> None:
    """Every track's state is wanted."""
    return None


@dataclass
class Labelled:
    """Labelled measurements of one dimension as columns: each row's sensor and target
    id, and the measurements (a target may come more than once: updated in turn)."""

    sensors: list[str]
    ids: list[str]
    batch: MeasurementBatch

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def of(cls, meas: Sequence[Measurement]) -> Labelled:
        """Validated records (`wire.Measurement`) of one dimension as columns."""
        dim = meas[0].dim if meas else 3
        return cls([m.sensor for m in meas], [m.target for m in meas],
                   MeasurementBatch.of(meas, dim))

    def rows(self, lo: int, hi: int) -> Labelled:
        """Rows lo to hi - 1."""
        return Labelled(self.sensors[lo:hi], self.ids[lo:hi], self.batch.rows(lo, hi))

    def take(self, index: list[int]) -> Labelled:
        """The rows at `index`, in that order."""
        return Labelled([self.sensors[i] for i in index], [self.ids[i] for i in index],
                        self.batch.take(index))

    @property
    def t(self) -> float:
        """The time of the newest row: the tracks stale then are deleted."""
        return float(self.batch.t.max())

    @staticmethod
    def joined(parts: list[Labelled]) -> list[Labelled]:
        """`parts` in order, consecutive ones of one dimension joined into one."""
        out: list[list[Labelled]] = []
        for r in parts:
            if out and out[-1][0].batch.dim == r.batch.dim:
                out[-1].append(r)
            else:
                out.append([r])
        return [g[0] if len(g) == 1 else
                Labelled([s for r in g for s in r.sensors], [k for r in g for k in r.ids],
                         MeasurementBatch.joined([r.batch for r in g])) for g in out]


@dataclass
class Unlabelled:
    """One unlabelled scan: all its detections from one sensor at time t, as columns,
    one batch per dimension with the detections' indices in the scan (`parts`)."""

    sensor: str
    t: float
    parts: list[tuple[list[int], MeasurementBatch]]

    @classmethod
    def of(cls, sensor: str, t: float, detections: Sequence[Measurement]) -> Unlabelled:
        """A checked scan's good detections (`wire.PlotScan.detections`), by dimension."""
        dims = sorted({m.dim for m in detections})
        parts = []
        for dim in dims:
            index = [i for i, m in enumerate(detections) if m.dim == dim] \
                if len(dims) > 1 else list(range(len(detections)))
            parts.append((index, MeasurementBatch.of([detections[i] for i in index], dim)))
        return cls(sensor, t, parts)

    def __len__(self) -> int:
        return sum(len(i) for i, _ in self.parts)


@dataclass
class Detections:
    """The detections of one dimension of an unlabelled scan (`batch`), or none (an empty
    scan: the sensor saw none of the tracks, of any dimension)."""

    sensor: str
    t: float
    batch: MeasurementBatch | None

    def __len__(self) -> int:
        return 0 if self.batch is None else len(self.batch.t)


@dataclass
class Instant:
    """A time without a measurement (a display instant, a new timeline's start)."""

    t: float


StepInput = Labelled | Unlabelled | Instant  # what `Tracker.step` takes


@dataclass
class StepOutcome:
    """What became of a step's rows: how many were applied, why the others were not
    (row, reason, in row order), the tracks deleted on the way and (when asked) the
    states of the tracks updated or started, one block per stage, in order."""

    accepted: int = 0
    rejected: list[tuple[int, str]] = field(default_factory=list)
    deleted: list[str] = field(default_factory=list)
    states: list[States] = field(default_factory=list)

    def renamed(self, ids: Mapping[str, tuple[str, int]]) -> None:
        """Tracks went on under other ids ({id: (new id, updates counted before)}): their
        states here are renamed and their updates counted on, the ids reported deleted."""
        for block in self.states:
            for i, track_id in enumerate(block.ids):
                if track_id in ids:
                    block.ids[i], before = ids[track_id]
                    block.updates[i] += before
        self.deleted += list(ids)

    def keep(self, states: Callable[[np.ndarray | None], States], ids: list[str | None],
             rows: np.ndarray, want: Want | None) -> None:
        """Keep the states of the `rows` (of a layout whose ids are `ids`) that `want`
        picks; `states(pick)` makes those of rows[pick] (None: of all)."""
        if want is None or not len(rows):
            return
        pick = want([ids[r] for r in rows.tolist()])  # type: ignore[misc]
        if pick is None or len(pick):
            self.states.append(states(None if pick is None else np.asarray(pick, dtype=int)))
