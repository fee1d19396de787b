"""The MCAP files of `track-record` and `track-replay` (docs/clients.md, "Recordings").

One MCAP channel per Zenoh key, sample kind and encoding: topic = the key, message
encoding `msgpack` for `application/msgpack` payloads (else the Zenoh encoding string),
no schema, channel metadata `zenoh_key`, `zenoh_kind` (`put` or `delete`) and
`zenoh_encoding`. Each message is the sample's payload as received, byte for byte, with
log_time = the recorder's receive time (Unix ns, made strictly increasing so that file
order, log-time order and receive order agree) and publish_time = the Zenoh timestamp of
the sample when it has one, else the payload's `t` (simulation seconds, as ns), else the
receive time. A metadata record `zenoh-track` names the namespace, the protocol version,
the package version and the key expressions recorded; `zenoh-track-end` the counts.
The display channel (`/scene`, foxglove.SceneUpdate in protobuf: clients/lib/scene.py,
the drawing that `track-foxglove` serves live) is derived from the `frame` samples, every
instance's merged into one picture as the client library merges them (`Merge`).
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import IO, Any

import numpy as np
from mcap.reader import make_reader
from mcap.well_known import SchemaEncoding
from mcap.writer import CompressionType, Writer

from zenoh_track.clients.lib import scene
from zenoh_track.clients.lib.frames import NO_STATUS, Frame
from zenoh_track.clients.lib.merge import Merge
from zenoh_track.wire import MSGPACK_ENCODING, PROTOCOL_VERSION, STATUSES, Keys, unpack

META = "zenoh-track"
META_END = "zenoh-track-end"
MESSAGE_ENCODINGS = {MSGPACK_ENCODING: "msgpack", "application/json": "json",
                     "text/json": "json", "application/cbor": "cbor",
                     "application/protobuf": "protobuf", "application/cdr": "cdr"}


def package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("zenoh-track-service")
    except PackageNotFoundError:
        return "unknown"


@dataclass(frozen=True)
class Sample:
    """One received Zenoh sample as recorded."""

    key: str
    kind: str  # "put" or "delete"
    encoding: str  # the Zenoh encoding, e.g. "application/msgpack"
    payload: bytes
    log_time: int  # ns
    publish_time: int  # ns


_T_FIXMAP = b"\xa1t\xcb"  # "t" as the first key of a map, then a float64


def payload_time_ns(payload: bytes) -> int | None:
    """The payload's `t` (simulation s) as ns, or None. Messages of this project put `t`
    first, read without decoding the rest; anything else is decoded."""
    t: Any = None
    if len(payload) >= 12 and 0x80 <= payload[0] <= 0x8F and payload[1:4] == _T_FIXMAP:
        t = struct.unpack(">d", payload[4:12])[0]
    elif payload:
        try:
            msg = unpack(payload)
        except ValueError:
            return None
        t = msg.get("t") if isinstance(msg, dict) else None
    if not isinstance(t, int | float) or isinstance(t, bool) or not math.isfinite(t):
        return None
    return max(int(round(t * 1e9)), 0)


class RecordingWriter:
    """Writes samples to an MCAP file, a channel per (key, kind, encoding), plus the
    display channel when `scene_hz` > 0 and `frame` samples come."""

    def __init__(self, out: IO[bytes], ns: str, keyexprs: list[str], scene_hz: float = 2.0,
                 scene_marker: float = 100.0) -> None:
        self.keys = Keys(ns)
        self.writer = Writer(out, compression=CompressionType.ZSTD)
        self.writer.start(profile="", library=f"zenoh-track-service {package_version()}")
        self.writer.add_metadata(META, {
            "namespace": self.keys.ns, "protocol": str(PROTOCOL_VERSION),
            "version": package_version(), "keys": json.dumps(keyexprs),
            "started": datetime.now(UTC).isoformat(timespec="seconds")})
        self.channels: dict[tuple[str, str, str], int] = {}
        self.last_log = 0
        self.written = 0
        self.scene_period = 1.0 / scene_hz if scene_hz > 0 else None
        self.scene_marker = scene_marker
        self.scene_next = -math.inf
        self.scene_channel: int | None = None
        self.merge = Merge()  # the frames of every instance into one picture
        self.scene_t = -math.inf  # the instant of the latest scene
        self.scenes = 0
        self.display_prefix = self.keys.display("")
        self.last_display: dict[str, bytes] = {}  # track id -> latest display/ payload

    def _channel(self, key: str, kind: str, encoding: str) -> int:
        cid = self.channels.get((key, kind, encoding))
        if cid is None:
            cid = self.channels[(key, kind, encoding)] = self.writer.register_channel(
                topic=key, message_encoding=MESSAGE_ENCODINGS.get(encoding, encoding),
                schema_id=0, metadata={"zenoh_key": key, "zenoh_kind": kind,
                                       "zenoh_encoding": encoding})
        return cid

    def _log_time(self, t: int) -> int:
        t = max(t, self.last_log + 1)
        self.last_log = t
        return t

    def write(self, key: str, kind: str, encoding: str, payload: bytes, recv_ns: int,
              stamp_ns: int | None) -> None:
        """Write one sample; `stamp_ns`: its Zenoh timestamp (Unix ns) if it had one."""
        log = self._log_time(recv_ns)
        pub = stamp_ns if stamp_ns is not None else payload_time_ns(payload)
        self.writer.add_message(self._channel(key, kind, encoding), log, payload,
                                log if pub is None else pub, sequence=self.written & 0xFFFFFFFF)
        self.written += 1
        if self.scene_period is None:
            return
        if key.startswith(self.display_prefix):
            tid = key[len(self.display_prefix):]
            if kind == "put":
                self.last_display[tid] = payload
            else:
                self.last_display.pop(tid, None)
        elif key == self.keys.frame and kind == "put":
            self._scene(payload, log)

    def _scene(self, payload: bytes, log: int) -> None:
        """The scene of the picture: every instance's frames merged as a live client
        merges them (`Merge`, on the receive times), at most `scene_hz` a second."""
        try:
            frame = Frame.from_payload(payload)
        except ValueError:
            return  # not a frame this version can read: no picture for it
        for pic in self.merge.add(frame, log / 1e9):
            again = pic.t == self.scene_t  # drawn again: an instance's first frame came
            if pic.t < self.scene_next - 1e-6 and not again:
                continue
            self.scene_t = pic.t
            self.scene_next = pic.t + self.scene_period  # type: ignore[operator]
            body = scene.scene_update(pic, marker=self.scene_marker, codes=self._codes(pic))
            if self.scene_channel is None:
                sid = self.writer.register_schema(scene.SCENE_SCHEMA, SchemaEncoding.Protobuf,
                                                  scene.schema(scene.SCENE_SCHEMA))
                self.scene_channel = self.writer.register_channel(
                    topic=scene.TOPIC, message_encoding="protobuf", schema_id=sid,
                    metadata={"derived_from": self.keys.frame})
            self.writer.add_message(self.scene_channel, self._log_time(log), body,
                                    max(int(round(pic.t * 1e9)), 0))
            self.scenes += 1

    def _codes(self, frame: Frame) -> np.ndarray | None:
        """The status codes of a frame without a status bin, from the `display/` keys
        recorded (None: the frame's own)."""
        if not self.last_display or (frame.codes != NO_STATUS).any():
            return None
        codes = np.full(len(frame), NO_STATUS, np.uint8)
        for row, tid in enumerate(frame.id_list):
            raw = self.last_display.get(tid)
            if raw is not None:
                try:
                    codes[row] = STATUSES.index(unpack(raw).get("status"))
                except (ValueError, AttributeError):
                    pass
        return codes

    def finish(self, received: int) -> None:
        self.writer.add_metadata(META_END, {
            "received": str(received), "written": str(self.written),
            "channels": str(len(self.channels)),
            "scene_updates": str(self.scenes),
            "ended": datetime.now(UTC).isoformat(timespec="seconds")})
        self.writer.finish()


@dataclass(frozen=True)
class Channel:
    """A recorded Zenoh channel."""

    id: int
    key: str
    kind: str
    encoding: str
    count: int


class Recording:
    """A recording opened for reading (a seekable binary stream)."""

    def __init__(self, stream: IO[bytes]) -> None:
        self.reader = make_reader(stream)
        summary = self.reader.get_summary()
        if summary is None:
            raise ValueError("the file has no MCAP summary (was the recording cut short? "
                             "track-record writes it when it stops)")
        self.meta: dict[str, dict[str, str]] = {
            m.name: dict(m.metadata) for m in self.reader.iter_metadata()}
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        self.channels = {
            cid: Channel(cid, ch.metadata["zenoh_key"], ch.metadata.get("zenoh_kind", "put"),
                         ch.metadata.get("zenoh_encoding", ""), counts.get(cid, 0))
            for cid, ch in summary.channels.items() if "zenoh_key" in ch.metadata}
        self.other = {cid: ch.topic for cid, ch in summary.channels.items()
                      if cid not in self.channels}

    @property
    def namespace(self) -> str | None:
        return self.meta.get(META, {}).get("namespace")

    def samples(self, channel_ids: set[int]) -> Iterator[tuple[Channel, Sample]]:
        """The samples of the given channels in receive order."""
        for _, ch, msg in self.reader.iter_messages(log_time_order=True):
            if ch.id in channel_ids:
                c = self.channels[ch.id]
                yield c, Sample(c.key, c.kind, c.encoding, msg.data, msg.log_time,
                                msg.publish_time)
