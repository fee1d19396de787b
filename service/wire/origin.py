"""The deployment's geodetic frame (contract 1.2, docs/protocol.md §13): the WGS-84
point whose East-North-Up axes every Cartesian position of the namespace is in, or a
local frame with no geodetic meaning. The service states it (`track-service --origin`)
and answers `get <ns>/origin`; gateways and displays take it from there, so that one
deployment has one frame.

Message: `{frame: "enu", datum: "WGS-84", lat, lon, alt}` (degrees, degrees, metres above
the ellipsoid), or `{frame: "local"}`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from .codec import Rejected, decode_map, pack

MAX_ALT = 1e7  # m: an origin farther than this from the ellipsoid is a typo, not a site
# two origins closer than this are the same (about 1 mm on the ground; 1 mm in height)
SAME_DEG = 1e-8
SAME_ALT = 1e-3


@dataclass(frozen=True, slots=True)
class Origin:
    """A geodetic origin: latitude and longitude in degrees, altitude in metres."""

    lat: float
    lon: float
    alt: float

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (self.lat, self.lon, self.alt)):
            raise Rejected(f"origin must be finite numbers, got {self.text()}")
        if not (-90.0 <= self.lat <= 90.0 and -180.0 <= self.lon <= 360.0):
            raise Rejected(f"origin latitude must be in [-90, 90] and longitude in "
                           f"[-180, 360], got {self.text()}")
        if abs(self.alt) > MAX_ALT:
            raise Rejected(f"origin altitude must be within {MAX_ALT:g} m, got {self.alt:g}")

    def text(self) -> str:
        return f"{self.lat:.9g},{self.lon:.9g},{self.alt:.6g}"

    def same(self, other: Origin) -> bool:
        """Whether two origins are one point (longitudes modulo 360)."""
        dlon = (self.lon - other.lon + 180.0) % 360.0 - 180.0
        return (abs(self.lat - other.lat) <= SAME_DEG and abs(dlon) <= SAME_DEG
                and abs(self.alt - other.alt) <= SAME_ALT)


def parse_origin(text: str) -> Origin:
    """`LAT,LON,ALT` (degrees, degrees, metres): Rejected with the reason otherwise."""
    parts = text.split(",")
    try:
        lat, lon, alt = (float(v) for v in parts)
    except ValueError:
        raise Rejected(f"origin takes LAT,LON,ALT (degrees, degrees, metres), not "
                       f"{text!r}") from None
    return Origin(lat, lon, alt)


def origin_message(origin: Origin | None) -> bytes:
    """The `<ns>/origin` reply of a service with this origin (None: a local frame)."""
    if origin is None:
        return pack({"frame": "local"})
    return pack({"frame": "enu", "datum": "WGS-84", "lat": origin.lat, "lon": origin.lon,
                 "alt": origin.alt})


def parse_origin_message(payload: bytes) -> Origin | None:
    """An `<ns>/origin` reply: the origin, None for a local frame; Rejected otherwise."""
    msg: dict[str, Any] = decode_map(payload)
    frame = msg.get("frame")
    if frame == "local":
        return None
    if frame != "enu" or msg.get("datum", "WGS-84") != "WGS-84":
        raise Rejected(f"origin message: unknown frame {frame!r} or datum {msg.get('datum')!r}")
    try:
        return Origin(*(float(msg[k]) for k in ("lat", "lon", "alt")))
    except (KeyError, TypeError, ValueError) as exc:
        raise Rejected(f"origin message needs numbers lat, lon, alt ({exc!r})") from None
