"""The browser's frame format of `track-web`: the service's `frame` (MessagePack, float64
bins) recast as one little-endian binary message that the page reads with typed arrays.

Layout (offsets in bytes; every array starts on a 4-byte boundary)::

    0   u32  magic b"TWF1"
    4   u32  n, the number of tracks
    8   f64  t, the display instant (s)
    16  u32  ids_seq: the version of the id list the rows follow
    20  u32  ids_len: bytes of the id block in this message (0: the browser has it)
    24  u32  extra_len: bytes of the JSON block (0: none)
    28  u32  dropped: frames this connection skipped so far (latest frame wins)
    32  ids block: the ids joined by "\\n" (UTF-8), zero-padded to 4 bytes
        extra block: JSON (interceptors), space-padded to 4 bytes
        f32 pos[3n], f32 vel[3n], f32 sigma[n], u8 status[n] (255: not sent)

Float32 keeps positions to 6 cm at 1,000 km: plenty to draw. The id list (about 15 bytes
a track) is sent to a connection only when it changed since that connection's last frame.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from zenoh_track.clients.lib.frames import NO_STATUS
from zenoh_track.clients.lib.frames import Frame as Columns

MAGIC = b"TWF1"
HEADER = struct.Struct("<4sIdIIII")  # 32 bytes
UNKNOWN_STATUS = 255


def _pad(block: bytes, fill: bytes) -> bytes:
    return block + fill * (-len(block) % 4)


@dataclass
class Frame:
    """One decoded frame, ready to be sent to any number of browsers."""

    seq: int  # frames received before it, itself included
    t: float
    ids: list[str]
    ids_seq: int
    ids_block: bytes
    body: bytes  # the arrays, as the page reads them
    status: np.ndarray  # (N,) uint8
    _row: dict[str, int] | None = field(default=None, repr=False)

    def row(self, track_id: str) -> int | None:
        """The row of a track in this frame (the index is built on first use)."""
        if self._row is None:
            self._row = {tid: i for i, tid in enumerate(self.ids)}
        return self._row.get(track_id)

    def message(self, ids_seq: int, dropped: int, extra: bytes = b"") -> bytes:
        """The message for a browser that holds the id list of version `ids_seq`."""
        ids = self.ids_block if ids_seq != self.ids_seq else b""
        extra = _pad(extra, b" ")
        head = HEADER.pack(MAGIC, len(self.ids), self.t, self.ids_seq, len(ids), len(extra),
                           dropped)
        return b"".join((head, ids, extra, self.body))


class FrameHub:
    """The latest picture and, made on demand, its browser form: pictures that arrive
    while no browser is ready are never recast (latest picture wins)."""

    def __init__(self) -> None:
        self.seq = 0
        self.bad = 0  # payloads that were not a frame
        self.raw: bytes | Columns | None = None
        self.frame: Frame | None = None
        self.ids: list[str] = []
        self.ids_seq = 0
        self.ids_block = b""

    def put(self, payload: bytes | Columns) -> None:
        """A `frame` payload, or a picture the client library drew (`Picture`)."""
        self.raw = payload
        self.seq += 1

    def latest(self) -> Frame | None:
        """The newest frame received (decoded once); None before the first good one."""
        if self.raw is not None and (self.frame is None or self.frame.seq != self.seq):
            try:
                self.frame = self.decode(self.raw, self.seq)
            except (ValueError, KeyError, TypeError):
                self.bad += 1
            self.raw = None
        return self.frame

    def decode(self, payload: bytes | Columns, seq: int) -> Frame:
        cols = payload if isinstance(payload, Columns) else Columns.from_payload(payload)
        ids, pos, vel, sigma = cols.id_list, cols.pos, cols.vel, cols.sigma
        codes = np.where(cols.codes >= NO_STATUS, UNKNOWN_STATUS, cols.codes).astype(np.uint8)
        if ids != self.ids:
            self.ids, self.ids_seq = ids, self.ids_seq + 1
            self.ids_block = _pad("\n".join(ids).encode(), b"\0")
        body = b"".join((pos.astype("<f4").tobytes(), vel.astype("<f4").tobytes(),
                         sigma.astype("<f4").tobytes(), codes.tobytes()))
        return Frame(seq, cols.t, self.ids, self.ids_seq, self.ids_block, body, codes)


def read_message(data: bytes) -> dict:
    """Decode a browser message (the page's reading of it, in Python: for tests and tools)."""
    magic, n, t, ids_seq, ids_len, extra_len, dropped = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise ValueError("not a track-web frame")
    off = HEADER.size
    ids = data[off:off + ids_len].rstrip(b"\0").decode().split("\n") if ids_len else None
    off += ids_len
    extra = data[off:off + extra_len].decode().strip() if extra_len else ""
    off += extra_len
    arrays = {}
    for key, shape, dtype in (("pos", (n, 3), "<f4"), ("vel", (n, 3), "<f4"),
                              ("sigma", (n,), "<f4"), ("status", (n,), np.uint8)):
        arr = np.frombuffer(data, dtype=dtype, count=int(np.prod(shape)), offset=off)
        arrays[key] = arr.reshape(shape)
        off += arr.nbytes
    return {"n": n, "t": t, "ids_seq": ids_seq, "ids": ids, "extra": extra,
            "dropped": dropped, **arrays}
