"""The worker: one thread takes each batch of inputs (`ingest`), in order, through the
stages: decode -> admit (time policy, reordering, seq gaps, the clock's frames) -> the
tracker -> publish. It owns the tracker, which needs no locks.

Admission makes each input an ordered plan (`plan.Plan`: rejections, labelled rows that
wait, frames, scans, answers); one loop carries it out (`_carry_out`), applying the rows
waiting in one pass over their columns before any step that must see them. The clock
(`clocks.Lockstep` or `clocks.Realtime`) says what each point of a step adds to the plan.
Every call into the tracker is a method of `TrackerCalls`.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
import threading
import time
from typing import Any

import numpy as np
import zenoh

from .. import defaults
from ..estimation.measurements import MeasurementBatch
from ..tracking.batches import Labelled, StepOutcome
from ..tracking.tracker import Tracker
from ..wire import Keys, Origin, PlotScan
from .admit import Admit
from .clocks import make_clock
from .decode import Decoder
from .ingest import ClockMessage, Ingest, Input, LabelledScan, Plots, Query, Singles
from .plan import SEES_ROWS, Answer, Apply, ApplyScan, Do, Frame, Plan, Refusals, Reject, Wait
from .publish import Publisher
from .queries import Queries
from .schedule import DRAIN, IDLE_AFTER, IDLE_POLL, POLL, Frames
from .state import StateFile
from .steps import TrackerCalls

log = logging.getLogger("track-service")
# s between two gc.freeze() of the worker (when nothing waits): the long-lived objects
# (the tracks' ids and keys, caches) leave the cyclic collector's generations, so its full
# collections scan only what is newer (a full collection over every track's objects would
# hold a frame up). Objects are still freed by reference counting; only cycles of frozen
# objects would never be (the service makes none that outlive a step).
FREEZE_EVERY = 5.0


def _malloc_trim() -> Any:
    """glibc's `malloc_trim` (None elsewhere): the tracks/ sender and Zenoh's threads
    allocate and free in arenas of their own, which glibc does not give back to the system
    by itself; trimmed with the freeze, the RSS stays flat (docs/performance.md). The
    service program sets the arenas up first (`zenoh_track.malloc`)."""
    try:
        trim = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


TRIM = _malloc_trim()


class TrackService:
    """One tracker instance on one Zenoh session."""

    def __init__(self, session: zenoh.Session, keys: Keys, tracker: Tracker, *,
                 clock: str = defaults.CLOCK, instance: str = "0",
                 noise: tuple[float, float, float, float] = defaults.NOISE,
                 per_target_display: bool = True, meas_keys: list[str] | None = None,
                 plot_keys: list[str] | None = None, scan_keys: list[str] | None = None,
                 reorder: float = defaults.REORDER,
                 max_jump: float = defaults.MAX_JUMP, state: str | None = None,
                 state_period: float = defaults.STATE_PERIOD,
                 origin: Origin | None = None) -> None:
        """`state`: the `--state` file's path (None: no checkpoints), written every
        `state_period` s; `origin`: the deployment's geodetic frame, as `status` says it."""
        self.session, self.keys, self.tracker = session, keys, tracker
        self.calls = TrackerCalls(tracker)
        display = tracker.display.config
        self.clock = make_clock(clock, display.rate, display.lag)
        self.out = Publisher(session, keys, self.clock.publishing, per_target_display,
                             instance)
        self.count = self.out.count
        self.decode = Decoder(keys, noise)
        self.admit = Admit(self.clock, max_jump, reorder)
        self.pending: list[Labelled] = []  # labelled rows taken, not yet applied
        self.frames = Frames(self.calls, self.out)
        self.state = None if state is None else \
            StateFile(state, self.checkpoint, state_period)  # checkpoints
        self.stop = threading.Event()
        self.next_freeze = 0.0  # monotonic time of the worker's next gc.freeze()
        self.last_input = time.monotonic()  # when the worker last took an input
        self.ingest = Ingest(session, keys, meas_keys, plot_keys, scan_keys)
        self.queries = Queries(keys, self.calls, self.out, self.clock, self.admit,
                               self.ingest, instance, display.rate, origin)
        self.token = session.liveliness().declare_token(keys.alive(instance))
        self.thread = threading.Thread(target=self._run, name="track-worker", daemon=True)

    # ------------------------------------------------------------ lifecycle
    def start(self) -> TrackService:
        gc.set_threshold(*defaults.GC_THRESHOLDS)  # the process's: it runs this worker
        self.thread.start()
        return self

    def close(self) -> None:
        self.stop.set()
        self.ingest.wake()
        if self.thread.ident is not None:  # started
            self.thread.join(timeout=10)
        if self.state is not None and not self.thread.is_alive():
            self.state.final()  # the worker has stopped: the table is still
        self.token.undeclare()
        self.out.close()

    def status(self) -> dict[str, Any]:
        return self.queries.status()

    def checkpoint(self) -> Any:
        """The service's checkpoint (on the worker): the tracks, the clock, the last `seq`
        of each sensor."""
        return self.calls.capture({"clock": {**self.clock.save(),
                                                "picture_t": self.admit.newest},
                                      "last_seq": self.admit.last_seq,
                                      "wall": time.time(), "ns": self.keys.ns})

    def restore(self, data: bytes) -> tuple[int, float, str]:
        """A checkpoint read back (before the worker starts): the tracks restored, the
        checkpoint's age (s) and a note on the clock. Raises `checkpoint.CheckpointError`
        (nothing changed) for data that is not a checkpoint this service can take."""
        extra = self.calls.load(data).get("extra", {})
        clock = extra.get("clock")
        note = self.clock.load(clock, time.time()) if isinstance(clock, dict) else ""
        picture = clock.get("picture_t") if isinstance(clock, dict) else None
        if note and isinstance(picture, int | float):  # where the picture was
            self.admit.newest = float(picture)
        seq = extra.get("last_seq", {})
        if isinstance(seq, dict):
            self.admit.last_seq.update({k: v for k, v in seq.items()
                                        if isinstance(k, str) and isinstance(v, int)})
        return len(self.calls), time.time() - extra.get("wall", time.time()), note

    def _run(self) -> None:
        while not self.stop.is_set():
            # the channels looked in every POLL s, less often when no input came for long
            # (an idle service costs next to nothing)
            poll = POLL if time.monotonic() - self.last_input < IDLE_AFTER else IDLE_POLL
            batch = self.ingest.next_batch(self.clock.timeout(time.time(), poll))
            if batch:
                self.last_input = time.monotonic()
            try:
                self._process(batch)
                if batch:  # the states handed over go out before more input is taken
                    self._drain()
                if self.state is not None:
                    self.state.tick()
                if time.monotonic() >= self.next_freeze and self.ingest.idle():
                    gc.freeze()
                    if TRIM is not None:
                        TRIM(0)
                    self.next_freeze = time.monotonic() + FREEZE_EVERY
            except Exception:  # keep serving: one bad batch must not stop the service
                log.exception("worker failed on a batch of %d inputs", len(batch))

    def _drain(self) -> None:
        """Wait for the states handed over to go out (the sender's puts then hold the GIL
        uncontended) while the sender keeps putting them, up to `DRAIN` s: a frame that
        falls due meanwhile is published at its instant, and the wait ends there if nothing
        was put since the last (a slow subscriber holds the sender up: the input goes on)."""
        end = time.time() + DRAIN
        left = self.out.unsent()
        while not self.out.drain(self.clock.timeout(now := time.time(), end - now)):
            self._process([])  # a frame due: published at its instant
            unsent = self.out.unsent()
            if unsent >= left or time.time() >= end:
                return  # nothing put since the last look (held up), or DRAIN is over
            left = unsent

    # ------------------------------------------------------------ take
    def _process(self, batch: list[Input]) -> None:
        """One step: a batch of inputs taken in order (each run of single measurements
        together, anything else alone, each planned then carried out), then the step's
        end as the clock has it (`Clock.end`: the rows waiting applied, ...)."""
        if batch:
            self.out.look()  # who listens to display/ and tracks/ (cheap unless due)
        i = 0
        while i < len(batch):
            item, j = batch[i], i + 1
            if type(item) is Singles:
                while j < len(batch) and type(batch[j]) is Singles:
                    j += 1
            plan = self._plan()
            try:
                if type(item) is Singles:
                    self._take_singles(plan, Singles.joined(batch[i:j]))  # type: ignore[arg-type]
                else:
                    self._take(plan, item)
            except Exception as exc:  # a fault of ours: report it, keep the batch going
                self._internal(item, exc, plan)
            else:
                try:
                    self._carry_out(plan)
                except Exception as exc:
                    self._internal(item, exc, None)
            i = j
        plan = self._plan()
        self.clock.end(plan, time.time(), self.admit, self.frames)
        self._carry_out(plan)

    def _internal(self, item: Input, exc: Exception, plan: Plan | None) -> None:
        """An input the service failed on (a bug, never a bad input): logged with its
        traceback, what was planned before the fault carried out (`plan`, if planning
        failed), reported on errors/ (code `internal`), counted; the rows waiting are
        applied (or, if they failed, dropped and reported), a query answered."""
        log.exception("worker failed on a %s input", type(item).__name__)
        if plan is not None:
            try:
                self._carry_out(plan)
            except Exception:
                log.exception("the plan before the fault left undone")
        self.count.internal_errors += 1
        self.out.reject(item.key, "unknown", f"internal error: {type(exc).__name__}: {exc}")
        try:
            self._apply_rows()
        except Exception:
            log.exception("dropping %d measurements", len(self.pending))
            self.pending.clear()
        if isinstance(item, Query):
            try:
                self.queries.answer(item)
            except Exception:
                log.exception("query left unanswered")

    def _plan(self) -> Plan:
        """An empty plan, the rows already waiting counted."""
        return Plan(sum(map(len, self.pending)))

    def _take(self, plan: Plan, item: Input) -> None:
        """One input other than a single measurement."""
        if isinstance(item, LabelledScan):
            self._take_labelled(plan, item)
        elif isinstance(item, Plots):
            plan.apply()  # the labelled ones received before it go first
            self._take_plots(plan, item)
        elif isinstance(item, ClockMessage):
            self._take_clock(plan, item)
        elif isinstance(item, Query):
            plan.answer(item)

    def _take_singles(self, plan: Plan, run: Singles) -> None:
        """Single measurements taken together, in order, as each alone would be: read as
        columns (`decode`), a bad one reported on its own key in message order, their `seq`
        gaps counted, the time policy and the clock applied, the good ones left waiting."""
        got = self.decode.singles(run)
        fine, keys, sensors, walls = got.fine, got.keys, got.sensors, got.walls
        bad = Refusals(got.bad, fine, plan)
        self.count.meas_lost += self.admit.lost(sensors, got.seqs)
        for index, cols in got.parts:
            if len(index) == len(sensors):  # all of them (the usual case)
                rows = Labelled(sensors, cols.ids, MeasurementBatch.of_scan(cols))
                at, near = keys, walls
            else:
                rows = Labelled([sensors[i] for i in index], cols.ids,
                                MeasurementBatch.of_scan(cols))
                at, near = [keys[i] for i in index], [walls[i] for i in index]
            if self.admit.near(rows.batch.t, near):  # one admission for all: the same outcome
                bad.before(index[-1])
                self._admit(plan, float(rows.batch.t.max()), near[-1], at[-1], rows.sensors[-1])
                self.clock.rows(plan, rows, near, self.admit.held())
                continue
            for i, x in enumerate(rows.batch.t.tolist()):  # else each in turn, as alone:
                bad.before(index[i])  # carried out before the next is admitted
                if self._admit(plan, x, near[i], at[i], rows.sensors[i]):
                    self.clock.rows(plan, rows.rows(i, i + 1), near[i:i + 1], self.admit.held())
                self._carry_out(plan)
        bad.before(len(fine))

    def _take_labelled(self, plan: Plan, item: LabelledScan) -> None:
        """A batched labelled scan (`scan/<sensor>`): its rows mean what single messages
        would (each bad row reported alone, the time policy per row's time) and wait with
        them."""
        sensor, scan, reason = self.decode.scan(item)
        if scan is None:
            plan.reject(item.key, sensor, reason)  # type: ignore[arg-type]
            return
        for _, why in scan.rejected:
            plan.reject(item.key, sensor, why)
        if not scan.good:
            return
        batch = MeasurementBatch.of_scan(scan)
        ids = scan.ids
        keep = self._admit_rows(plan, batch.t, item.wall, item.key, sensor)
        if keep is not None:
            if not keep.any():
                return
            batch = batch.take(np.flatnonzero(keep))
            ids = [i for i, k in zip(ids, keep.tolist(), strict=True) if k]
        self.clock.rows(plan, Labelled([sensor] * len(ids), ids, batch), [item.wall] * len(ids),
                        self.admit.held())

    def _take_plots(self, plan: Plan, item: Plots) -> None:
        """An unlabelled scan: checked, its bad detections reported, held back in the
        reorder buffer; the scans it releases applied."""
        sensor, scan, reason = self.decode.plots(item)
        if scan is None:
            plan.reject(item.key, sensor, reason)  # type: ignore[arg-type]
            return
        if not self._admit(plan, scan.t, item.wall, item.key, sensor):
            return  # far from the picture's time (before `late`: the worse fault)
        late = self.admit.late(scan.t, sensor)
        if late:
            plan.reject(item.key, sensor, late)
            return
        for _, why in scan.rejected:
            plan.reject(item.key, sensor, why)
        released = self.admit.hold(sensor, scan.t, (item.key, scan))
        self.clock.scan(plan, scan.t, item.wall, released, self.admit.held())

    def _take_clock(self, plan: Plan, item: ClockMessage) -> None:
        """A clock message: nothing older will come (the scans held go); the frames its
        time makes due show the measurements received before it."""
        t, reason = self.decode.clock(item)
        if t is None:
            plan.reject(item.key, "clock", reason)  # type: ignore[arg-type]
            return
        if not self._admit(plan, t, item.wall, item.key, "clock"):
            return
        if len(self.admit):
            plan.apply()
            released = self.admit.release(t, flush=True)
            self.clock.released(plan, released, self.admit.held())
        self.clock.clock_message(plan, t, item.wall, self.admit.held())

    # ------------------------------------------------------------ admit
    def _admit(self, plan: Plan, t: float, wall: float, key: str, sensor: str) -> bool:
        """The time policy for an input of time t received at `wall`: False when it was
        refused (and reported)."""
        # rows waiting or planned count as tracks: they are about to be applied
        held = len(self.calls) or len(self.pending) or plan.planned
        reason, jump, now = self.admit.time(t, wall, held)
        if reason is not None:
            plan.reject(key, sensor, reason)
            return False
        if jump:
            self._new_timeline(plan, t, now)
        self.admit.taken(t)
        return True

    def _admit_rows(self, plan: Plan, t: np.ndarray, wall: float, key: str, sensor: str
                    ) -> np.ndarray | None:
        """The time policy for the rows of a batched scan, times t: None when every row
        is taken (all within --max-jump of the picture's time: one admission for all),
        else the mask of the rows taken (the policy once per distinct time, in time
        order, as single messages; a refusal reported once per time, every row counted)."""
        if self.admit.all_near(t, wall):
            self._admit(plan, float(t.max()), wall, key, sensor)  # the picture moves there
            return None
        times = np.unique(t)
        refused = [x for x in times.tolist() if not self._admit(plan, x, wall, key, sensor)]
        if not refused:
            return None
        keep = ~np.isin(t, refused)
        extra = int((~keep).sum()) - len(refused)
        self.count.meas_rejected += extra
        by = self.count.by_reason  # counted by code like the one reported
        by["time_far"] = by.get("time_far", 0) + extra
        return keep

    def _new_timeline(self, plan: Plan, t: float, now: float | None) -> None:
        """Move the picture to time t, carried out at once (what follows is admitted
        against it): the old timeline's inputs go first, the clock starts afresh (no
        frames for the gap); forward, the tracks stale at t are deleted, backward, the
        tracks of the abandoned later timeline (they would never age out)."""
        plan.apply()
        self.clock.released(plan, self.admit.release_all(), self.admit.held())
        self.admit.restart(t)
        plan.do(self._timeline_deleted, t, now)
        self._carry_out(plan)

    def _timeline_deleted(self, t: float, now: float | None) -> None:
        if now is not None and t < now:
            self.out.deleted(self.calls.drop_newer(t))
        else:  # the tracks stale at the new time go before its first input
            self.out.deleted(self.calls.delete(t))

    # ------------------------------------------------------------ carry out
    def _carry_out(self, plan: Plan) -> None:
        """The plan's steps in order; the rows waiting applied before a step that sees
        them."""
        for step in plan:
            if isinstance(step, SEES_ROWS):
                self._apply_rows()
            kind = type(step)
            if kind is Reject:
                self.out.reject(step.key, step.sensor, step.reason)  # type: ignore[union-attr]
            elif kind is Wait:
                self.pending.append(step.rows)  # type: ignore[union-attr]
            elif kind is Frame:
                self.frames.publish(step.t)  # type: ignore[union-attr]
            elif kind is ApplyScan:
                self._apply_scan(step.key, step.scan)  # type: ignore[union-attr]
            elif kind is Answer:
                self.queries.answer(step.query)  # type: ignore[union-attr]
            elif kind is Do:
                step.run(*step.args)  # type: ignore[union-attr]
            else:
                assert kind is Apply
        plan.carried_out(sum(map(len, self.pending)))

    def _apply_rows(self) -> None:
        """Apply the rows waiting, in order, in one pass over their columns per dimension
        (the clock's frames around it: `Clock.apply`)."""
        pending = self.pending
        if not pending:
            return
        want = self.out.wanted if self.out.wants_states else None

        def run(rows: Labelled, pause: Any) -> StepOutcome:
            outcome = self.calls.rows(rows, want, pause)
            self.out.deleted(outcome.deleted)
            return outcome

        def report(rows: Labelled, outcome: StepOutcome) -> None:
            self.out.batch(rows.sensors, rows.ids, outcome)

        for rows in Labelled.joined(pending):
            self.clock.apply(rows, self.frames, run, report)
        pending.clear()
        self.out.noise(self.calls.noise)  # a sensor whose stated noise is far off

    def _apply_scan(self, key: str, scan: PlotScan) -> None:
        outcome = self.calls.scan(scan)
        self.out.deleted(outcome.deleted)
        self.count.scans_applied += 1
        self.out.scan(key, scan.sensor, outcome)
        self.out.noise(self.calls.noise)

