"""`track-foxglove`: the live picture in Foxglove and Lichtblick.

A Foxglove WebSocket server (foxglove-sdk) on ws://127.0.0.1:8765 serving, as each frame
of the service comes:
- `/scene` (foxglove.SceneUpdate): every track as a cube coloured by status, its
  velocity as an arrow, its id as a label and its 1-sigma sphere; the sensors and the
  interceptors (the drawing of `track-record`'s `/scene`: clients/lib/scene.py);
- `/tracks/fixes` (foxglove.LocationFixes): a LocationFix per track for the Map panel,
  when the deployment's geodetic origin is known (`--origin`), at most `--map-hz` times a
  second (10: a map at human pace, a third of the cost of every frame at 10,000 tracks);
- `/counters` (JSON): tracks per status, frames skipped; `/status` (JSON, once a second
  per service instance): the service's counters, for the Plot panel.
Open Foxglove or Lichtblick on ws://127.0.0.1:8765 with the layout of `--layout` (the
3-D scene, the map, the counters' plot; docs/foxglove.md).

A channel nobody subscribes is not encoded. A slow viewer never makes anything queue:
the frames wait in the client library's queue of one (the newest wins), and each viewer
is given a frame only once it has taken the previous one (no more than half a send
buffer left unsent, its receive window open again), the newest frame at that moment;
the others are not encoded for it. A viewer that reads one frame a second is given the
frame that was newest when it last read, never an ever older one.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from importlib import resources
from typing import Any

import numpy as np

from zenoh_track.clients.foxglove.sockets import Connection, accepted
from zenoh_track.clients.lib import scene
from zenoh_track.clients.lib.frames import NO_STATUS, Frame
from zenoh_track.clients.lib.origin import deployment_origin, parse_origin
from zenoh_track.clients.lib.session import Client
from zenoh_track.wire import (
    STATUSES,
    Keys,
    Stop,
    add_zenoh_args,
    fail,
    need,
    on_signals,
    open_session,
)

PROG = "track-foxglove"
PORT = 8765  # Foxglove's default WebSocket port
# messages the SDK keeps per viewer: one frame's scene, fixes and counters and a status;
# fewer would let a frame's counters push out its scene
BACKLOG = 4
SEND_BUFFER = 256 * 1024  # bytes of a viewer's connection send buffer (clients/foxglove/sockets.py)
STATUS_PERIOD = 1.0  # s between /status messages
# s between looks at the connections of viewers still waiting for the latest frame: a
# viewer that reads as fast as frames come is given each within this of its draining
POLL = 0.005
PAIR_PERIOD = 1.0  # s between looks for a viewer's connection not found yet
# s a viewer's receive window may stay less than half its widest, nothing unsent, before
# the server takes that window as its widest: a kernel short of memory may narrow a
# receive buffer for good, and the viewer would be given nothing more
NARROWED = 10.0
MAP_HZ = 10.0  # location fixes per second at most
LAYOUT = "track-foxglove.layout.json"
FIXES_TOPIC = "/tracks/fixes"
COUNTERS_TOPIC = "/counters"
STATUS_TOPIC = "/status"
STATUS_KEYS = ("tracks", "meas_accepted", "meas_rejected", "frames_published",
               "frames_missed", "queue", "rejects_per_s")
_INT = {"type": "integer"}
COUNTERS_SCHEMA = {"type": "object", "title": "track-foxglove counters", "properties": {
    "t": {"type": "number"}, "tracks": _INT, **{s: _INT for s in STATUSES},
    "unknown": _INT, "frames": _INT, "skipped": _INT, "encode_ms": {"type": "number"}}}
STATUS_SCHEMA = {"type": "object", "title": "track-service status", "properties": {
    "instance": {"type": "string"}, **{k: {"type": "number"} for k in STATUS_KEYS}}}


def layout_text() -> str:
    """The layout shipped for Foxglove and Lichtblick (3-D, map, counters' plot)."""
    return (resources.files("zenoh_track.clients.foxglove") / LAYOUT).read_text()


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--host", default="127.0.0.1",
                   help="address to serve on (default %(default)s: this machine only)")
    p.add_argument("--port", type=int, default=PORT,
                   help="WebSocket port (default %(default)s; 0: a free one, printed)")
    p.add_argument("--origin", type=parse_origin, metavar="LAT,LON,ALT",
                   help="geodetic origin of the ENU frame, where the service states none: a "
                        "LocationFix per track (default: the service's; one that differs "
                        "is refused)")
    p.add_argument("--map-hz", type=float, default=MAP_HZ, metavar="HZ",
                   help="location fixes per second at most (0: with every frame; default "
                        "%(default)s)")
    p.add_argument("--marker", type=float, default=100.0, metavar="M",
                   help="size of a track's cube, m (default %(default)s)")
    p.add_argument("--arrow", type=float, default=10.0, metavar="S",
                   help="velocity arrows show the way flown in this time (default %(default)s)")
    p.add_argument("--no-labels", dest="labels", action="store_false",
                   help="no id labels (fewer bytes per frame)")
    p.add_argument("--backlog", type=int, default=BACKLOG, metavar="N",
                   help="messages the SDK keeps for a viewer, oldest dropped (default "
                        "%(default)s)")
    p.add_argument("--send-buffer", type=int, default=SEND_BUFFER, metavar="BYTES",
                   help="a viewer's connection send buffer (default %(default)s; 0: the "
                        "system's, which grows to MBs for a viewer that reads slowly)")
    p.add_argument("--layout", action="store_true",
                   help="print the Foxglove/Lichtblick layout (JSON) and exit")
    add_zenoh_args(p)
    return p


class Viewer:
    """A connected viewer: its id (the SDK's client id, which is also its sink id: the
    SDK allocates both once per connection, counting from 1, and this process has no
    other sink), the topics it subscribes and its connection once found."""

    def __init__(self, sink: int, slack: int = 0) -> None:
        self.sink, self.slack = sink, slack
        self.topics: set[str] = set()
        self.connection: Connection | None = None
        self.gone = False  # its connection closed; its unsubscription follows
        self.looked = 0.0  # monotonic s of the last look for its connection
        self.widest = 0  # the widest receive window it has advertised, bytes
        self.closed_since = 0.0  # monotonic s since which its window is not half open

    def drained(self) -> bool | None:
        """Whether the viewer has taken what it was given, but for `slack` bytes: its
        kernel has all but those (unsent) and its receive window is at least half open,
        which its reading frees (a viewer's kernel announces a window that has at least
        doubled, so a viewer that has read everything is seen so); None when its
        connection is gone. The slack lets a viewer that keeps up be given the next frame
        while it takes the end of the previous one, as a queue of one would, without
        ever putting a whole frame before the newest."""
        assert self.connection is not None
        unsent = self.connection.unsent()
        if unsent is None:
            return None
        if unsent > self.slack:
            return False
        window = self.connection.window()
        if window is None:  # a kernel without tcpi_snd_wnd: the send queue alone
            return True
        self.widest = max(self.widest, window)
        if 2 * window >= self.widest:
            self.closed_since = 0.0
            return True
        now = time.monotonic()
        if not self.closed_since:
            self.closed_since = now
        elif now - self.closed_since > NARROWED:  # a kernel that narrowed its buffer
            self.widest, self.closed_since = window, 0.0
            return True
        return False


class Viewers:
    """The server's listener: who subscribes to what, each viewer's connection (the one
    accepted on the server's port that has just received the subscription), trimmed to
    `send_buffer` bytes; `ready()`, the viewers whose previous frame has drained."""

    def __init__(self, send_buffer: int) -> None:
        self.send_buffer, self.port = send_buffer, 0
        self.by_sink: dict[int, Viewer] = {}
        self.lock = threading.Lock()

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self.lock:
            viewer = self.by_sink.setdefault(client.id, Viewer(client.id,
                                                                self.send_buffer // 2))
            viewer.topics.add(channel.topic)
            if viewer.connection is None:
                self._pair(viewer)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        with self.lock:
            viewer = self.by_sink.get(client.id)
            if viewer is not None:
                viewer.topics.discard(channel.topic)
                if not viewer.topics:
                    del self.by_sink[client.id]

    def _pair(self, viewer: Viewer) -> None:
        """The viewer's connection: of those no other viewer holds, the one that received
        data last (the subscription being handled; this runs as the SDK handles it)."""
        viewer.looked = time.monotonic()
        if not self.port:
            return
        held = {v.connection.inode for v in self.by_sink.values() if v.connection}
        free = [c for c in accepted(self.port) if c.inode not in held]
        if free:
            viewer.connection = min(free, key=Connection.recency)
            if self.send_buffer > 0:
                viewer.connection.set_send_buffer(self.send_buffer)

    def waiting(self) -> set[int]:
        """The viewers that may still take a frame (their connection open)."""
        with self.lock:
            return {v.sink for v in self.by_sink.values() if not v.gone}

    def ready(self, skip: set[int]) -> list[Viewer]:
        """The viewers not in `skip` that have taken what they were given: each is given
        the newest frame once it has taken the previous one, but for half a send
        buffer. A viewer whose connection
        was not found is always ready (the SDK's backlog bounds what waits for it)."""
        with self.lock:
            out = []
            for viewer in self.by_sink.values():
                if viewer.sink in skip or viewer.gone:
                    continue
                if viewer.connection is None:
                    if time.monotonic() - viewer.looked > PAIR_PERIOD:
                        self._pair(viewer)
                    if viewer.connection is None:
                        out.append(viewer)
                        continue
                drained = viewer.drained()
                if drained is None:
                    viewer.gone = True
                elif drained:
                    out.append(viewer)
            return out


class Publisher:
    """The channels of the picture on one Foxglove server. `offer` a frame, then
    `deliver` it to the viewers ready for it; each message is encoded once per frame,
    when a viewer first needs it."""

    def __init__(self, origin: tuple[float, float, float] | None, marker: float, arrow_s: float,
                 labels: bool, map_hz: float = MAP_HZ) -> None:
        import foxglove

        def protobuf(topic: str, name: str) -> foxglove.Channel:
            return foxglove.Channel(topic, message_encoding="protobuf", schema=foxglove.Schema(
                name=name, encoding="protobuf", data=scene.schema(name)))

        self.origin, self.marker, self.arrow_s, self.labels = origin, marker, arrow_s, labels
        self.scene = protobuf(scene.TOPIC, scene.SCENE_SCHEMA)
        self.fixes = protobuf(FIXES_TOPIC, scene.LOCATION_SCHEMA) if origin else None
        self.counters = foxglove.Channel(COUNTERS_TOPIC, schema=COUNTERS_SCHEMA)
        self.status = foxglove.Channel(STATUS_TOPIC, schema=STATUS_SCHEMA)
        self.frames = 0  # frames offered
        self.encode_ms = 0.0
        self.map_period = 1.0 / map_hz if map_hz > 0 else 0.0
        self.map_next = 0.0  # monotonic s
        self.latest: tuple[Frame, int, list[dict[str, Any]], list[dict[str, Any]]] | None = None
        self.log_time = 0
        self.fixes_due = False
        self.encoded: dict[str, bytes] = {}
        self.given: set[int] = set()  # the viewers (sinks) given the latest frame

    def offer(self, frame: Frame, skipped: int, sensors: list[dict[str, Any]],
              interceptors: list[dict[str, Any]]) -> None:
        """The newest frame, to be delivered; one not yet delivered is let go."""
        self.latest = (frame, skipped, sensors, interceptors)
        self.log_time = time.time_ns()
        now = time.monotonic()
        self.fixes_due = self.fixes is not None and now >= self.map_next
        self.encoded, self.given, self.encode_ms = {}, set(), 0.0
        self.frames += 1

    def deliver(self, viewers: Viewers) -> bool:
        """Log the latest frame to each viewer ready for it; whether a viewer still waits
        for it."""
        if self.latest is None:
            return False
        for viewer in viewers.ready(self.given):
            for channel, payload in self._messages(viewer.topics):
                channel.log(payload, log_time=self.log_time, sink_id=viewer.sink)
            self.given.add(viewer.sink)
        return bool(viewers.waiting() - self.given)

    def _messages(self, topics: set[str]) -> list[tuple[Any, bytes]]:
        """The latest frame's messages on `topics`, encoded on first need."""
        assert self.latest is not None
        frame, skipped, sensors, interceptors = self.latest
        out = []
        start = time.perf_counter()
        if scene.TOPIC in topics:
            if scene.TOPIC not in self.encoded:
                self.encoded[scene.TOPIC] = scene.scene_update(
                    frame, marker=self.marker, arrow_s=self.arrow_s, labels=self.labels,
                    sensors=sensors, interceptors=interceptors)
            out.append((self.scene, self.encoded[scene.TOPIC]))
        if self.fixes is not None and self.origin is not None and self.fixes_due \
                and FIXES_TOPIC in topics:
            if FIXES_TOPIC not in self.encoded:
                self.encoded[FIXES_TOPIC] = scene.location_fixes(frame, self.origin)
                self.map_next = time.monotonic() + self.map_period
            out.append((self.fixes, self.encoded[FIXES_TOPIC]))
        self.encode_ms += 1e3 * (time.perf_counter() - start)
        if COUNTERS_TOPIC in topics:
            if COUNTERS_TOPIC not in self.encoded:
                counts = np.bincount(np.minimum(frame.codes, NO_STATUS),
                                     minlength=NO_STATUS + 1)
                counts = [int(c) for c in counts]
                self.encoded[COUNTERS_TOPIC] = json.dumps(
                    {"t": frame.t, "tracks": len(frame),
                     **dict(zip(STATUSES, counts, strict=False)), "unknown": counts[-1],
                     "frames": self.frames, "skipped": skipped,
                     "encode_ms": round(self.encode_ms, 2)}).encode()
            out.append((self.counters, self.encoded[COUNTERS_TOPIC]))
        return out

    def services(self, services: list[dict[str, Any]]) -> None:
        for s in services:
            self.status.log({"instance": str(s.get("instance")),
                             **{k: s[k] for k in STATUS_KEYS
                                if isinstance(s.get(k), int | float)}})


def serve(args: argparse.Namespace, stop: Stop) -> None:
    import foxglove

    from zenoh_track.clients.web.link import Link

    with open_session(args, log=True) as session:
        keys = Keys(args.ns)
        origin = deployment_origin(session, args.ns, args.origin, PROG)
        link = Link(session, keys, lambda payload: None)  # sensors, interceptors, status
        client = Client(session, args.ns, own=False)
        picture = client.picture(maxlen=1)
        listener = Viewers(args.send_buffer)
        try:
            server = foxglove.start_server(name=f"{PROG} ({keys.ns})", host=args.host,
                                           port=args.port, message_backlog_size=args.backlog,
                                           server_listener=listener)
            listener.port = server.port
        except RuntimeError as exc:
            picture.close()
            link.close()
            fail(f"cannot serve on {args.host}:{args.port}: {exc} (another program on that "
                 "port? choose another with --port)", PROG)
        pub = Publisher(origin, args.marker, args.arrow, args.labels, args.map_hz)
        print(f"{PROG}: ws://{args.host}:{server.port} (ns {keys.ns}); layout: "
              f"{PROG} --layout > {LAYOUT}", file=sys.stderr, flush=True)
        next_status = time.monotonic()
        waiting = False  # a viewer waits for the latest frame to drain its connection
        try:
            while not stop.is_set():
                try:
                    frame = picture.next(timeout=POLL if waiting else 0.2)
                except TimeoutError:
                    frame = None
                except StopIteration:
                    break
                if frame is not None:
                    extra = link.health()
                    pub.offer(frame, picture.dropped, extra["sensors"], link.extra())
                waiting = pub.deliver(listener)
                if time.monotonic() >= next_status:
                    pub.services(link.health()["services"])
                    next_status = time.monotonic() + STATUS_PERIOD
        finally:
            server.stop()
            picture.close()
            link.close()
    print(f"{PROG}: {pub.frames} frames served, {picture.dropped} skipped", file=sys.stderr,
          flush=True)


def main(argv: list[str] | None = None) -> None:
    args = parser().parse_args(argv)
    stop = on_signals()
    if args.layout:
        sys.stdout.write(layout_text())
        return
    need("foxglove", "foxglove", PROG)
    need("pymap3d", "foxglove", PROG)
    if args.backlog < 1:
        fail("--backlog must be at least 1", PROG)
    serve(args, stop)


if __name__ == "__main__":
    main()
