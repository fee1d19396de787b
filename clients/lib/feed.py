"""Publishing measurements to a track service, checked against the contract first by
the service's own checks (`wire.parse_full`, `parse_scan`, `parse_plots`), and the
service's reports of what it refused (`<ns>/errors/<sensor>`)."""

from __future__ import annotations

import threading
from collections.abc import Sequence
from types import TracebackType
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import zenoh

from zenoh_track.wire import (
    MSGPACK_ENCODING,
    Rejected,
    pack,
    parse_full,
    parse_plots,
    parse_scan,
    unpack,
)

if TYPE_CHECKING:
    from zenoh_track.clients.lib.session import Client

Values = float | Sequence[float] | npt.NDArray[np.floating[Any]]
# the noise a check assumes where a message gives none (the check does not depend on it)
_NOISE = (10.0, 0.01, 0.01, 1.0)
_NOISE_KEYS = ("sr", "saz", "sel", "sigma")


def _column(value: Values) -> bytes | float:
    """A number stays a number; anything else becomes a bin of little-endian float64."""
    if isinstance(value, int | float | np.floating | np.integer):
        return float(value)
    return np.ascontiguousarray(value, "<f8").tobytes()


def _fields(**values: Any) -> dict[str, Any]:
    return {k: v for k, v in values.items() if v is not None}


class Feed:
    """Publishes as one sensor: labelled measurements (`measure`), batched labelled scans
    (`scan`), unlabelled scans (`plots`) and the lockstep clock (`clock`). Each message
    is checked before it is sent (`Rejected`, a ValueError whose text names the field);
    `errors` lists what the service refused of this sensor's inputs."""

    def __init__(self, client: Client, sensor: str, check: bool = True) -> None:
        self.client = client
        self.keys = client.keys
        self.sensor = sensor
        self.check = check
        self._errors: list[dict[str, Any]] = []
        self._cond = threading.Condition()
        self._sub: Any = client.session.declare_subscriber(self.keys.errors(sensor),
                                                           self._on_error)

    def _on_error(self, sample: Any) -> None:
        try:
            body = unpack(sample.payload.to_bytes())
        except ValueError:
            return
        with self._cond:
            self._errors.append(body if isinstance(body, dict) else {"reason": repr(body)})
            self._cond.notify_all()

    @property
    def errors(self) -> list[dict[str, Any]]:
        """The service's reports {key, reason, code, t_wall} received so far."""
        with self._cond:
            return list(self._errors)

    def wait_for_errors(self, count: int = 1, timeout: float = 10.0) -> list[dict[str, Any]]:
        """Block until `count` reports arrived; TimeoutError after `timeout` s."""
        with self._cond:
            if not self._cond.wait_for(lambda: len(self._errors) >= count, timeout):
                raise TimeoutError(f"{len(self._errors)} of {count} error reports on "
                                   f"{self.keys.errors(self.sensor)} within {timeout:g} s")
            return list(self._errors)

    def _send(self, key: str, payload: bytes) -> None:
        """Put as a feed must: nothing dropped (BLOCK), MessagePack's encoding."""
        self.client.session.put(key, payload, encoding=MSGPACK_ENCODING,
                                congestion_control=zenoh.CongestionControl.BLOCK)

    def measure(self, target: str, t: float, *, r: float | None = None,
                az: float | None = None, el: float | None = None,
                pos: Sequence[float] | npt.NDArray[np.floating[Any]] | None = None,
                sigma: float | Sequence[float] | None = None, sr: float | None = None,
                saz: float | None = None, sel: float | None = None,
                sensor_pos: Sequence[float] | None = None, seq: int | None = None,
                sigma_t: float | None = None) -> None:
        """One labelled measurement of `target`: polar (`r`, `az`[, `el`]) or Cartesian
        (`pos`), noise optional (the service's defaults); `sigma_t`: the std of the time
        `t`, s (docs/timing.md; absent: the service measures it)."""
        def plain(v: Any) -> Any:
            return None if v is None else [float(x) for x in np.ravel(v)]

        msg = _fields(t=float(t), r=r, az=az, el=el, pos=plain(pos), sr=sr, saz=saz, sel=sel,
                      sigma=sigma if sigma is None or np.isscalar(sigma) else plain(sigma),
                      sensor_pos=plain(sensor_pos), seq=seq, sigma_t=sigma_t)
        payload = pack(msg)
        if self.check:
            parse_full(self.sensor, target, payload, _NOISE)
        self._send(self.keys.meas(self.sensor, target), payload)

    def _columns(self, t: Values | None, r: Values | None, az: Values | None,
                 el: Values | None, pos: Any, noise: dict[str, Values | None],
                 sensor_pos: Sequence[float] | None) -> dict[str, Any]:
        msg: dict[str, Any] = {} if t is None else {"t": _column(t)}
        for key, value in (("r", r), ("az", az), ("el", el)):
            if value is not None:
                msg[key] = np.ascontiguousarray(value, "<f8").tobytes()
        if pos is not None:
            rows = np.asarray(pos, "<f8")
            if rows.ndim != 2 or rows.shape[1] not in (2, 3):
                raise Rejected(f"'pos' must be rows of 2 or 3 coordinates, not shape "
                               f"{rows.shape}")
            msg["pos"], msg["dim"] = np.ascontiguousarray(rows).tobytes(), rows.shape[1]
        msg.update({k: _column(v) for k, v in noise.items() if v is not None})
        if sensor_pos is not None:
            msg["sensor_pos"] = [float(x) for x in sensor_pos]
        return msg

    def scan(self, t: Values, ids: Sequence[str], *, r: Values | None = None,
             az: Values | None = None, el: Values | None = None, pos: Any = None,
             sigma: Values | None = None, sr: Values | None = None, saz: Values | None = None,
             sel: Values | None = None, sensor_pos: Sequence[float] | None = None,
             sigma_t: Values | None = None) -> None:
        """Many labelled measurements in one message (`<ns>/scan/<sensor>`): row i for
        target `ids[i]`; `t` one time or one per row; `pos` an (N, 2|3) array; `sigma_t`
        the std of the times, s, one for all or one per row (docs/timing.md)."""
        msg = {"ids": [str(i) for i in ids], **self._columns(
            t, r, az, el, pos, dict(zip(_NOISE_KEYS, (sr, saz, sel, sigma), strict=True)),
            sensor_pos)}
        if sigma_t is not None:
            msg["sigma_t"] = _column(sigma_t)
        payload = pack(msg)
        if self.check:
            rejected = parse_scan(self.sensor, payload, _NOISE).rejected
            if rejected:
                raise Rejected(rejected[0][1])
        self._send(self.keys.scan(self.sensor), payload)

    def plots(self, t: float, *, r: Values | None = None, az: Values | None = None,
              el: Values | None = None, pos: Any = None, sigma: Values | None = None,
              sr: Values | None = None, saz: Values | None = None, sel: Values | None = None,
              sensor_pos: Sequence[float] | None = None) -> None:
        """One unlabelled scan (`<ns>/plots/<sensor>`): detections as columns, polar
        (`r`, `az`[, `el`]) or Cartesian (`pos`, (N, 2|3)); empty columns: nothing seen."""
        msg = self._columns(float(t), r, az, el, pos,
                            dict(zip(_NOISE_KEYS, (sr, saz, sel, sigma), strict=True)),
                            sensor_pos)
        payload = pack(msg)
        if self.check:
            rejected = parse_plots(self.sensor, payload, _NOISE).rejected
            if rejected:
                raise Rejected(rejected[0][1])
        self._send(self.keys.plots(self.sensor), payload)

    def clock(self, t: float) -> None:
        """Advance a lockstep service's clock to `t` (frames up to `t` are published once
        the measurements sent before are applied)."""
        self._send(self.keys.clock, pack({"t": float(t)}))

    def close(self) -> None:
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None

    def __enter__(self) -> Feed:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
