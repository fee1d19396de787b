"""The Zenoh side of `track-web`: the frames, the service's health, the sensors and the
interceptors, gathered from the key space (docs/protocol.md) for the web server.

Zenoh calls the callbacks on its own threads; the picture (every instance's frames merged
by the client library's `Picture`) goes to the server's event loop (`on_frame`),
everything else is kept here under a lock and read as JSON-ready dicts.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from zenoh_track.clients.lib import Client, Frame
from zenoh_track.wire import Keys, decode_map, unpack

SENSOR_REFRESH = 2.0  # s: a sensor's position is read again at most this often
STATUS_PERIOD = 1.0  # s between status queries


def _vector(value: Any, size: int = 3) -> list[float] | None:
    """A list of `size` finite floats (shorter lists padded with 0), else None."""
    if not isinstance(value, list | tuple) or not 1 <= len(value) <= size:
        return None
    try:
        out = [float(v) for v in value] + [0.0] * (size - len(value))
    except (TypeError, ValueError):
        return None
    return out if all(math.isfinite(v) for v in out) else None


def _reach(msg: dict[str, Any]) -> float:
    """The farthest range (m) in a polar measurement or scan (`r` a number or a float64
    bin, or the `r` of each of `dets`), 0 when it has none: the sensor's coverage drawn
    on the map is the farthest range it has reported."""
    r = msg.get("r")
    values: list[float] = []
    if isinstance(r, int | float) and not isinstance(r, bool):
        values = [float(r)]
    elif isinstance(r, bytes) and len(r) % 8 == 0:
        values = np.frombuffer(r, "<f8").tolist()
    elif isinstance(msg.get("dets"), list):
        values = [float(d["r"]) for d in msg["dets"]
                  if isinstance(d, dict) and isinstance(d.get("r"), int | float)]
    finite = [v for v in values if math.isfinite(v) and v > 0]
    return max(finite, default=0.0)


class Link:
    """Subscriptions and queries of one namespace for the web page."""

    def __init__(self, session: zenoh.Session, keys: Keys,
                 on_frame: Callable[[Frame], None]) -> None:
        self.session, self.keys = session, keys
        self.lock = threading.Lock()
        self.alive: set[str] = set()
        self.sensors: dict[str, dict[str, Any]] = {}
        self.sensor_read: dict[str, float] = {}
        self.interceptors: dict[str, dict[str, Any]] = {}
        self.services: list[dict[str, Any]] = []
        self.last_rejected: dict[str, tuple[float, int]] = {}  # instance: (wall, count)
        self.stopping = threading.Event()
        self.serving: tuple[str, ...] = ()  # the instances in the latest picture
        meas_prefix = f"{keys.ns}/meas/"
        plots_prefix = f"{keys.ns}/plots/"

        def measurement(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            prefix = meas_prefix if key.startswith(meas_prefix) else plots_prefix
            self._sensor(key[len(prefix):].split("/", 1)[0], sample)

        self.subs = [
            session.declare_subscriber(keys.space("meas"), measurement),
            session.declare_subscriber(keys.plots("*"), measurement),
            session.declare_subscriber(keys.display("interceptor-$*"), self._interceptor),
            session.liveliness().declare_subscriber(f"{keys.ns}/alive/tracker/**",
                                                    self._token, history=True),
        ]
        self.poller = threading.Thread(target=self._poll, name="track-web-status",
                                       daemon=True)
        self.poller.start()

        def picture(frame: Frame) -> None:
            self.serving = frame.instances
            on_frame(frame)

        # the picture of every instance, merged by the client library; it asks each
        # instance for its latest frame at once (a paused lockstep picture may have no
        # next instant for long)
        self.client = Client(session, keys.ns, own=False)
        self.picture = self.client.picture(maxlen=1, on_frame=picture)

    @property
    def frames(self) -> int:
        """Frames received (of every instance)."""
        return self.picture.received

    def close(self) -> None:
        self.stopping.set()
        self.client.close()
        for sub in self.subs:
            sub.undeclare()
        self.poller.join(timeout=5)

    # ------------------------------------------------------------ callbacks
    def _token(self, sample: zenoh.Sample) -> None:
        instance = str(sample.key_expr).rsplit("/", 1)[-1]
        with self.lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(instance)
            else:
                self.alive.discard(instance)

    def _sensor(self, sensor: str, sample: zenoh.Sample) -> None:
        """A sensor's position from its polar measurements and scans (`sensor_pos`,
        default the origin), read at most every SENSOR_REFRESH s per sensor."""
        now = time.monotonic()
        if now - self.sensor_read.get(sensor, -math.inf) < SENSOR_REFRESH:
            return
        self.sensor_read[sensor] = now
        try:
            msg = decode_map(sample.payload.to_bytes())
        except ValueError:
            return
        if "r" not in msg and "az" not in msg and "dets" not in msg:
            return  # a position report: no sensor to draw
        pos = _vector(msg.get("sensor_pos", [0.0, 0.0, 0.0]))
        if pos is not None:
            with self.lock:
                reach = max(_reach(msg), self.sensors.get(sensor, {}).get("reach", 0.0))
                self.sensors[sensor] = {"id": sensor, "pos": pos, "reach": reach}

    def _interceptor(self, sample: zenoh.Sample) -> None:
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        with self.lock:
            if sample.kind == zenoh.SampleKind.DELETE:
                self.interceptors.pop(name, None)
                return
        try:
            msg = unpack(sample.payload.to_bytes())
            pos, vel = _vector(msg["pos"]), _vector(msg.get("vel", [0.0]))
        except (ValueError, KeyError, TypeError):
            return
        if pos is None:
            return
        with self.lock:
            self.interceptors[name] = {"id": name, "pos": pos, "vel": vel or [0.0] * 3,
                                       "target": str(msg.get("target", "")),
                                       "captured": bool(msg.get("captured", False))}

    # ------------------------------------------------------------ queries
    def _poll(self) -> None:
        while not self.stopping.wait(STATUS_PERIOD):
            try:
                self.services = self._statuses()
            except zenoh.ZError:
                if self.stopping.is_set():
                    return

    def _statuses(self) -> list[dict[str, Any]]:
        """Every service's status, with its rejected inputs per second since the last
        query."""
        replies = self.session.get(self.keys.status, target=zenoh.QueryTarget.ALL,
                                   consolidation=zenoh.ConsolidationMode.NONE,
                                   timeout=STATUS_PERIOD)
        now, out = time.monotonic(), []
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                st = decode_map(reply.ok.payload.to_bytes())
            except ValueError:
                continue
            instance = str(st.get("instance", "?"))
            rejected = st.get("meas_rejected", 0)
            wall, before = self.last_rejected.get(instance, (now, rejected))
            rate = (rejected - before) / (now - wall) if now > wall else 0.0
            self.last_rejected[instance] = (now, rejected)
            out.append({k: st.get(k) for k in (
                "instance", "tracks", "meas_accepted", "meas_rejected", "frames_published",
                "frames_missed", "clock", "rate", "queue", "version", "protocol")}
                | {"rejects_per_s": rate})
        return sorted(out, key=lambda s: s["instance"])

    def track(self, track_id: str, timeout: float = 2.0) -> dict[str, Any] | None:
        """The `tracks/<id>` state of one track (get), or None if no service holds it."""
        replies = self.session.get(self.keys.tracks(track_id), timeout=timeout)
        for reply in replies:
            if reply.ok is not None:
                try:
                    return decode_map(reply.ok.payload.to_bytes())
                except ValueError:
                    return None
        return None

    def health(self) -> dict[str, Any]:
        with self.lock:
            return {"type": "health", "alive": sorted(self.alive), "services": self.services,
                    "serving": list(self.serving),
                    "sensors": sorted(self.sensors.values(), key=lambda s: s["id"])}

    def extra(self) -> list[dict[str, Any]]:
        """What goes with each frame: the interceptors."""
        with self.lock:
            return list(self.interceptors.values())
