"""The Zenoh adapter: subscribe inputs, run the pipeline on one worker thread, publish.

Measurements wait in Zenoh's own FIFO channels (Zenoh's receive thread never needs the
GIL for them, so a busy worker cannot throttle the link); the worker moves them to its
inbox in batches. Clock messages and queries come by callback into the same inbox. One
worker thread owns the tracker, so the tracker needs no locks. Data flows one way:
wire (decode, validate) -> tracking (associate, update, delete, initiate; display state)
-> clock -> publication (docs/architecture.md).
"""

from __future__ import annotations

import heapq
import json
import logging
import math
import queue
import struct
import threading
import time
from typing import Any

import numpy as np
import zenoh

from . import __version__, defaults
from .estimation.measurements import MeasurementBatch
from .outputs import MSGPACK, Publisher
from .tracking.bulk import Rows, track_columns
from .tracking.clock import Lockstep, Realtime
from .tracking.reorder import ReorderBuffer
from .tracking.timeline import Timeline
from .tracking.tracker import Tracker
from .wire import (
    PROTOCOL_VERSION,
    Keys,
    PlotScan,
    Rejected,
    pack,
    parse_clock,
    parse_plots,
    parse_scan_columns,
    parse_singles,
    unpack,
)

log = logging.getLogger("track-service")
MAX_BATCH = 4096  # inputs per worker step: bounds how long a due frame waits
CHANNEL = 1 << 13  # measurements Zenoh holds for the worker before it pushes back (bounds memory)
POLL = 0.001  # s: an idle worker looks in the measurement channels this often


def _meas_time(item: tuple) -> float:
    """A measurement's t for ordering (-inf when unreadable: rejected first)."""
    try:
        t = unpack(item[2]).get("t")
        if isinstance(t, bytes) and len(t) >= 8:  # a batched scan's times: its first
            t = struct.unpack_from("<d", t)[0]
        return float(t) if isinstance(t, int | float) and not isinstance(t, bool) else -math.inf
    except (ValueError, AttributeError):
        return -math.inf


class TrackService:
    """One tracker instance on one Zenoh session."""

    def __init__(self, session: zenoh.Session, keys: Keys, tracker: Tracker, *,
                 clock: str = defaults.CLOCK, instance: str = "0",
                 noise: tuple[float, float, float, float] = defaults.NOISE,
                 per_target_display: bool = True, meas_keys: list[str] | None = None,
                 plot_keys: list[str] | None = None, scan_keys: list[str] | None = None,
                 reorder: float = defaults.REORDER,
                 max_jump: float = defaults.MAX_JUMP) -> None:
        self.session, self.keys, self.tracker = session, keys, tracker
        rate = tracker.config.display.rate
        self.realtime = clock == "realtime"
        self.clock = Realtime(rate) if self.realtime else Lockstep(rate)
        self.rate, self.instance, self.noise = rate, instance, noise
        self.per_target_display = per_target_display
        self.out = Publisher(session, keys, self.realtime, per_target_display,
                             defaults.LISTENERS_REFRESH if self.realtime else 0.0)
        self.count = self.out.count
        self.started = time.monotonic()
        self.inbox: queue.SimpleQueue[tuple] = queue.SimpleQueue()
        self.last_seq: dict[str, int] = {}
        self.timeline = Timeline(max_jump)
        self.state: Any = None  # service.state.StateFile with --state: checkpoints
        self.picture_t: float | None = None  # lockstep: the newest input time taken
        self.stop = threading.Event()
        put = self.inbox.put

        def direct(fn: Any) -> zenoh.handlers.Callback:
            # run on Zenoh's receive thread: inputs keep their order across keys (an
            # indirect callback has a thread per subscriber, so a clock message could
            # overtake the measurements sent before it)
            return zenoh.handlers.Callback(fn, indirect=False)

        def control(item: Any) -> None:
            # a clock message or query: the measurements received before it go first
            self._ingest(limit=None)
            put(item)

        def clock(s: zenoh.Sample) -> None:
            control(("clock", str(s.key_expr), s.payload.to_bytes(), time.time()))

        self.ingest_lock = threading.Lock()
        # measurements and unlabelled scans wait in Zenoh's FIFO channels: (kind, sub)
        self.reorder: ReorderBuffer[tuple[str, PlotScan]] = ReorderBuffer(reorder)
        fifo = zenoh.handlers.FifoChannel
        self.meas_subs = [
            *(("meas", session.declare_subscriber(k, fifo(CHANNEL)))
              for k in (meas_keys or [keys.space("meas")])),
            *(("plots", session.declare_subscriber(k, fifo(CHANNEL)))
              for k in (plot_keys or [keys.plots("*")])),
            *(("scan", session.declare_subscriber(k, fifo(CHANNEL)))
              for k in (scan_keys or [keys.scan("*")]))]
        self.subs = [
            *(sub for _, sub in self.meas_subs),
            session.declare_subscriber(keys.clock, direct(clock)),
            session.declare_queryable(keys.space("tracks"),
                                      direct(lambda q: control(("tracks", q)))),
            session.declare_queryable(keys.status, direct(lambda q: control(("status", q)))),
            # late joiners: the latest instant published, at once (docs/operations.md)
            session.declare_queryable(keys.frame, direct(lambda q: control(("frame", q)))),
            session.declare_queryable(keys.space("display"),
                                      direct(lambda q: control(("display", q)))),
        ]
        self.token = session.liveliness().declare_token(keys.alive(instance))
        self.thread = threading.Thread(target=self._run, name="track-worker", daemon=True)

    # ------------------------------------------------------------ lifecycle
    def start(self) -> TrackService:
        self.thread.start()
        return self

    def close(self) -> None:
        self.stop.set()
        self.inbox.put(("wake",))
        self.thread.join(timeout=10)
        if self.state is not None and not self.thread.is_alive():
            self.state.final(self)  # the worker has stopped: the table is still
        self.token.undeclare()
        self.out.close()

    def _ingest(self, limit: int | None = MAX_BATCH) -> None:
        """Move measurements from Zenoh's channels to the inbox, keeping arrival order.

        With several channels (measurements and scans; a shard's several key expressions)
        the order between them is lost: everything waiting is taken and, when more than one
        channel had something, merged by measurement time (feeds send in time order), so a
        lockstep frame is not released by one channel's later input while another's
        earlier ones still wait. One busy channel is taken as it is (no decoding)."""
        with self.ingest_lock:
            now = time.time()
            subs = self.meas_subs
            if len(subs) > 1:
                limit = None
            lists = [got for kind, sub in subs if (got := self._drain(kind, sub, limit, now))]
            items = lists[0] if len(lists) == 1 else heapq.merge(*lists, key=_meas_time)
            for item in items:
                self.inbox.put(item)

    @staticmethod
    def _drain(kind: str, sub: Any, limit: int | None, now: float) -> list[tuple]:
        out: list[tuple] = []
        while limit is None or len(out) < limit:
            s = sub.try_recv()
            if s is None:
                break
            out.append((kind, str(s.key_expr), s.payload.to_bytes(), now))
        return out

    def _run(self) -> None:
        while not self.stop.is_set():
            timeout = POLL
            if self.realtime:
                deadline = self.clock.next_deadline(time.time())
                if deadline is not None:
                    timeout = min(max(deadline - time.time(), 0.0), POLL)
            self._ingest()
            batch = []
            try:
                batch.append(self.inbox.get(timeout=timeout))
                while len(batch) < MAX_BATCH:
                    batch.append(self.inbox.get_nowait())
            except queue.Empty:
                pass
            try:
                self._process(batch)
                if self.realtime:
                    self._tick()
                if self.state is not None:
                    self.state.tick(self)
            except Exception:  # keep serving: one bad batch must not stop the service
                log.exception("worker failed on a batch of %d inputs", len(batch))

    # ------------------------------------------------------------ inputs
    def _process(self, batch: list[tuple]) -> None:
        """Take a batch of inputs in order: each run of single measurements together
        (`_take_singles`), anything else alone; the measurements waiting are applied
        before anything that must see them (and at the end)."""
        if batch:
            self.out.look()  # who listens to display/ and tracks/ (cheap unless due)
        pending: list[Rows] = []
        i = 0
        while i < len(batch):
            j = i + 1
            if batch[i][0] == "meas":
                while j < len(batch) and batch[j][0] == "meas":
                    j += 1
            try:
                if j > i + 1 or batch[i][0] == "meas":
                    self._take_singles(batch[i:j], pending)
                else:
                    self._take(batch[i], pending)
            except Exception as exc:  # a fault of ours: report it, keep the batch going
                self._internal(batch[i], exc, pending)
            i = j
        self._flush(pending)

    def _internal(self, item: tuple, exc: Exception, pending: list[Rows]) -> None:
        """An input the service failed on (a bug, never a bad input): logged with its
        traceback, reported on errors/ (code `internal`), counted; the measurements
        waiting are applied (or, if they failed, dropped and reported), a query answered."""
        log.exception("worker failed on a %s input", item[0])
        self.count.internal_errors += 1
        key = item[1] if isinstance(item[1], str) else str(getattr(item[1], "key_expr", ""))
        self.out.reject(key, "unknown", f"internal error: {type(exc).__name__}: {exc}")
        try:
            self._flush(pending)
        except Exception:
            log.exception("dropping %d measurements", len(pending))
            pending.clear()
        if item[0] in ("tracks", "status", "frame", "display"):
            try:
                self._answer(item[0], item[1])
            except Exception:
                log.exception("query left unanswered")

    def _take(self, item: tuple, pending: list[Rows]) -> None:
        """One input of the worker's batch other than a single measurement."""
        kind = item[0]
        if kind == "clock":
            try:
                t = parse_clock(item[2])
            except Rejected as exc:
                self.out.reject(item[1], "clock", str(exc))
                return
            if not self._admit(t, item[3], item[1], "clock", pending):
                return
            if len(self.reorder):  # nothing older will come: the held scans go
                self._flush(pending)
                for _, (key, scan) in self.reorder.advance(t, flush=True):
                    self._apply_scan(key, scan)
            if self.realtime:
                self.clock.observe(t, item[3])
            else:
                self._frames_before(t, pending)
        elif kind == "scan":
            self._take_labelled(item[1], item[2], item[3], pending)
        elif kind == "plots":
            self._flush(pending)  # the labelled ones received before it go first
            self._take_scan(item[1], item[2], item[3])
        elif kind in ("tracks", "status", "frame", "display"):
            self._flush(pending)
            self._answer(kind, item[1])

    def _take_singles(self, items: list[tuple], pending: list[Rows]) -> None:
        """Single measurements taken together, in order, as each alone would be: checked
        as columns (`wire.parse_singles`; a bad one reported on its own key), their
        `seq` counted, the time policy and the clock applied, and the good ones left
        waiting in `pending` (a lockstep frame due before one goes out before it)."""
        keys, sensors, targets, payloads, walls = [], [], [], [], []
        for _, key, payload, wall in items:
            chunks = self.keys.chunks_after(key, "meas")
            if len(chunks) != 2:
                self.out.reject(key, chunks[0] if chunks and chunks[0] else "unknown",
                                "measurement key must be <ns>/meas/<sensor>/<target>")
                continue
            keys.append(key)
            sensors.append(chunks[0])
            targets.append(chunks[1])
            payloads.append(payload)
            walls.append(wall)
        got = parse_singles(sensors, targets, payloads, self.noise)
        bad = iter(got.rejected)
        later = next(bad, None)

        def reject_before(upto: float) -> None:  # bad ones reported in message order
            nonlocal later
            while later is not None and later[0] < upto:
                self.out.reject(keys[later[0]], sensors[later[0]], later[1])
                later = next(bad, None)

        last_seq = self.last_seq
        for sensor, seq in zip(sensors, got.seqs, strict=True):
            if seq is not None:
                last = last_seq.get(sensor)
                if last is not None and seq > last + 1:
                    self.count.meas_lost += seq - last - 1
                last_seq[sensor] = seq if last is None else max(last, seq)
        for index, cols in got.parts:
            rows = Rows([sensors[i] for i in index], cols.ids, MeasurementBatch.of_scan(cols))
            at, near = [keys[i] for i in index], [walls[i] for i in index]
            if self._near(rows.batch.t, near):  # one admission for all: the same outcome
                reject_before(index[-1])
                self._admit(float(rows.batch.t.max()), near[-1], at[-1], rows.sensors[-1],
                            pending)
                self._wait(rows, near, pending)
                continue
            for i, x in enumerate(rows.batch.t.tolist()):  # else each in turn, as alone
                reject_before(index[i])
                if self._admit(x, near[i], at[i], rows.sensors[i], pending):
                    self._wait(rows.rows(i, i + 1), near[i:i + 1], pending)
        reject_before(math.inf)

    def _near(self, t: np.ndarray, walls: list[float]) -> bool:
        """Whether inputs of times t received at `walls` are all within --max-jump of the
        picture's time and of each other (then the time policy takes each of them)."""
        lo, hi = float(t.min()), float(t.max())
        if self.realtime:
            off = self.clock.offset
            if off is not None:
                lo, hi = min(lo, min(walls) + off), max(hi, max(walls) + off)
        elif self.picture_t is not None:
            lo, hi = min(lo, self.picture_t), max(hi, self.picture_t)
        return hi - lo <= self.timeline.max_jump

    def _wait(self, rows: Rows, walls: list[float], pending: list[Rows]) -> None:
        """Taken measurements wait in `pending`; the realtime clock learns from them, a
        lockstep frame due before one goes out before it."""
        if self.realtime:
            self._observe(rows.batch.t, walls)
            pending.append(rows)
        else:
            self._wait_lockstep(rows, pending)

    def _observe(self, t: np.ndarray, walls: list[float]) -> None:
        """The realtime clock learns from inputs of times t received at `walls` (the
        newest time of each arrival stamp: what observing each would leave)."""
        newest: dict[float, float] = {}
        for x, w in zip(t.tolist(), walls, strict=True):
            if x > newest.get(w, -math.inf):
                newest[w] = x
        for w, x in newest.items():
            self.clock.observe(x, w)

    def _wait_lockstep(self, rows: Rows, pending: list[Rows]) -> None:
        """Lockstep: the frames due before each measurement go out before it (and after
        those before it): `rows` wait in `pending` in pieces cut where frames fall due."""
        t = rows.batch.t.tolist()
        start = 0
        for i, x in enumerate(t):
            if i == 0 or self._frame_due(x):
                if i > start:
                    pending.append(rows.rows(start, i))
                    start = i
                self._frames_before(x, pending)
        pending.append(rows.rows(start, len(t)) if start else rows)

    def _frame_due(self, t: float) -> bool:
        """Whether a lockstep frame is due before an input of time t."""
        held = self.reorder.oldest()
        x = t if held is None else min(t, held)
        return self.clock.due_soon(x - self.tracker.config.display.lag)

    def _parsed(self, key: str, kind: str, what: str, parse: Any, payload: bytes
                ) -> tuple[str, Any]:
        """The sensor of a `<ns>/<kind>/<sensor>` key and its payload parsed by `parse`,
        or the sensor and None once a rejection is reported."""
        chunks = self.keys.chunks_after(key, kind)
        sensor = chunks[0] if chunks and chunks[0] else "unknown"
        try:
            if len(chunks) != 1:
                raise Rejected(f"{what} key must be <ns>/{kind}/<sensor>")
            return sensor, parse(chunks[0], payload, self.noise)
        except Rejected as exc:
            self.out.reject(key, sensor, str(exc))
            return sensor, None

    def _take_labelled(self, key: str, payload: bytes, wall: float,
                       pending: list[Rows]) -> None:
        """A batched labelled scan (`scan/<sensor>`): its rows mean what single messages
        would (each bad row reported alone, the time policy per row's time) and are
        applied in one pass over the columns (`tracking.bulk`), after the measurements
        received before it."""
        sensor, scan = self._parsed(key, "scan", "batched scan", parse_scan_columns, payload)
        if scan is None:
            return
        for _, reason in scan.rejected:
            self.out.reject(key, sensor, reason)
        if not scan.good:
            return
        batch = MeasurementBatch.of_scan(scan)
        ids = scan.ids
        keep = self._admit_rows(batch.t, wall, key, sensor, pending)
        if keep is not None:
            if not keep.any():
                return
            batch = batch.take(np.flatnonzero(keep))
            ids = [i for i, k in zip(ids, keep.tolist(), strict=True) if k]
        if self.realtime:
            self.clock.observe(float(batch.t.max()), wall)
        else:
            self._frames_before(float(batch.t.min()), pending)
        self._flush(pending)
        outcome = track_columns(self.tracker, ids, sensor, batch,
                                self.out.wanted if self.out.wants_states else None,
                                self._frame_between if self.realtime else None)
        self.out.deleted(outcome.deleted)
        self.out.batch(sensor, ids, outcome)

    def _admit_rows(self, t: np.ndarray, wall: float, key: str, sensor: str,
                    pending: list[Rows]) -> np.ndarray | None:
        """The time policy for the rows of a batched scan, times t: None when every row
        is taken (all within --max-jump of the picture's time: one admission for all),
        else the mask of the rows taken (the policy once per distinct time, in time
        order, as single messages; a refusal reported once per time, every row counted)."""
        lo, hi = float(t.min()), float(t.max())
        if self.realtime:
            off = self.clock.offset
            now = None if off is None else wall + off
        else:
            now = self.picture_t
        if now is not None and max(abs(lo - now), abs(hi - now)) <= self.timeline.max_jump:
            self._admit(hi, wall, key, sensor, pending)  # taken: the picture moves to hi
            return None
        times = np.unique(t)
        refused = [x for x in times.tolist() if not self._admit(x, wall, key, sensor, pending)]
        if not refused:
            return None
        keep = ~np.isin(t, refused)
        extra = int((~keep).sum()) - len(refused)
        self.out.count.meas_rejected += extra
        by = self.out.count.by_reason  # counted by code like the one reported
        by["time_far"] = by.get("time_far", 0) + extra
        return keep

    def _take_scan(self, key: str, payload: bytes, wall: float) -> None:
        """Check an unlabelled scan, report its bad detections, and let it wait in the
        reorder buffer; apply the scans it releases."""
        sensor, scan = self._parsed(key, "plots", "scan", parse_plots, payload)
        if scan is None:
            return
        if not self._admit(scan.t, wall, key, sensor, []):
            return  # far from the picture's time (before `late`: the worse fault)
        late = self.reorder.late(scan.t, sensor)
        if late:
            self.out.reject(key, sensor, late)
            return
        for _, reason in scan.rejected:
            self.out.reject(key, sensor, reason)
        if self.realtime:
            self.clock.observe(scan.t, wall)
        for _, (k, s) in self.reorder.push(sensor, scan.t, (key, scan)):
            self._apply_scan(k, s)

    def _admit(self, t: float, wall: float, key: str, sensor: str,
               pending: list[Rows]) -> bool:
        """The time policy (`tracking.timeline`, docs/protocol.md §6.1) for an input of
        time t received at `wall`: False when it was refused (and reported)."""
        if self.realtime:
            off = self.clock.offset
            now = None if off is None else wall + off
        else:
            now = self.picture_t
        # measurements waiting in `pending` count as tracks: they are about to be applied
        reason, jump = self.timeline.admit(t, now, len(self.tracker) or len(pending))
        if reason is not None:
            self.out.reject(key, sensor, reason)
            return False
        if jump:
            self._new_timeline(t, now, pending)  # realtime: its clock starts one itself
        if not self.realtime and (self.picture_t is None or t > self.picture_t):
            self.picture_t = t
        return True

    def _new_timeline(self, t: float, now: float | None, pending: list[Rows]) -> None:
        """Move the picture to time t: the old timeline's inputs go first, the lockstep
        clock starts afresh (no frames for the gap); forward, the tracks stale at t are
        deleted, backward, the tracks of the abandoned later timeline (they would never
        age out)."""
        self._flush(pending)
        for _, (k, s) in self.reorder.advance(math.inf, flush=True):
            self._apply_scan(k, s)
        self.reorder.reset()
        if not self.realtime:
            self.clock.restart(t)
            self.picture_t = t
        if now is not None and t < now:
            self.out.deleted(self.tracker.drop_newer(t))
        else:  # the tracks stale at the new time go before its first input
            self.out.deleted(self.tracker.delete(t))

    def _apply_scan(self, key: str, scan: PlotScan) -> None:
        if not self.realtime:
            self._frames_before(scan.t, [])
        outcomes, deleted = self.tracker.track_scan(scan)
        self.out.deleted(deleted)
        self.count.scans_applied += 1
        self.out.states(outcomes, key)

    def _flush(self, pending: list[Rows]) -> None:
        """Apply the measurements waiting, in order, in one pass over their columns
        (`tracking.bulk`, as a batched scan's rows; one pass per dimension when they mix
        2-D and 3-D)."""
        if not pending:
            return
        want = self.out.wanted if self.out.wants_states else None
        pause = self._frame_between if self.realtime else None
        for rows in Rows.joined(pending):
            outcome = track_columns(self.tracker, rows.ids, rows.sensors, rows.batch, want,
                                    pause)
            self.out.deleted(outcome.deleted)
            self.out.batch(rows.sensors, rows.ids, outcome)
        pending.clear()

    # ------------------------------------------------------------ outputs
    def _frames_before(self, t: float, pending: list[Rows]) -> None:
        held = self.reorder.oldest()  # frames wait for the scans the reorder buffer holds
        if held is not None:
            t = min(t, held)
        due = self.clock.due_before(t - self.tracker.config.display.lag)
        if due:
            self._flush(pending)
            for instant in due:
                self._publish_frame(instant)

    def _publish_frame(self, t: float) -> None:
        self.out.deleted(self.tracker.step([], now=t))  # an empty scan: coast and delete
        self.out.frame(t, self.tracker.snapshot(t, detail=False))

    def _frame_between(self) -> None:
        """Between two parts of a scan's update: the frame due, if any, and nothing else
        (no deletion, no held scan: the scan's rows still to come hold their tracks)."""
        instant = self.clock.due(time.time() - self.tracker.config.display.lag)
        if instant is not None:
            self.out.look()
            self.count.frames_missed = self.clock.missed
            self.out.frame(instant, self.tracker.snapshot(instant, detail=False))

    def _tick(self) -> None:
        if len(self.reorder) and self.clock.offset is not None:
            for _, (key, scan) in self.reorder.advance(time.time() + self.clock.offset):
                self._apply_scan(key, scan)
        instant = self.clock.due(time.time() - self.tracker.config.display.lag)
        if instant is not None:
            self.out.look()
            self.count.frames_missed = self.clock.missed
            self._publish_frame(instant)

    # ------------------------------------------------------------ queries
    def status(self) -> dict[str, Any]:
        c = self.count
        return {
            "tracks": len(self.tracker), "meas_accepted": c.meas_accepted,
            "meas_rejected": c.meas_rejected, "frames_published": c.frames_published,
            "uptime_s": time.monotonic() - self.started, "version": __version__,
            "protocol": PROTOCOL_VERSION, "instance": self.instance,
            "clock": type(self.clock).__name__.lower(),
            "rate": self.rate, "meas_lost": c.meas_lost, "frames_missed": c.frames_missed,
            "tracks_deleted": c.tracks_deleted,
            "frames_skipped": getattr(self.clock, "skipped", 0),
            "timeline_jumps": self.timeline.jumps,
            "internal_errors": c.internal_errors,
            "states_withheld": c.states_withheld,
            "scans_applied": c.scans_applied, "scans_held": len(self.reorder),
            "rejected_by_reason": dict(c.by_reason),
            "display_puts": c.display_puts, "tracks_puts": c.tracks_puts,
            "queue": self.inbox.qsize(),
        }

    def _answer(self, kind: str, query: Any) -> None:
        """Answer a query: `status` (as JSON when asked `?format=json`), the latest
        `frame` and `display/**`, `tracks/**`."""
        try:
            if kind == "status":
                if query.parameters.get("format") == "json":
                    query.reply(self.keys.status, json.dumps(self.status()),
                                encoding=zenoh.Encoding.APPLICATION_JSON)
                else:
                    query.reply(self.keys.status, pack(self.status()), encoding=MSGPACK)
            elif kind == "frame":
                if self.out.latest[0] is not None:
                    query.reply(self.keys.frame, bytes(self.out.latest[0]), encoding=MSGPACK)
            elif kind == "display":
                sel = zenoh.KeyExpr(str(query.key_expr))
                for track_id, body in zip(*self.out.latest_displays(), strict=True):
                    if track_id in self.tracker.store:  # not deleted since
                        key = zenoh.KeyExpr(self.keys.display(track_id))
                        if sel.intersects(key):
                            query.reply(key, body, encoding=MSGPACK)
            else:
                sel = zenoh.KeyExpr(str(query.key_expr))
                for track_id in list(self.tracker.store.where):
                    key = zenoh.KeyExpr(self.keys.tracks(track_id))
                    if sel.intersects(key):
                        query.reply(key, pack(self.tracker.state(track_id)), encoding=MSGPACK)
        finally:
            query.drop()
