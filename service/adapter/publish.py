"""The last stage: the service's outputs on Zenoh: `tracks/` states, 30 Hz `display/` and `frame`,
deletions and `errors/`, each encoded in bulk from the tracker's columns (`encode`),
with the counters that `status` reports.

`frame` is always published; `display/<id>` and `tracks/<id>` only for the tracks that
some subscriber listens to (`listeners.Listeners`), and the batched `states` key only
while someone subscribes it. Every put and reply carries the Zenoh encoding
`application/msgpack` (`wire.MSGPACK_ENCODING`; JSON replies `application/json`)."""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import zenoh

from ..tracking.batches import StepOutcome
from ..tracking.display import Snapshot
from ..tracking.noise_check import NoiseCheck
from ..tracking.store import States
from ..wire import CHUNK, MSGPACK_ENCODING, Keys, pack, reason_code
from .encode import pack_displays, pack_frame, pack_states, pack_tracks
from .listeners import Listeners
from .schedule import Publishing

__all__ = ["Counters", "Publisher"]

MSGPACK = zenoh.Encoding(MSGPACK_ENCODING)

log = logging.getLogger("track-service")
LOG_EVERY = 10.0  # s: rejected inputs are logged at most once in this period


@dataclass
class Counters:
    meas_accepted: int = 0
    meas_rejected: int = 0
    meas_lost: int = 0
    frames_published: int = 0
    frames_missed: int = 0
    tracks_deleted: int = 0
    states_withheld: int = 0
    internal_errors: int = 0  # inputs the service failed on (a bug; each reported)
    scans_applied: int = 0
    by_reason: dict[str, int] = field(default_factory=dict)  # rejections by reason code
    display_puts: int = 0  # display/<id> messages put (only for tracks someone listens to)
    tracks_puts: int = 0  # tracks/<id> messages put (likewise)



class Publisher:
    """Everything the service puts, as its clock's `publishing` says: the display keys'
    congestion control (a realtime frame may drop: a stale frame is worthless) and the
    senders of frames and states; `tracks/`, `states`, deletions and errors never drop.
    `per_target_display` False: no `display/<id>` even when someone listens. `instance`
    (the liveliness name) goes into every frame: clients merge several instances' frames
    by it."""

    def __init__(self, session: zenoh.Session, keys: Keys, publishing: Publishing,
                 per_target_display: bool, instance: str | None = None) -> None:
        self.session, self.keys, self.instance = session, keys, instance
        self.per_target_display = per_target_display
        self.count = Counters()
        self.log_after = 0.0  # wall time before which no rejection is logged
        cc = zenoh.CongestionControl
        self.display_cc = publishing.display_cc
        self.block = cc.BLOCK
        self.pub_frame = session.declare_publisher(keys.frame, congestion_control=self.display_cc,
                                                   encoding=MSGPACK)
        self.sender = publishing.frame_sender(self.pub_frame)
        self.track_sender = publishing.track_sender(session, MSGPACK)
        self.pub_states = session.declare_publisher(keys.states, congestion_control=self.block,
                                                    encoding=MSGPACK)
        # who listens is read again every `refresh` s (0: at every step: a replay must not
        # miss a subscriber)
        refresh = publishing.refresh
        self.display_listeners = Listeners(session, keys.display("").rstrip("/"), refresh)
        self.track_listeners = Listeners(session, keys.tracks("").rstrip("/"), refresh)
        self.states_wanted = False  # someone subscribes `states` (as of the last look)
        # key expressions of each track's display/ and tracks/ keys, made once per track;
        # plain session.put on them: zenoh declares cost O(declared) each, so a
        # publisher per target would make starting N tracks O(N^2) (bench/README.md)
        self.track_keys: dict[str, tuple[zenoh.KeyExpr, zenoh.KeyExpr]] = {}
        self.frame_ids: tuple[list[str] | None, bytes] = (None, b"")  # ids, packed
        # the latest instant's frame and snapshot: late joiners get them by query
        self.latest: tuple[bytes | None, Snapshot | None] = (None, None)
        self.latest_bodies: tuple[Snapshot | None, list[bytes]] = (None, [])

    def reject(self, key: str, sensor: str, reason: str) -> None:
        c = self.count
        c.meas_rejected += 1
        code = reason_code(reason)  # a short, stable set: the map stays bounded
        c.by_reason[code] = c.by_reason.get(code, 0) + 1
        now = time.time()
        if now >= self.log_after:  # at most one line per LOG_EVERY s: a flood of bad
            self.log_after = now + LOG_EVERY  # input must not flood the log
            log.warning("rejected %s: %s (%d rejected so far: %s)", key[:200], reason,
                        c.meas_rejected, c.by_reason)
        self.session.put(self.keys.errors(sensor if CHUNK.fullmatch(sensor) else "unknown"),
                         pack({"key": key, "reason": reason, "code": code, "t_wall": now}),
                         congestion_control=zenoh.CongestionControl.BLOCK, encoding=MSGPACK)

    @property
    def replaced(self) -> int:
        """Frames replaced by a newer one before they went out (`FrameSender`)."""
        return self.sender.replaced

    def noise(self, check: NoiseCheck) -> None:
        """Each sensor whose stated noise is far off, on `errors/<sensor>` (code `noise`,
        docs/protocol.md §4.3; at most once per `defaults.NOISE_EVERY` s of wall time per
        sensor; the input was used, so nothing is counted as rejected)."""
        for r in check.due(time.time()):
            log.warning("sensor %s: %s", r.sensor[:200], r.reason())
            self.session.put(self.keys.errors(r.sensor if CHUNK.fullmatch(r.sensor) else
                                              "unknown"),
                             pack({"key": self.keys.meas(r.sensor, "*"), "reason": r.reason(),
                                   "code": "noise", "t_wall": time.time(), **r.body()}),
                             congestion_control=zenoh.CongestionControl.BLOCK, encoding=MSGPACK)

    def look(self) -> None:
        """Bring the listeners of `display/`, `tracks/` and `states` up to date (once per
        step, so that a subscriber declared before an input is served with it; cheap
        unless due)."""
        now = time.monotonic()
        self.display_listeners.look(now)
        self.track_listeners.look(now)
        self.states_wanted = self.pub_states.matching_status.matching

    def unsent(self) -> int:
        """`tracks/` messages handed over, not yet put."""
        return self.track_sender.waiting

    def drain(self, timeout: float) -> bool:
        """Wait up to `timeout` s for the `tracks/` states handed over to be put (True:
        they were)."""
        return self.track_sender.drain(timeout)

    def close(self) -> None:
        self.sender.close()
        self.track_sender.close()
        self.display_listeners.close()
        self.track_listeners.close()

    def scan(self, key: str, sensor: str, outcome: StepOutcome) -> None:
        """Count and report the outcome of an unlabelled scan's detections (a rejection
        on the scan's key) and put the states of the tracks they updated or started."""
        for _, reason in outcome.rejected:
            self.reject(key, sensor, reason)
        self.count.meas_accepted += outcome.accepted
        self.put_states(outcome.states)

    def wanted(self, ids: list[str]) -> list[int] | None:
        """Which of these tracks' states are to be put (`states` subscribed: all, None;
        else the indices of those someone listens to on `tracks/`)."""
        listeners = self.track_listeners
        if listeners.everything or self.states_wanted:
            return None
        rows = listeners.select(ids)
        return None if rows is None else rows.tolist()

    @property
    def wants_states(self) -> bool:
        """Whether anyone listens to `tracks/` or `states` (else no state is put)."""
        return not self.track_listeners.none or self.states_wanted

    def batch(self, sensor: str | list[str], ids: list[str], outcome: StepOutcome) -> None:
        """Count and report the outcome of labelled rows (`ids`: the rows' target ids,
        `sensor`: of all rows or of each; a rejection is reported on the row's own `meas/`
        key, as for a single message) and put the states of the tracks they updated."""
        for row, reason in outcome.rejected:
            sn = sensor if isinstance(sensor, str) else sensor[row]
            self.reject(self.keys.meas(sn, ids[row]), sn, reason)
        self.count.meas_accepted += outcome.accepted
        self.put_states(outcome.states)

    def put_states(self, blocks: list[States]) -> None:
        """The `states` messages of blocks of tracks, and their `tracks/<id>` for the
        tracks someone listens to."""
        if not blocks:
            return
        if self.states_wanted:
            for st in blocks:
                self.pub_states.put(pack_states(st))
        listeners = self.track_listeners
        if listeners.none:
            return  # nobody listens to tracks/: nothing to encode
        known, keys = self.track_keys, self._keys
        for st in blocks:
            pick = listeners.select(st.ids)
            if pick is not None:
                if not len(pick):
                    continue
                st = st.select(pick)
            bodies = pack_tracks(st.t, st.ids, st.pos, st.vel, st.x, st.p, st.models, st.nis,
                                 st.updates)
            self.track_sender.put([(known.get(i) or keys(i))[1] for i in st.ids],
                                  bodies)  # in order
            self.count.tracks_puts += len(bodies)

    def _keys(self, track_id: str) -> tuple[zenoh.KeyExpr, zenoh.KeyExpr]:
        """The display/ and tracks/ key expressions of a track."""
        ke = self.track_keys.get(track_id)
        if ke is None:
            ke = self.track_keys[track_id] = (zenoh.KeyExpr(self.keys.display(track_id)),
                                              zenoh.KeyExpr(self.keys.tracks(track_id)))
        return ke

    @property
    def wants_display(self) -> bool:
        """Whether any `display/<id>` is to be put (the snapshot needs its details)."""
        return self.per_target_display and not self.display_listeners.none

    def frame(self, t: float, snap: Snapshot) -> None:
        """The display keys of instant t: `frame`, and `display/<id>` of the tracks that
        someone listens to."""
        snap = self._finite(snap)
        if snap.ids is not self.frame_ids[0]:
            self.frame_ids = (snap.ids, pack(snap.ids))
        frame = pack_frame(t, self.frame_ids[1], snap.pos, snap.vel, snap.sigma, snap.codes,
                           self.instance)
        self.sender.put(frame)
        self.latest = (frame, snap)
        if self.wants_display and len(snap.ids):
            rows = self.display_listeners.select(snap.ids)
            if rows is not None:
                snap = snap.select(rows)
            snap = snap.detailed()
            put, cc, keys = self.session.put, self.display_cc, self._keys
            bodies = pack_displays(t, snap.ids, snap.pos, snap.vel, snap.sigma, snap.age,
                                   snap.status, snap.shown)
            for track_id, body in zip(snap.ids, bodies, strict=True):
                put(keys(track_id)[0], body, congestion_control=cc, encoding=MSGPACK)
            self.count.display_puts += len(bodies)
        self.count.frames_published += 1

    def latest_displays(self) -> tuple[list[str], list[bytes]]:
        """The ids and `display/<id>` bodies of the latest instant published (made when
        first asked: a late joiner's query)."""
        snap = self.latest[1]
        if snap is None:
            return [], []
        if self.latest_bodies[0] is not snap:
            full = snap.detailed()
            self.latest_bodies = (snap, pack_displays(
                snap.t, full.ids, full.pos, full.vel, full.sigma, full.age, full.status,
                full.shown))
        return snap.ids, self.latest_bodies[1]

    def _finite(self, snap: Snapshot) -> Snapshot:
        """Withhold (and count) any track whose displayed state is not finite."""
        if math.isfinite(float(np.sum(snap.pos)) + float(np.sum(snap.vel))
                         + float(np.sum(snap.sigma))):
            return snap  # the usual case: one sum per array (a NaN or an infinity makes
            # it non-finite; so may an overflow of finite values, checked row by row)
        ok = (np.isfinite(snap.pos).all(1) & np.isfinite(snap.vel).all(1)
              & np.isfinite(snap.sigma))
        self.count.states_withheld += int((~ok).sum())
        return snap.select(np.flatnonzero(ok))

    def deleted(self, ids: list[str]) -> None:
        """Announce deleted tracks: a Zenoh delete on each of their keys."""
        if not ids:
            return
        gone = [k for k in map(self.track_keys.pop, ids, [None] * len(ids)) if k is not None]
        for display_key, _ in gone:  # in order with the display/ puts, here; never dropped
            self.session.delete(display_key, congestion_control=self.block)
        self.track_sender.delete([tracks_key for _, tracks_key in gone])  # after the states
        self.count.tracks_deleted += len(ids)
