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
import logging
import math
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from . import __version__, defaults
from .encode import pack_displays, pack_frame, pack_tracks
from .tracking.clock import Lockstep, Realtime
from .tracking.display import Snapshot
from .tracking.store import States
from .tracking.tracker import Tracker
from .wire import (
    CHUNK,
    PROTOCOL_VERSION,
    Keys,
    Measurement,
    Rejected,
    pack,
    parse_clock,
    parse_measurement,
    unpack,
)

log = logging.getLogger("track-service")
MAX_BATCH = 256  # inputs per worker step: bounds how long a due frame waits
CHANNEL = 1 << 13  # measurements Zenoh holds for the worker before it pushes back (bounds memory)
POLL = 0.001  # s: an idle worker looks in the measurement channels this often


def _meas_time(item: tuple) -> float:
    """A measurement's t for ordering (-inf when unreadable: rejected first)."""
    try:
        t = unpack(item[2]).get("t")
        return float(t) if isinstance(t, int | float) and not isinstance(t, bool) else -math.inf
    except (ValueError, AttributeError):
        return -math.inf


@dataclass
class Counters:
    meas_accepted: int = 0
    meas_rejected: int = 0
    meas_lost: int = 0
    frames_published: int = 0
    frames_missed: int = 0
    tracks_deleted: int = 0
    states_withheld: int = 0
    reasons: dict[str, int] = field(default_factory=dict)


class TrackService:
    """One tracker instance on one Zenoh session."""

    def __init__(self, session: zenoh.Session, keys: Keys, tracker: Tracker, *,
                 clock: str = defaults.CLOCK, instance: str = "0",
                 noise: tuple[float, float, float, float] = defaults.NOISE,
                 per_target_display: bool = True, meas_keys: list[str] | None = None) -> None:
        self.session, self.keys, self.tracker = session, keys, tracker
        rate = tracker.config.display.rate
        self.realtime = clock == "realtime"
        self.clock = Realtime(rate) if self.realtime else Lockstep(rate)
        self.rate, self.instance, self.noise = rate, instance, noise
        self.per_target_display = per_target_display
        self.count = Counters()
        self.started = time.monotonic()
        self.inbox: queue.SimpleQueue[tuple] = queue.SimpleQueue()
        self.last_seq: dict[str, int] = {}
        self.stop = threading.Event()
        cc = zenoh.CongestionControl
        self.display_cc = cc.DROP if self.realtime else cc.BLOCK
        self.pub_frame = session.declare_publisher(keys.frame, congestion_control=self.display_cc)
        # key expressions of each track's display/ and tracks/ keys, made once per track;
        # plain session.put on them: zenoh declares cost O(declared) each, so a
        # publisher per target would make starting N tracks O(N^2) (bench/README.md)
        self.track_keys: dict[str, tuple[zenoh.KeyExpr, zenoh.KeyExpr]] = {}
        self.frame_ids: tuple[list[str] | None, bytes] = (None, b"")  # ids, packed
        self.block = zenoh.CongestionControl.BLOCK
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
        self.meas_subs = [session.declare_subscriber(k, zenoh.handlers.FifoChannel(CHANNEL))
                          for k in (meas_keys or [keys.space("meas")])]
        self.subs = [
            *self.meas_subs,
            session.declare_subscriber(keys.clock, direct(clock)),
            session.declare_queryable(keys.space("tracks"),
                                      direct(lambda q: control(("tracks", q)))),
            session.declare_queryable(keys.status, direct(lambda q: control(("status", q)))),
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
        self.token.undeclare()

    def _ingest(self, limit: int | None = MAX_BATCH) -> None:
        """Move measurements from Zenoh's channels to the inbox, keeping arrival order.

        With several measurement key expressions (a shard's part of the key space), the
        order between their channels is lost: everything waiting is taken and merged by
        measurement time (feeds send in time order), so a lockstep frame is not released
        by one channel's later measurement while another's earlier ones still wait."""
        with self.ingest_lock:
            now = time.time()
            subs = self.meas_subs
            if len(subs) > 1:
                limit = None
            lists = [self._drain(sub, limit, now) for sub in subs]
            items = lists[0] if len(lists) == 1 else heapq.merge(*lists, key=_meas_time)
            for item in items:
                self.inbox.put(item)

    @staticmethod
    def _drain(sub: Any, limit: int | None, now: float) -> list[tuple]:
        out: list[tuple] = []
        while limit is None or len(out) < limit:
            s = sub.try_recv()
            if s is None:
                break
            out.append(("meas", str(s.key_expr), s.payload.to_bytes(), now))
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
            except Exception:  # keep serving: one bad batch must not stop the service
                log.exception("worker failed on a batch of %d inputs", len(batch))

    # ------------------------------------------------------------ inputs
    def _process(self, batch: list[tuple]) -> None:
        pending: list[Measurement] = []
        seen = (None, -np.inf)  # (arrival stamp, newest t) last given to the clock
        for item in batch:
            kind = item[0]
            if kind == "meas":
                m = self._validate(item[1], item[2])
                if m is None:
                    continue
                if self.realtime:
                    if item[3] != seen[0] or m.t > seen[1]:  # else it cannot move the offset
                        self.clock.observe(m.t, item[3])
                        seen = (item[3], m.t)
                else:
                    self._frames_before(m.t, pending)
                pending.append(m)
            elif kind == "clock":
                try:
                    t = parse_clock(item[2])
                except Rejected as exc:
                    self._reject(item[1], "clock", str(exc))
                    continue
                if self.realtime:
                    self.clock.observe(t, item[3])
                else:
                    self._frames_before(t, pending)
            elif kind in ("tracks", "status"):
                self._flush(pending)
                self._answer(kind, item[1])
        self._flush(pending)

    def _validate(self, key: str, payload: bytes) -> Measurement | None:
        chunks = self.keys.chunks_after(key, "meas")
        sensor = chunks[0] if chunks and chunks[0] else "unknown"
        try:
            if len(chunks) != 2:
                raise Rejected("measurement key must be <ns>/meas/<sensor>/<target>")
            m = parse_measurement(chunks[0], chunks[1], payload, self.noise)
        except Rejected as exc:
            self._reject(key, sensor, str(exc))
            return None
        if m.seq is not None:
            last = self.last_seq.get(m.sensor)
            if last is not None and m.seq > last + 1:
                self.count.meas_lost += m.seq - last - 1
            self.last_seq[m.sensor] = m.seq if last is None else max(last, m.seq)
        return m

    def _reject(self, key: str, sensor: str, reason: str) -> None:
        c = self.count
        c.meas_rejected += 1
        head = reason.split(":")[0]
        c.reasons[head] = c.reasons.get(head, 0) + 1
        log.warning("rejected %s: %s", key, reason)
        self.session.put(self.keys.errors(sensor if CHUNK.fullmatch(sensor) else "unknown"),
                         pack({"key": key, "reason": reason, "t_wall": time.time()}),
                         congestion_control=zenoh.CongestionControl.BLOCK)

    def _flush(self, pending: list[Measurement]) -> None:
        if not pending:
            return
        blocks: dict[int, States] = {}  # the updated tracks, in order, once each block
        outcomes, deleted = self.tracker.track(pending)
        self._deleted(deleted)
        for out in outcomes:
            m = out.meas
            if out.reason is not None:
                self._reject(self.keys.meas(m.sensor, m.target), m.sensor, out.reason)
                continue
            self.count.meas_accepted += 1
            blocks.setdefault(id(out.states), out.states)  # type: ignore[arg-type]
        put, keys, block = self.session.put, self._keys, self.block
        for st in blocks.values():
            bodies = pack_tracks(st.t, st.ids, st.pos, st.vel, st.x, st.p, st.models, st.nis,
                                 st.updates)
            for track_id, body in zip(st.ids, bodies, strict=True):
                put(keys(track_id)[1], body, congestion_control=block)
        pending.clear()

    # ------------------------------------------------------------ outputs
    def _keys(self, track_id: str) -> tuple[zenoh.KeyExpr, zenoh.KeyExpr]:
        """The display/ and tracks/ key expressions of a track."""
        ke = self.track_keys.get(track_id)
        if ke is None:
            ke = self.track_keys[track_id] = (zenoh.KeyExpr(self.keys.display(track_id)),
                                              zenoh.KeyExpr(self.keys.tracks(track_id)))
        return ke

    def _frames_before(self, t: float, pending: list[Measurement]) -> None:
        due = self.clock.due_before(t - self.tracker.config.display.lag)
        if due:
            self._flush(pending)
            for instant in due:
                self._publish_frame(instant)

    def _tick(self) -> None:
        instant = self.clock.due(time.time() - self.tracker.config.display.lag)
        if instant is not None:
            self.count.frames_missed = self.clock.missed
            self._publish_frame(instant)

    def _publish_frame(self, t: float) -> None:
        self._deleted(self.tracker.step([], now=t))  # an empty scan: coast and delete
        snap = self.tracker.snapshot(t, detail=self.per_target_display)
        snap = self._finite(snap)
        if snap.ids is not self.frame_ids[0]:
            self.frame_ids = (snap.ids, pack(snap.ids))
        self.pub_frame.put(pack_frame(t, self.frame_ids[1], snap.pos, snap.vel, snap.sigma))
        if self.per_target_display:
            put, cc, keys = self.session.put, self.display_cc, self._keys
            bodies = pack_displays(t, snap.ids, snap.pos, snap.vel, snap.sigma, snap.age,
                                   snap.status, snap.shown)
            for track_id, body in zip(snap.ids, bodies, strict=True):
                put(keys(track_id)[0], body, congestion_control=cc)
        self.count.frames_published += 1

    def _finite(self, snap: Snapshot) -> Snapshot:
        """Withhold (and count) any track whose displayed state is not finite."""
        if (np.isfinite(snap.pos).all() and np.isfinite(snap.vel).all()
                and np.isfinite(snap.sigma).all()):
            return snap  # the usual case, checked without per-row reductions
        ok = (np.isfinite(snap.pos).all(1) & np.isfinite(snap.vel).all(1)
              & np.isfinite(snap.sigma))
        self.count.states_withheld += int((~ok).sum())
        keep = np.flatnonzero(ok)
        pick = keep.tolist()
        return Snapshot(snap.t, [snap.ids[i] for i in pick], snap.pos[keep], snap.vel[keep],
                        snap.sigma[keep], snap.age[keep],
                        [snap.status[i] for i in pick] if snap.status else [],
                        [snap.shown[i] for i in pick] if snap.shown else [])

    def _deleted(self, ids: list[str]) -> None:
        """Announce deleted tracks: a Zenoh delete on each of their keys."""
        if not ids:
            return
        for track_id in ids:
            for key in self.track_keys.pop(track_id, None) or ():
                self.session.delete(key, congestion_control=self.block)  # never dropped
        self.count.tracks_deleted += len(ids)

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
            "states_withheld": c.states_withheld,
            "reject_reasons": dict(c.reasons),
            "queue": self.inbox.qsize(),
        }

    def _answer(self, kind: str, query: Any) -> None:
        try:
            if kind == "status":
                query.reply(self.keys.status, pack(self.status()))
            else:
                sel = zenoh.KeyExpr(str(query.key_expr))
                for track_id in list(self.tracker.store.where):
                    key = zenoh.KeyExpr(self.keys.tracks(track_id))
                    if sel.intersects(key):
                        query.reply(key, pack(self.tracker.state(track_id)))
        finally:
            query.drop()
