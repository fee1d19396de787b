"""Publish, on request: the answers to queries (`status`, the latest `frame` and
`display/**` for late joiners, `tracks/**`), on the worker, behind the inputs received
before them."""

from __future__ import annotations

import json
import time
from typing import TYPE_CHECKING, Any

import zenoh

from .. import __version__
from ..estimation import jit
from ..wire import PROTOCOL_VERSION, Keys, Origin, origin_message, pack, unpack
from .admit import Admit
from .ingest import Ingest, Query
from .publish import MSGPACK, Publisher
from .schedule import Clock

if TYPE_CHECKING:
    from .steps import TrackerCalls


class Queries:
    """What a service answers about itself and its tracks."""

    def __init__(self, keys: Keys, calls: TrackerCalls, out: Publisher, clock: Clock,
                 admit: Admit, ingest: Ingest, instance: str, rate: float,
                 origin: Origin | None = None) -> None:
        self.keys, self.calls, self.out, self.clock = keys, calls, out, clock
        self.admit, self.ingest, self.instance, self.rate = admit, ingest, instance, rate
        self.origin = unpack(origin_message(origin))  # as `<ns>/origin` answers it
        self.started = time.monotonic()

    def status(self) -> dict[str, Any]:
        c = self.out.count
        return {
            "tracks": len(self.calls), "meas_accepted": c.meas_accepted,
            "meas_rejected": c.meas_rejected, "frames_published": c.frames_published,
            "uptime_s": time.monotonic() - self.started, "version": __version__,
            "kernels": jit.state(),
            "protocol": PROTOCOL_VERSION, "instance": self.instance,
            "clock": self.clock.name,
            "rate": self.rate, "meas_lost": c.meas_lost, "frames_missed": c.frames_missed,
            "tracks_deleted": c.tracks_deleted,
            "frames_skipped": self.clock.skipped,
            "timeline_jumps": self.admit.timeline.jumps,
            "internal_errors": c.internal_errors,
            "states_withheld": c.states_withheld,
            "scans_applied": c.scans_applied, "scans_held": len(self.admit),
            "rejected_by_reason": dict(c.by_reason),
            "sensor_noise": self.calls.noise.status(),
            "second_look": self.calls.second_look(),
            "tracks_continued": self.calls.continued(),
            "display_puts": c.display_puts, "tracks_puts": c.tracks_puts,
            "queue": self.ingest.waiting(), "origin": self.origin,
        }

    def answer(self, item: Query) -> None:
        """Answer a query: `status` (as JSON when asked `?format=json`), the latest
        `frame` and `display/**`, `tracks/**`."""
        query, kind = item.query, item.what
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
                    if self.calls.has(track_id):  # not deleted since
                        key = zenoh.KeyExpr(self.keys.display(track_id))
                        if sel.intersects(key):
                            query.reply(key, body, encoding=MSGPACK)
            else:
                sel = zenoh.KeyExpr(str(query.key_expr))
                for track_id in self.calls.ids():
                    key = zenoh.KeyExpr(self.keys.tracks(track_id))
                    if sel.intersects(key):
                        query.reply(key, pack(self.calls.state(track_id)),
                                    encoding=MSGPACK)
        finally:
            query.drop()
