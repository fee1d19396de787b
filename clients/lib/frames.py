"""The `frame` message (docs/protocol.md section 5.3) as NumPy columns: the one decoding of
it in the clients (the wire's `decode_frame` is its plain, per-track reference)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import numpy.typing as npt

from zenoh_track.wire import STATUSES, decode_map

F64 = npt.NDArray[np.float64]
NO_STATUS = len(STATUSES)  # the code of a track whose status the frame does not carry
STATUS_NAMES = np.array([*STATUSES, "-"])


@dataclass(frozen=True)
class Frame:
    """Every track at one display instant, row i of each column for `ids[i]`.

    `pos`, `vel`: (N, 3) m and m/s; `sigma`: (N,) m; `codes`: (N,) uint8 indices into
    `wire.STATUSES` (NO_STATUS where the frame has no status bin); `status` their names
    ("-" for none). The arrays are read-only views of the message's bytes.

    `instance`: the service that drew it ("" when the frame does not say); a merged
    picture (`merge.Merge`) holds the rows of every instance in `instances`."""

    t: float
    id_list: list[str]  # the ids as the message holds them
    pos: F64
    vel: F64
    sigma: F64
    codes: npt.NDArray[np.uint8]
    instance: str = ""
    instances: tuple[str, ...] = ()

    @cached_property
    def ids(self) -> npt.NDArray[np.str_]:
        """The ids as a NumPy array (made on first use: most readers of most frames never
        look them up)."""
        return np.array(self.id_list, dtype=str)

    @property
    def status(self) -> npt.NDArray[np.str_]:
        names: npt.NDArray[np.str_] = STATUS_NAMES[np.minimum(self.codes, NO_STATUS)]
        return names

    def __len__(self) -> int:
        return len(self.id_list)

    def index(self, track_id: str) -> int | None:
        """The row of `track_id`, None when the frame does not hold it."""
        try:
            return self.id_list.index(track_id)
        except ValueError:
            return None

    def track(self, track_id: str) -> dict[str, Any] | None:
        """One track's row {id, pos, vel, sigma, status}, None when absent."""
        i = self.index(track_id)
        if i is None:
            return None
        return {"id": track_id, "pos": self.pos[i], "vel": self.vel[i],
                "sigma": float(self.sigma[i]), "status": str(self.status[i])}

    def rows(self) -> list[dict[str, Any]]:
        """Every track as a dict {id, pos, vel, sigma, status} of plain floats (the rows of
        `wire.decode_frame`; no `status` when the frame has none)."""
        pos, vel, sigma = self.pos.tolist(), self.vel.tolist(), self.sigma.tolist()
        out = [{"id": i, "pos": p, "vel": v, "sigma": s}
               for i, p, v, s in zip(self.id_list, pos, vel, sigma, strict=True)]
        for row, name, code in zip(out, self.status.tolist(), self.codes.tolist(),
                                   strict=True):
            if code < NO_STATUS:
                row["status"] = name
        return out

    def confirmed(self) -> npt.NDArray[np.bool_]:
        """The rows of confirmed tracks (a mask)."""
        return self.codes == STATUSES.index("confirmed")  # type: ignore[no-any-return]

    @classmethod
    def decode(cls, msg: dict[str, Any]) -> Frame:
        """The columns of a decoded `frame` map; ValueError if its arrays do not match its
        ids (a frame without a status bin, or with one of another length: codes NO_STATUS)."""
        ids = msg["ids"]
        if not isinstance(ids, list) or not all(isinstance(i, str) for i in ids):
            raise ValueError("frame 'ids' must be a list of strings")
        n = len(ids)
        cols = []
        for key, width in (("pos", 3), ("vel", 3), ("sigma", 1)):
            data = msg[key]
            if not isinstance(data, bytes) or len(data) != 8 * width * n:
                raise ValueError(f"frame bin '{key}' does not hold {n} rows of {width} float64")
            cols.append(np.frombuffer(data, "<f8"))
        raw = msg.get("status")
        codes = np.frombuffer(raw, np.uint8) if isinstance(raw, bytes) and len(raw) == n \
            else np.full(n, NO_STATUS, np.uint8)
        instance = msg.get("instance", "")
        instance = instance if isinstance(instance, str) else ""
        return cls(float(msg["t"]), ids, cols[0].reshape(n, 3), cols[1].reshape(n, 3), cols[2],
                   codes, instance, (instance,))

    @classmethod
    def from_payload(cls, payload: bytes) -> Frame:
        """`decode` of a `frame` payload (ValueError for anything that is not one)."""
        try:
            return cls.decode(decode_map(payload))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"not a frame message: {exc!r}") from None
