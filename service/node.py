"""The Zenoh adapter: subscribe inputs, run the pipeline on one worker thread, publish.

Measurements wait in Zenoh's own FIFO channels (Zenoh's receive thread never needs the
GIL for them, so a busy worker cannot throttle the link); the worker takes them in
batches, straight into its step when nothing else waits (`_next_batch`). Clock messages
and queries come by callback into its inbox, behind the measurements received before
them. One
worker thread owns the tracker, so the tracker needs no locks. Data flows one way:
wire (decode, validate) -> tracking (associate, update, delete, initiate; display state)
-> clock -> publication (docs/architecture.md).
"""

from __future__ import annotations

import gc
import heapq
import json
import logging
import math
import queue
import struct
import threading
import time
from typing import Any

import zenoh

from . import __version__, defaults
from .estimation import jit
from .inputs import Inputs
from .outputs import MSGPACK, Publisher
from .tracking.bulk import Rows
from .tracking.clock import Lockstep, Realtime
from .tracking.reorder import ReorderBuffer
from .tracking.timeline import Timeline
from .tracking.tracker import Tracker
from .wire import (
    PROTOCOL_VERSION,
    Keys,
    PlotScan,
    pack,
    stamp_ns,
    unpack,
)

log = logging.getLogger("track-service")
MAX_BATCH = 1024  # inputs per worker step: bounds how long a due frame waits
CHANNEL = 1 << 13  # measurements Zenoh holds for the worker before it pushes back (bounds memory)
POLL = 0.001  # s: an idle worker looks in the measurement channels this often
TRANSIT = 0.1  # s a publication stamp may precede the sample's arrival (`arrival`)
# s between two gc.freeze() of the worker (when nothing waits): the long-lived objects
# (the tracks' ids and keys, caches) leave the cyclic collector's generations, so its full
# collections scan only what is newer: 0.5 ms instead of ~30 ms at 10,000 tracks (a frame
# late). Objects are still freed by reference counting; only cycles of frozen objects
# would never be (the service makes none that outlive a step).
FREEZE_EVERY = 5.0


def arrival(sample: zenoh.Sample, since: float, now: float) -> float:
    """When `sample` reached this session, or was published (Unix s): its Zenoh timestamp
    (stamped by a publisher with timestamping on, a router on the way, or this session on
    arrival), kept within [since - TRANSIT, now]: its channel was found empty at `since`
    and it was taken at `now`, and a publication stamp may precede its arrival by the
    transit (a stamp outside is another clock's error, bounded so); `now` without one."""
    ns = stamp_ns(sample)
    return now if ns is None else min(max(ns / 1e9, since - TRANSIT), now)


def _meas_time(item: tuple) -> float:
    """A measurement's t for ordering (-inf when unreadable: rejected first)."""
    try:
        t = unpack(item[2]).get("t")
        if isinstance(t, bytes) and len(t) >= 8:  # a batched scan's times: its first
            t = struct.unpack_from("<d", t)[0]
        return float(t) if isinstance(t, int | float) and not isinstance(t, bool) else -math.inf
    except (ValueError, AttributeError):
        return -math.inf


class TrackService(Inputs):
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
        self.meas_key_parts: dict[str, tuple[str, ...]] = {}
        self.timeline = Timeline(max_jump)
        self.state: Any = None  # service.state.StateFile with --state: checkpoints
        self.picture_t: float | None = None  # lockstep: the newest input time taken
        self.unswept: float | None = None  # realtime: a frame published without its deletion
        self.stop = threading.Event()
        self.next_freeze = 0.0  # monotonic time of the worker's next gc.freeze()
        put = self.inbox.put

        def direct(fn: Any) -> zenoh.handlers.Callback:
            # run on Zenoh's receive thread: inputs keep their order across keys (an
            # indirect callback has a thread per subscriber, so a clock message could
            # overtake the measurements sent before it)
            return zenoh.handlers.Callback(fn, indirect=False)

        def control(item: Any) -> None:
            # a clock message or query: the measurements received before it go first (the
            # lock held until it is in the inbox: see `_next_batch`)
            with self.ingest_lock:
                self._move(None)
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
        self.empty_at = [-math.inf] * len(self.meas_subs)  # when each was last found empty
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
        if self.thread.ident is not None:  # started
            self.thread.join(timeout=10)
        if self.state is not None and not self.thread.is_alive():
            self.state.final(self)  # the worker has stopped: the table is still
        self.token.undeclare()
        self.out.close()

    def _move(self, limit: int | None) -> None:
        """`_measurements` into the inbox (the caller holds `ingest_lock`)."""
        put = self.inbox.put
        for item in self._measurements(limit):
            put(item)

    def _measurements(self, limit: int | None) -> list[tuple]:
        """What waits in Zenoh's channels, in arrival order (the caller holds
        `ingest_lock`).

        With several channels (measurements and scans; a shard's several key expressions)
        the order between them is lost: everything waiting is taken and, when more than one
        channel had something, merged by measurement time (feeds send in time order), so a
        lockstep frame is not released by one channel's later input while another's
        earlier ones still wait. One busy channel is taken as it is (no decoding)."""
        subs = self.meas_subs
        if len(subs) > 1:
            limit = None
        lists = [got for i, (kind, sub) in enumerate(subs)
                 if (got := self._drain(i, kind, sub, limit))]
        if len(lists) <= 1:
            return lists[0] if lists else []
        return list(heapq.merge(*lists, key=_meas_time))

    def _next_batch(self, timeout: float) -> list[tuple]:
        """The worker's next inputs in order, at most MAX_BATCH (waiting up to `timeout`
        s for one). When the inbox is empty the measurements go from Zenoh's channels
        straight into the batch (no round trip through the inbox): a clock message or
        query puts the measurements received before it, then itself, into the inbox under
        `ingest_lock`, so with the inbox empty under that lock nothing waiting is older
        than what the channels hold."""
        inbox = self.inbox
        with self.ingest_lock:
            if inbox.empty():
                got = self._measurements(MAX_BATCH)
                if len(got) <= MAX_BATCH:
                    if got:
                        return got
                else:  # several channels: the rest waits in the inbox, in order
                    for item in got[MAX_BATCH:]:
                        inbox.put(item)
                    return got[:MAX_BATCH]
            else:
                self._move(MAX_BATCH)  # behind the inputs waiting
        batch = []
        try:
            batch.append(inbox.get(timeout=timeout))
            while len(batch) < MAX_BATCH:
                batch.append(inbox.get_nowait())
        except queue.Empty:
            pass
        return batch

    def _drain(self, i: int, kind: str, sub: Any, limit: int | None) -> list[tuple]:
        """Up to `limit` inputs of channel i, each given the time of the last (`arrival`: no
        earlier input arrived later), so a worker busy while they wait does not make them
        look late to the realtime clock."""
        got: list[Any] = []
        while limit is None or len(got) < limit:
            s = sub.try_recv()
            if s is None:
                break
            got.append(s)
        now = time.time()
        since = self.empty_at[i]
        if limit is None or len(got) < limit:
            self.empty_at[i] = now  # nothing older than `now` waits in it
        if not got:
            return []
        wall = arrival(got[-1], since, now)
        return [(kind, str(s.key_expr), s.payload.to_bytes(), wall) for s in got]

    def _run(self) -> None:
        while not self.stop.is_set():
            timeout = POLL
            if self.realtime:
                deadline = self.clock.next_deadline(time.time())
                if deadline is not None:
                    timeout = min(max(deadline - time.time(), 0.0), POLL)
            batch = self._next_batch(timeout)
            try:
                self._process(batch)
                if self.realtime:
                    self._tick()
                if self.state is not None:
                    self.state.tick(self)
                if time.monotonic() >= self.next_freeze and self.inbox.empty():
                    gc.freeze()
                    self.next_freeze = time.monotonic() + FREEZE_EVERY
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
        self.unswept = None
        self.out.frame(t, self.tracker.snapshot(t, detail=False))

    def _due(self) -> float | None:
        """Realtime: the display instant due now, if any (the listeners looked at and the
        instants missed counted first)."""
        instant = self.clock.due(time.time() - self.tracker.config.display.lag)
        if instant is not None:
            self.out.look()
            self.count.frames_missed = self.clock.missed + self.out.sender.replaced
        return instant

    def _frame_between(self) -> None:
        """Within a step (around a pass, between two parts of an update): the frame due, if
        any, and nothing else (no deletion, no held scan: the rows still to come hold their
        tracks); the step's `_tick` coasts and deletes at its instant."""
        instant = self._due()
        if instant is not None:
            self.out.frame(instant, self.tracker.snapshot(instant, detail=False))
            self.unswept = instant

    def _tick(self) -> None:
        if len(self.reorder) and self.clock.offset is not None:
            for _, (key, scan) in self.reorder.advance(time.time() + self.clock.offset):
                self._apply_scan(key, scan)
        instant = self._due()
        if instant is not None:
            self._publish_frame(instant)
        elif self.unswept is not None:  # a frame went out within the step: its coast and
            self.out.deleted(self.tracker.step([], now=self.unswept))  # delete, now
            self.unswept = None

    # ------------------------------------------------------------ queries
    def status(self) -> dict[str, Any]:
        c = self.count
        return {
            "tracks": len(self.tracker), "meas_accepted": c.meas_accepted,
            "meas_rejected": c.meas_rejected, "frames_published": c.frames_published,
            "uptime_s": time.monotonic() - self.started, "version": __version__,
            "kernels": jit.state(),
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
