"""The worker: one thread takes each batch of inputs (`ingest`), in order, through the
stages: decode -> admit (time policy, reordering, seq gaps) -> the tracker -> schedule
(the display clock's instants) -> publish. It owns the tracker, which needs no locks.

Labelled measurements taken wait in `pending` as `Rows` and are applied together, in one
pass over their columns (`_flush`), before anything that must see them (a frame, an
unlabelled scan, a query, a new timeline) and at the end of the batch; a lockstep frame
due between two of them goes out between them. Every call into the tracker is a method
of `Tracking`.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
import math
import threading
import time
from typing import Any

import numpy as np
import zenoh

from .. import defaults
from ..estimation.measurements import MeasurementBatch
from ..tracking.batches import Labelled as Rows
from ..tracking.batches import StepOutcome as BatchOutcome
from ..tracking.tracker import Tracker
from ..wire import Keys, PlotScan
from .admit import Admit
from .decode import Decoder
from .ingest import ClockMessage, Ingest, Input, Plots, Query, Scan, Singles
from .publish import Publisher
from .queries import Queries
from .schedule import Frames, make_clock
from .state import StateFile
from .steps import Tracking

log = logging.getLogger("track-service")
POLL = 0.001  # s: an idle worker looks in the measurement channels this often
# s between two gc.freeze() of the worker (when nothing waits): the long-lived objects
# (the tracks' ids and keys, caches) leave the cyclic collector's generations, so its full
# collections scan only what is newer (a full collection over every track's objects would
# hold a frame up). Objects are still freed by reference counting; only cycles of frozen
# objects would never be (the service makes none that outlive a step).
FREEZE_EVERY = 5.0


def _malloc_trim() -> Any:
    """glibc's `malloc_trim` (None elsewhere). The tracks/ sender and Zenoh's threads
    allocate and free in arenas of their own, which glibc does not give back to the system
    by itself: the service's RSS crept up by ~1 MB a minute at 10,000 targets with a
    `tracks/**` subscriber; trimmed with the freeze, it stayed within 301-318 MB over 10
    minutes (docs/performance.md, issue 26)."""
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
                 state_period: float = defaults.STATE_PERIOD) -> None:
        """`state`: the `--state` file's path (None: no checkpoints), written every
        `state_period` s."""
        self.session, self.keys, self.tracker = session, keys, tracker
        self.tracking = Tracking(tracker)
        display = tracker.display.config
        self.clock = make_clock(clock, display.rate, display.lag)
        self.out = Publisher(session, keys, self.clock.anytime, per_target_display)
        self.count = self.out.count
        self.decode = Decoder(keys, noise)
        self.admit = Admit(self.clock, max_jump, reorder)
        self.pending: list[Rows] = []  # labelled rows taken, not yet applied
        self.frames = Frames(self.clock, self.tracking, self.out)
        self.state = None if state is None else \
            StateFile(state, self.checkpoint, state_period)  # checkpoints
        self.stop = threading.Event()
        self.next_freeze = 0.0  # monotonic time of the worker's next gc.freeze()
        self.ingest = Ingest(session, keys, meas_keys, plot_keys, scan_keys)
        self.queries = Queries(keys, self.tracking, self.out, self.clock, self.admit,
                               self.ingest, instance, display.rate)
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
        return self.tracking.capture({"clock": self.clock.save(),
                                      "last_seq": self.admit.last_seq,
                                      "wall": time.time(), "ns": self.keys.ns})

    def restore(self, data: bytes) -> tuple[int, float, str]:
        """A checkpoint read back (before the worker starts): the tracks restored, the
        checkpoint's age (s) and a note on the clock. Raises `checkpoint.CheckpointError`
        (nothing changed) for data that is not a checkpoint this service can take."""
        extra = self.tracking.load(data).get("extra", {})
        clock = extra.get("clock")
        note = self.clock.load(clock, time.time()) if isinstance(clock, dict) else ""
        seq = extra.get("last_seq", {})
        if isinstance(seq, dict):
            self.admit.last_seq.update({k: v for k, v in seq.items()
                                        if isinstance(k, str) and isinstance(v, int)})
        return len(self.tracking), time.time() - extra.get("wall", time.time()), note

    def _run(self) -> None:
        while not self.stop.is_set():
            timeout = POLL
            deadline = self.clock.next_deadline(time.time())
            if deadline is not None:
                timeout = min(max(deadline - time.time(), 0.0), POLL)
            batch = self.ingest.next_batch(timeout)
            try:
                self._process(batch)
                self._tick()
                if self.state is not None:
                    self.state.tick()
                if time.monotonic() >= self.next_freeze and self.ingest.idle():
                    gc.freeze()
                    if TRIM is not None:
                        TRIM(0)
                    self.next_freeze = time.monotonic() + FREEZE_EVERY
            except Exception:  # keep serving: one bad batch must not stop the service
                log.exception("worker failed on a batch of %d inputs", len(batch))

    # ------------------------------------------------------------ take
    def _process(self, batch: list[Input]) -> None:
        """Take a batch of inputs in order: each run of single measurements together,
        anything else alone; the rows waiting are applied before anything that must see
        them (and at the end)."""
        if batch:
            self.out.look()  # who listens to display/ and tracks/ (cheap unless due)
        i = 0
        while i < len(batch):
            item, j = batch[i], i + 1
            if type(item) is Singles:
                while j < len(batch) and type(batch[j]) is Singles:
                    j += 1
            try:
                if type(item) is Singles:
                    self._take_singles(Singles.joined(batch[i:j]))  # type: ignore[arg-type]
                else:
                    self._take(item)
            except Exception as exc:  # a fault of ours: report it, keep the batch going
                self._internal(item, exc)
            i = j
        self._flush()

    def _internal(self, item: Input, exc: Exception) -> None:
        """An input the service failed on (a bug, never a bad input): logged with its
        traceback, reported on errors/ (code `internal`), counted; the rows waiting are
        applied (or, if they failed, dropped and reported), a query answered."""
        log.exception("worker failed on a %s input", type(item).__name__)
        self.count.internal_errors += 1
        self.out.reject(item.key, "unknown", f"internal error: {type(exc).__name__}: {exc}")
        try:
            self._flush()
        except Exception:
            log.exception("dropping %d measurements", len(self.pending))
            self.pending.clear()
        if isinstance(item, Query):
            try:
                self.queries.answer(item)
            except Exception:
                log.exception("query left unanswered")

    def _take(self, item: Input) -> None:
        """One input other than a single measurement."""
        if isinstance(item, Scan):
            self._take_labelled(item)
        elif isinstance(item, Plots):
            self._flush()  # the labelled ones received before it go first
            self._take_plots(item)
        elif isinstance(item, ClockMessage):
            self._take_clock(item)
        elif isinstance(item, Query):
            self._flush()
            self.queries.answer(item)

    def _take_singles(self, run: Singles) -> None:
        """Single measurements taken together, in order, as each alone would be: read as
        columns (`decode`), a bad one reported on its own key in message order, their `seq`
        gaps counted, the time policy and the clock applied, the good ones left waiting."""
        got = self.decode.singles(run)
        fine, keys, sensors, walls = got.fine, got.keys, got.sensors, got.walls
        bad = iter(got.bad)
        later = next(bad, None)

        def reject_before(upto: float) -> None:  # message index upto (in `fine`) and after
            nonlocal later
            at = fine[int(upto)] if upto < len(fine) else math.inf
            while later is not None and later[0] < at:
                self.out.reject(*later[1:])
                later = next(bad, None)

        self.count.meas_lost += self.admit.lost(sensors, got.seqs)
        for index, cols in got.parts:
            if len(index) == len(sensors):  # all of them (the usual case)
                rows = Rows(sensors, cols.ids, MeasurementBatch.of_scan(cols))
                at, near = keys, walls
            else:
                rows = Rows([sensors[i] for i in index], cols.ids,
                            MeasurementBatch.of_scan(cols))
                at, near = [keys[i] for i in index], [walls[i] for i in index]
            if self.admit.near(rows.batch.t, near):  # one admission for all: the same outcome
                reject_before(index[-1])
                self._admit(float(rows.batch.t.max()), near[-1], at[-1], rows.sensors[-1])
                self._wait(rows, near)
                continue
            for i, x in enumerate(rows.batch.t.tolist()):  # else each in turn, as alone
                reject_before(index[i])
                if self._admit(x, near[i], at[i], rows.sensors[i]):
                    self._wait(rows.rows(i, i + 1), near[i:i + 1])
        reject_before(math.inf)

    def _take_labelled(self, item: Scan) -> None:
        """A batched labelled scan (`scan/<sensor>`): its rows mean what single messages
        would (each bad row reported alone, the time policy per row's time) and wait with
        them."""
        sensor, scan, reason = self.decode.scan(item)
        if scan is None:
            self.out.reject(item.key, sensor, reason)  # type: ignore[arg-type]
            return
        for _, why in scan.rejected:
            self.out.reject(item.key, sensor, why)
        if not scan.good:
            return
        batch = MeasurementBatch.of_scan(scan)
        ids = scan.ids
        keep = self._admit_rows(batch.t, item.wall, item.key, sensor)
        if keep is not None:
            if not keep.any():
                return
            batch = batch.take(np.flatnonzero(keep))
            ids = [i for i, k in zip(ids, keep.tolist(), strict=True) if k]
        self._wait(Rows([sensor] * len(ids), ids, batch), [item.wall] * len(ids))

    def _take_plots(self, item: Plots) -> None:
        """An unlabelled scan: checked, its bad detections reported, held back in the
        reorder buffer; the scans it releases applied."""
        sensor, scan, reason = self.decode.plots(item)
        if scan is None:
            self.out.reject(item.key, sensor, reason)  # type: ignore[arg-type]
            return
        if not self._admit(scan.t, item.wall, item.key, sensor):
            return  # far from the picture's time (before `late`: the worse fault)
        late = self.admit.late(scan.t, sensor)
        if late:
            self.out.reject(item.key, sensor, late)
            return
        for _, why in scan.rejected:
            self.out.reject(item.key, sensor, why)
        self.clock.observe(scan.t, item.wall)
        self._apply_scans(self.admit.hold(sensor, scan.t, (item.key, scan)))

    def _take_clock(self, item: ClockMessage) -> None:
        """A clock message: nothing older will come (the scans held go); the frames its
        time makes due show the measurements received before it."""
        t, reason = self.decode.clock(item)
        if t is None:
            self.out.reject(item.key, "clock", reason)  # type: ignore[arg-type]
            return
        if not self._admit(t, item.wall, item.key, "clock"):
            return
        if len(self.admit):
            self._flush()
            self._apply_scans(self.admit.release(t, flush=True))
        if self.clock.anytime:  # a frame may fall due as soon as the clock learns t
            self._flush()
        self.clock.observe(t, item.wall)
        self._frames_before(t)

    # ------------------------------------------------------------ admit
    def _admit(self, t: float, wall: float, key: str, sensor: str) -> bool:
        """The time policy for an input of time t received at `wall`: False when it was
        refused (and reported)."""
        # rows waiting count as tracks: they are about to be applied
        reason, jump, now = self.admit.time(t, wall, len(self.tracking) or len(self.pending))
        if reason is not None:
            self.out.reject(key, sensor, reason)
            return False
        if jump:
            self._new_timeline(t, now)
        self.admit.taken(t)
        return True

    def _admit_rows(self, t: np.ndarray, wall: float, key: str, sensor: str
                    ) -> np.ndarray | None:
        """The time policy for the rows of a batched scan, times t: None when every row
        is taken (all within --max-jump of the picture's time: one admission for all),
        else the mask of the rows taken (the policy once per distinct time, in time
        order, as single messages; a refusal reported once per time, every row counted)."""
        if self.admit.all_near(t, wall):
            self._admit(float(t.max()), wall, key, sensor)  # taken: the picture moves there
            return None
        times = np.unique(t)
        refused = [x for x in times.tolist() if not self._admit(x, wall, key, sensor)]
        if not refused:
            return None
        keep = ~np.isin(t, refused)
        extra = int((~keep).sum()) - len(refused)
        self.count.meas_rejected += extra
        by = self.count.by_reason  # counted by code like the one reported
        by["time_far"] = by.get("time_far", 0) + extra
        return keep

    def _new_timeline(self, t: float, now: float | None) -> None:
        """Move the picture to time t: the old timeline's inputs go first, the clock starts
        afresh (no frames for the gap); forward, the tracks stale at t are deleted,
        backward, the tracks of the abandoned later timeline (they would never age out)."""
        self._flush()
        self._apply_scans(self.admit.release_all())
        self.clock.restart(t)
        if now is not None and t < now:
            self.out.deleted(self.tracking.drop_newer(t))
        else:  # the tracks stale at the new time go before its first input
            self.out.deleted(self.tracking.delete(t))

    def _wait(self, rows: Rows, walls: list[float]) -> None:
        """Taken rows wait in `pending`; the clock learns from them, and a frame due before
        one goes out before it (the rows cut where frames fall due)."""
        t = rows.batch.t
        if self.clock.anytime and self.pending and \
                sum(map(len, self.pending)) + len(t) > defaults.PASS_ROWS:
            self._flush()  # realtime: a pass at most this long, then the frame due, if any
        self.clock.observe_all(t, walls)
        self._frames_before(float(t[0]))
        start = 0
        while (i := self.clock.first_due(t, start + 1, self.admit.held())) is not None:
            self.pending.append(rows.rows(start, i))
            start = i
            self._frames_before(float(t[i]))
        self.pending.append(rows.rows(start, len(t)) if start else rows)

    # ------------------------------------------------------------ the tracker
    def _flush(self) -> None:
        """Apply the rows waiting, in order, in one pass over their columns (one pass per
        dimension when they mix 2-D and 3-D). A frame due on the wall clock goes out
        before the pass and after it, before the states (a step of a burst spends most
        of its time in the pass), and between parts of a long update."""
        pending = self.pending
        if not pending:
            return
        want = self.out.wanted if self.out.wants_states else None
        pause = self._between_parts if self.clock.anytime else None
        for rows in Rows.joined(pending):
            self.frames.between()
            outcome = self.tracking.rows(rows, want, pause)
            self.out.deleted(outcome.deleted)
            self.frames.between()
            self.out.batch(rows.sensors, rows.ids, outcome)
        pending.clear()
        self.out.noise(self.tracking.noise)  # a sensor whose stated noise is far off

    def _between_parts(self, outcome: BatchOutcome) -> None:
        """Between parts of an update: the states of the tracks updated so far go out,
        then the frame due, if any."""
        self.out.put_states(outcome.states)
        outcome.states.clear()
        self.frames.between()

    def _apply_scans(self, scans: list[tuple[str, PlotScan]]) -> None:
        for key, scan in scans:
            self._frames_before(scan.t)
            outcome = self.tracking.scan(scan)
            self.out.deleted(outcome.deleted)
            self.count.scans_applied += 1
            self.out.scan(key, scan.sensor, outcome)
            self.out.noise(self.tracking.noise)

    # ------------------------------------------------------------ schedule
    def _frames_before(self, t: float) -> None:
        """The instants due before an input of time t (or the oldest scan held back, if
        older: the frames wait for it) go out, after the rows waiting."""
        held = self.admit.held()
        due = self.clock.due_before(t if held is None else min(t, held))
        if due:
            self._flush()
            for instant in due:
                self.frames.publish(instant)

    def _tick(self) -> None:
        """After a batch: the scans the wall clock releases, the frame it makes due (or
        the coast and delete of a frame put within the step: `Frames.settle`)."""
        if len(self.admit) and (now := self.clock.sim_time(time.time())) is not None:
            self._apply_scans(self.admit.release(now))
        self.frames.settle()
