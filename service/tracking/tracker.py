"""The tracker: the loop of the field's textbook over the stacked track store.

Every input enters one loop, `Tracker.step`, as one typed columnar batch (`batches`):
labelled measurements, an unlabelled scan, or a display instant without any. Each part
of a scan is associated with the tracks, the associated tracks are predicted and
updated, the tracks in view count the scan as a detection or a miss, stale tracks are
deleted and unassociated measurements start new tracks. Each stage is a component with
Stone Soup's name (associator, updater, deleter, initiator; `protocols`) so that one can
be swapped without touching the rest; the display state follows every change. Labelled
measurements go through the `LabelAssociator`; unlabelled radar scans through the GNN or
JPDA associator (`plot_association`), and their tracks live by M of N (`life`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .. import defaults
from ..estimation import blocks
from ..estimation.catalog import Filter, FilterSpec
from ..estimation.measurements import MeasurementBatch
from ..wire import TIME_TOL
from .batches import (
    Detections,
    Instant,
    Labelled,
    StepInput,
    StepOutcome,
    Unlabelled,
    Want,
    all_states,
)
from .deleter import CompositeDeleter, UpdateTimeDeleter
from .display import DISPLAY_COLUMNS, DisplayConfig, DisplayState, Snapshot
from .hypotheses import Hypotheses, WeightedUpdate
from .initiator import SinglePointInitiator
from .jpda import JPDAAssociator
from .label_association import LabelAssociator
from .life import LIFE_COLUMNS, MofNDeleter, MofNLife, restore_lost
from .noise_check import NoiseCheck
from .plot_association import GNNAssociator, SensorModels
from .protocols import (
    Deleter,
    Display,
    Initiator,
    LabelledAssociator,
    Life,
    NoiseMonitor,
    ScanAssociator,
    Stage,
    Updater,
)
from .reach import Reach
from .second_look import SecondLook
from .stages import SecondChance, SpeedGate
from .stitcher import Stitcher
from .store import States, TrackArrays, TrackStore

NON_FINITE = "update gave a non-finite state"
# rows of an update per thread between two pauses (`Tracker.step`'s `pause`): a realtime
# frame due meanwhile waits for one part, which the kernel's threads share
# (bench/pass_cost.py measures a part's CPU)
PART = 1024
SCAN_ASSOCIATORS = {"gnn": GNNAssociator, "jpda": JPDAAssociator}  # --associator


def stages(associator: str, reach: Reach, second_look: float) -> list[Stage]:
    """The service's association stages: the speed gate, and with a second look's margin
    (> 0) the second look and, for one-to-one assignments (GNN), the second chance."""
    out: list[Stage] = [SpeedGate(reach)]
    if second_look > 0:
        look = SecondLook(second_look, reach)
        out += [look, SecondChance(look)] if associator == "gnn" else [look]
    return out


@dataclass(frozen=True)
class TrackerConfig:
    """What a tracker is built from; every default from `zenoh_track.defaults`."""

    filter: FilterSpec = field(default_factory=FilterSpec)  # the updater, by name
    init_speed: float = defaults.INIT_SPEED  # m/s: prior std of velocity at initiation
    init_accel: float = defaults.INIT_ACCEL  # m/s^2: prior std of acceleration (order 3)
    delete_after: float = defaults.DELETE_AFTER  # s of simulation time without a measurement
    display: DisplayConfig = field(default_factory=DisplayConfig)
    # unlabelled scans (plots/)
    associator: str = defaults.ASSOCIATOR  # a key of SCAN_ASSOCIATORS: "gnn" or "jpda"
    sensors: SensorModels = field(default_factory=SensorModels)
    gate_probability: float = defaults.GATE_PROBABILITY
    second_look: float = defaults.SECOND_LOOK  # ln ratio below which a scan waits a scan
    max_speed: float = defaults.MAX_SPEED  # m/s: an aircraft's reach (`reach.Reach`) ...
    max_accel: float = defaults.MAX_ACCEL  # m/s^2: ... and its manoeuvres
    stitch_reach: float | None = None  # m/s^2: a lost track continued (None: max_accel; 0: never)
    confirm_m: int = defaults.CONFIRM_M
    confirm_n: int = defaults.CONFIRM_N
    confirm_score: float = defaults.CONFIRM_SCORE
    delete_misses: int = defaults.DELETE_MISSES
    delete_sigma: float = defaults.DELETE_SIGMA


@dataclass(frozen=True)
class EquivalentConversion:
    """A PDA update as one equivalent measurement per track (`jpda.pda`):
    called with the filter's own prediction it returns z and
    R~ = R / b + ((1 - b) / b) H P H'."""

    z: np.ndarray
    r: np.ndarray
    mass: np.ndarray

    def __call__(self, xp: np.ndarray, pp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d, b = self.z.shape[1], self.mass[:, None, None]
        return self.z, self.r / b + (1 - b) / b * pp[:, :d, :d]


class TrackNumbers:
    """Ids `<sensor>-<n>` of new unlabelled tracks, n counting per sensor from 1, never
    reused in a run."""

    def __init__(self) -> None:
        self.last: dict[str, int] = {}  # per sensor: the last number given

    def new(self, sensor: str, k: int) -> list[str]:
        n0 = self.last.get(sensor, 0)
        self.last[sensor] = n0 + k
        return [f"{sensor}-{n}" for n in range(n0 + 1, n0 + 1 + k)]


class Tracker:
    """All tracks, keyed by target id: one filtered state each, in a `TrackStore`. Given
    its parts (`protocols`), it calls only what their protocols declare; `from_config`
    builds the service's."""

    def __init__(self, *, filter: Filter, associator: LabelledAssociator,
                 scan_associator: ScanAssociator, initiator: Initiator, deleter: Deleter,
                 life: Life, display: Display, noise: NoiseMonitor,
                 plot_speed: float = defaults.MAX_SPEED / 3) -> None:
        """`filter`: the updater and its conversion (`estimation.catalog`); `plot_speed`:
        the velocity prior's std of a new track of unlabelled scans (m/s per axis)."""
        self.filter = filter
        self.updater: Updater = filter.updater
        self.conversion = filter.conversion
        self.associator: LabelledAssociator = associator
        self.scan_associator: ScanAssociator = scan_associator
        self.initiator: Initiator = initiator
        self.deleter: Deleter = deleter
        self.life: Life = life
        self.display: Display = display
        self.noise: NoiseMonitor = noise  # each sensor's stated noise against its measurements
        self.plot_speed = plot_speed
        self.store = TrackStore(self.updater.order, self.updater.fields,
                                {**LIFE_COLUMNS, **DISPLAY_COLUMNS, **associator.columns})
        self.numbers = TrackNumbers()

    @classmethod
    def from_config(cls, config: TrackerConfig | None = None, **parts: object) -> Tracker:
        """The service's tracker of `config` (every default from `zenoh_track.defaults`);
        `parts`: any of the constructor's arguments instead of the one built."""
        c = config or TrackerConfig()
        built = parts.get("filter") or c.filter.build()
        reach = Reach(c.max_speed, c.max_accel)
        stitch = c.max_accel if c.stitch_reach is None else c.stitch_reach
        made = dict(
            filter=built, associator=LabelAssociator(),
            initiator=SinglePointInitiator(c.init_speed, c.init_accel),
            deleter=CompositeDeleter(
                UpdateTimeDeleter(c.delete_after),
                MofNDeleter(c.confirm_m, c.confirm_n, c.delete_misses, c.delete_sigma)),
            life=MofNLife(c.confirm_m, c.confirm_n, c.confirm_score,
                          Stitcher(Reach(c.max_speed, stitch)) if stitch > 0 else None),
            display=DisplayState(c.display, built.q), noise=NoiseCheck(),
            plot_speed=c.max_speed / 3)
        if "scan_associator" not in parts:
            made["scan_associator"] = SCAN_ASSOCIATORS[c.associator](
                built.q, c.sensors, c.gate_probability, predict=built.updater.gate_prediction,
                stages=stages(c.associator, reach, c.second_look))
        return cls(**{**made, **parts})  # type: ignore[arg-type]

    def __len__(self) -> int:
        return len(self.store)

    def __contains__(self, track_id: str) -> bool:
        return track_id in self.store

    def ids(self) -> list[str]:
        """Every track's id."""
        return list(self.store.where)

    def step(self, scan: StepInput, want: Want | None = all_states,
             pause: Callable[[StepOutcome], None] | None = None) -> StepOutcome:
        """Apply one input: each part of it (`Associator.split`) associated, its tracks
        updated, the tracks in view counted as detected or missed, the stale tracks
        deleted at its time and new tracks started; an `Instant` only deletes.
        `want`: which of the tracks updated or started (given their ids) to return the
        states of (None: none). `pause`: called between parts of `PART` rows of an
        update with the outcome so far (a realtime service puts the states of the part
        done and a due frame there; a row's update does not depend on the others, so the
        parts give the same result)."""
        out = StepOutcome()
        if isinstance(scan, Instant):
            out.deleted += self.delete(scan.t)
            return out
        for index, part, hyp in self._associated(scan):
            bad = hyp.rejected
            self._update(hyp, part, bad, out, want, pause)
            for weighted in hyp.weighted:
                good, x, p = self._update_weighted(weighted, part.t)
                good, x, p = self._settle(part, weighted.arrays, good, x, p)
                out.keep(self._block(weighted.arrays, good, x, p), weighted.arrays.ids, good,
                         want)
            self.count_detections(hyp, out)
            out.deleted += self.delete(part.t)
            if hyp.unassociated:
                self._initiate(hyp, part, bad, out, want)
            out.rejected += [(index[i], reason) for i, reason in bad.items()]
            out.accepted += len(index) - len(bad)
        out.rejected.sort()
        return out

    # ------------------------------------------------------------ the stages
    def _associated(self, scan: Labelled | Unlabelled
                    ) -> Iterator[tuple[list[int], Labelled | Detections, Hypotheses]]:
        """Each part of a scan with its hypotheses, associated when its turn comes (after
        the parts before it changed the store)."""
        if isinstance(scan, Labelled):
            for index, part in self.associator.split(scan):
                yield index, part, self.associator.associate(self.store, part)
        else:
            for index, det in self.scan_associator.split(scan):
                hyp = self.scan_associator.associate(self.store, det)
                for arrays, rows in hyp.moved:  # put back behind the display's back
                    self.display.forget(arrays, rows)
                yield index, det, hyp

    def _update(self, hyp: Hypotheses, part_of: Labelled | Detections, bad: dict[int, str],
                out: StepOutcome, want: Want | None,
                pause: Callable[[StepOutcome], None] | None) -> None:
        """Predict and update the tracks associated, in store order, in parts of `PART`
        rows when paused between them; a non-finite result rejects its measurement."""
        batch = part_of.batch
        sensors = part_of.sensors if isinstance(part_of, Labelled) else part_of.sensor
        upd, rows = hyp.pairs()
        if not len(rows) or batch is None:
            return
        arrays = self.store.layout(hyp.dim)
        order = np.argsort(rows, kind="stable")  # the rows in store order: a row's
        upd, rows = upd[order], rows[order]  # result does not depend on the others
        cut = len(rows) if pause is None else PART * blocks.cores()
        for lo in range(0, len(rows), cut):
            if lo:
                pause(out)  # type: ignore[misc]
            part = upd[lo:lo + cut]
            good, ok, _, x, p = self._update_rows(
                arrays, rows[lo:lo + cut], batch.take(part),
                sensors if isinstance(sensors, str) else [sensors[i] for i in part])
            for j in np.flatnonzero(~ok).tolist():
                bad[int(part[j])] = NON_FINITE
            good, x, p = self._settle(part_of, arrays, good, x, p)
            out.keep(self._block(arrays, good, x, p), arrays.ids, good, want)

    def _settle(self, part: Labelled | Detections, arrays: TrackArrays, good: np.ndarray,
                x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rows an unlabelled part just updated less those whose update its associator
        keeps aside (`ScanAssociator.settle`: back on their branch before the update, drawn
        afresh), with their states."""
        if isinstance(part, Labelled):
            return good, x, p
        doubt = self.scan_associator.settle(arrays, good)
        if not doubt.any():
            return good, x, p
        self.display.forget(arrays, good[doubt])
        return good[~doubt], x[~doubt], p[~doubt]

    def update(self, arrays: TrackArrays, rows: np.ndarray, batch: MeasurementBatch,
               sensors: str | list[str] = "") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Predict and update `rows` of `arrays` with `batch` (row i with measurement i,
        of `sensors`: one for all, or one each): the rows updated (those whose result is
        finite), the mask of them and every NIS."""
        return self._update_rows(arrays, rows, batch, sensors)[:3]

    def _update_rows(self, arrays: TrackArrays, rows: np.ndarray, batch: MeasurementBatch,
                     sensors: str | list[str] = "") -> tuple[np.ndarray, ...]:
        """`update`, and the new states and covariances of the rows updated."""
        # the sensors whose stated noise is far too small: their measured noise, and once
        # in their tracks' covariances (`noise_check.NoiseCheck.adjust`)
        stated, (batch, grow, dp) = batch, self.noise.adjust(
            sensors, batch, rows, batch.t - arrays.t[rows], self.updater.order, arrays.ids,
            arrays.updates[rows])
        if len(grow):
            arrays.p[rows[grow]] += dp
            self.updater.inflate(arrays, rows[grow], dp)
        t = batch.t
        xn, pn, nis, ok = self.updater.update(arrays, rows, t - arrays.t[rows],
                                              self.conversion(batch))
        self.noise.observe(sensors, arrays.ids, rows, stated, nis, ok)
        every = np.count_nonzero(ok) == len(ok)
        good = rows if every else rows[ok]
        if not every:
            xn, pn, nis_ok, t = xn[ok], pn[ok], nis[ok], t[ok]
        else:
            nis_ok = nis
        self.display.update(arrays, good, t, xn, pn)
        arrays.x[good], arrays.p[good], arrays.nis[good] = xn, pn, nis_ok
        arrays.t[good] = t
        arrays.updates[good] += 1
        return good, ok, nis, xn, pn

    def _update_weighted(self, w: WeightedUpdate, t: float
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Update tracks each with the equivalent measurement of its weighted detections
        (JPDA), then add the spread of those detections to their covariances; the rows
        updated, their new states and covariances."""
        arrays, rows = w.arrays, w.rows
        times = np.full(len(rows), t)
        by_pda = self.updater.update_pda(arrays, rows, times - arrays.t[rows], w)
        if by_pda is not None:  # the filter's own (an IMM: mode by mode)
            xn, pn, nis, ok = by_pda
        else:
            xn, pn, nis, ok = self.updater.update(arrays, rows, times - arrays.t[rows],
                                                  EquivalentConversion(w.z, w.r, w.mass))
            pn = pn + w.spread
            self.updater.inflate(arrays, rows[ok], w.spread[ok])
        good, xn, pn = rows[ok], xn[ok], pn[ok]
        self.display.update(arrays, good, times[ok], xn, pn)
        arrays.x[good], arrays.p[good], arrays.nis[good] = xn, pn, nis[ok]
        arrays.t[good] = t
        arrays.updates[good] += 1
        return good, xn, pn

    def count_detections(self, hyp: Hypotheses, out: StepOutcome) -> None:
        """The unlabelled tracks in view count the scan as a detection or a miss (M of
        N, the track score); a track confirmed by it that continues a lost one takes
        the lost one's id (`Stitcher`: its new id is reported deleted in `out`, and its
        states there renamed). Tracks without a measurement keep their filtered state:
        the display predicts it to every instant, and labelled ones turn coasting with
        age."""
        joined = self.life.count(self.store, hyp.seen)
        if joined:
            out.renamed(joined)

    def delete(self, now: float) -> list[str]:
        """Remove the tracks the deleter picks at time `now`; their ids."""
        return self.remove(self.deleter.delete_tracks(self.store, now))

    def drop_newer(self, t: float) -> list[str]:
        """Remove the tracks updated after time t (a timeline abandoned for an earlier
        one: they would never age out); their ids."""
        ids: list[str] = []
        for arrays in self.store.layouts.values():
            rows, names = arrays.live()
            ids += [names[i] for i in np.flatnonzero(arrays.t[rows] > t + TIME_TOL).tolist()]
        return self.remove(ids)

    def remove(self, ids: list[str]) -> list[str]:
        self.store.remove(ids)
        self.associator.forget(ids)
        return ids

    def _initiate(self, hyp: Hypotheses, part: Labelled | Detections, bad: dict[int, str],
                  out: StepOutcome, want: Want | None) -> None:
        """Start a track from each unassociated measurement of a part: named by its
        label, or, unlabelled, `<sensor>-<n>` (`TrackNumbers`)."""
        new, batch = hyp.unassociated, part.batch
        assert batch is not None  # a part with measurements
        if isinstance(part, Labelled):
            ids, speed = [part.ids[i] for i in new], None
            batch = batch if len(new) == len(part) else batch.take(new)
        else:
            ids, speed = self.numbers.new(part.sensor, len(new)), self.plot_speed
            batch = batch.take(new)
        arrays, rows, reasons, x, p = self._start(hyp.dim, batch, ids, speed)
        for i, reason in zip(new, reasons, strict=True):
            if reason is not None:
                bad[i] = reason
        out.keep(self._block(arrays, rows, x, p), arrays.ids, rows, want)

    def initiate(self, dim: int, batch: MeasurementBatch, ids: Sequence[str],
                 speed: float | None = None) -> tuple[TrackArrays, np.ndarray,
                                                      list[str | None]]:
        """New tracks named `ids`, one per measurement of `batch` (`speed`: the velocity
        prior's std, given for unlabelled tracks, which are tentative until confirmed M
        of N): the layout, the rows started and each measurement's reason for starting
        none (None: started)."""
        return self._start(dim, batch, ids, speed)[:3]

    def _start(self, dim: int, batch: MeasurementBatch, ids: Sequence[str],
               speed: float | None) -> tuple:
        """`initiate`, and the new tracks' states and covariances."""
        arrays, rows, reasons = self.initiator.initiate(self.store, dim, batch, ids, speed)
        if speed is not None:
            self.life.start(arrays, rows)
        self.updater.initiate(arrays, rows)
        x, p = arrays.x[rows], arrays.p[rows]
        self.display.initiate(arrays, rows, x, p)
        return arrays, rows, reasons, x, p

    # ------------------------------------------------------------ checkpoints
    def memory(self) -> dict[str, dict]:
        """What the tracker keeps beside the store: the track numbers given per sensor
        and the sensor of each labelled track's last update (JSON-serialisable)."""
        return {"numbers": dict(self.numbers.last), "last": self.associator.memory(self.store)}

    def restore(self, dim: int, ids: list[str], columns: Mapping[str, np.ndarray]) -> None:
        """Tracks of one layout back from a checkpoint: their ids and every per-row
        column of them."""
        arrays, rows = self.store.add_many(ids, dim)
        for name, values in columns.items():
            getattr(arrays, name)[rows] = values
        restore_lost(arrays, rows)
        self.display.initiate(arrays, rows)

    def recall(self, memory: Mapping[str, Mapping]) -> None:
        """Take back what `memory` gave (after `restore`: the last sensors of tracks not
        restored are dropped)."""
        self.numbers.last.update(memory.get("numbers", {}))
        self.associator.remember(self.store, memory.get("last", {}))

    # ------------------------------------------------------------ queries
    def counts(self) -> dict[str, int]:
        """What the association's stages and the track life did since start (`status`):
        every count present, zero where a part is left out."""
        return {"deferred": 0, "reverted": 0, "chances": 0, "retaken": 0, "continued": 0,
                **self.scan_associator.counts(), **self.life.counts()}

    def states(self, arrays: TrackArrays, rows: Sequence[int] | np.ndarray) -> States:
        """The filtered states of rows of one layout, as columns."""
        r = np.asarray(rows, dtype=int)
        return self.store.states(arrays, r, self.updater.labels(arrays, r))

    def _block(self, arrays: TrackArrays, rows: np.ndarray, x: np.ndarray, p: np.ndarray
               ) -> Callable[[np.ndarray | None], States]:
        """How to make the states of rows[pick] (None: all) of a layout, from their new
        states x and covariances p (not gathered from the store again)."""
        def make(pick: np.ndarray | None) -> States:
            r, xs, ps = (rows, x, p) if pick is None else (rows[pick], x[pick], p[pick])
            return self.store.states(arrays, r, self.updater.labels(arrays, r), xs, ps)
        return make

    def state(self, track_id: str) -> dict:
        """The filtered state of one track (the `tracks/<id>` message body)."""
        arrays, row = self.store.where[track_id]
        return self.states(arrays, [row]).body(0)

    def snapshot(self, t: float, detail: bool = True) -> Snapshot:
        """Every track as the display shows it at instant t (`display.DisplayState`)."""
        return self.display.snapshot(self.store, t, detail)
