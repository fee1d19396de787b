"""The deployment's geodetic origin: where the service's ENU frame (x East, y North,
z up, metres) sits on the WGS-84 ellipsoid. Every client that draws geography or
writes latitudes asks `deployment_origin`, the one place that decides where it comes
from (today the operator's `--origin`)."""

from __future__ import annotations

import argparse
from typing import Any

Origin = tuple[float, float, float]


def parse_origin(text: str) -> list[float]:
    """`LAT,LON,ALT` (degrees, degrees, metres) of the ENU frame's origin."""
    try:
        lat, lon, alt = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LAT,LON,ALT, got {text!r}") from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 360):
        raise argparse.ArgumentTypeError(f"latitude/longitude out of range: {text!r}")
    return [lat, lon, alt]


def deployment_origin(given: list[float] | None, session: Any = None) -> Origin | None:
    """The origin to draw with: the operator's (`--origin`) when given, else None
    (positions stay in ENU metres). `session`: the Zenoh session, for an origin that the
    service announces."""
    if given is not None:
        return (float(given[0]), float(given[1]), float(given[2]))
    return None
