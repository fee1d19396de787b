"""The deployment's geodetic frame as a client takes it: from the service
(`get <ns>/origin`, contract 1.2), an explicit option only where it agrees. Every client
that draws geography or writes latitudes asks `deployment_origin`, the one place that
decides where it comes from."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from zenoh_track.wire import Origin, Rejected, fail, parse_origin_message
from zenoh_track.wire import parse_origin as parse_origin_text

if TYPE_CHECKING:
    from zenoh_track.clients.lib.session import Client

UNKNOWN = "unknown"  # no service answered `<ns>/origin`


class OriginConflict(ValueError):
    """An explicit origin that is not the service's: the two would shift every track."""


def service_origin(client: Client, timeout: float = 5.0) -> Origin | None | str:
    """The origin the services of the namespace state: an Origin, None for a local frame,
    UNKNOWN when none answers. OriginConflict when two services state different ones;
    a malformed answer counts as none."""
    found: list[Origin | None] = []
    for reply in client.session.get(client.keys.origin, timeout=timeout):
        if reply.ok is not None:
            try:
                found.append(parse_origin_message(reply.ok.payload.to_bytes()))
            except Rejected:
                continue
    if not found:
        return UNKNOWN
    first = found[0]
    for other in found[1:]:
        if (first is None) != (other is None) or (first is not None and other is not None
                                                   and not first.same(other)):
            raise OriginConflict(f"the services of {client.keys.origin} state different "
                                 f"origins ({_text(first)} and {_text(other)})")
    return first


def agreed_origin(client: Client, given: Origin | None, timeout: float = 5.0
                  ) -> tuple[Origin | None, str]:
    """The origin to use and where it came from ("service", "option", "none").

    The service's when it states one; an explicit `given` must then be the same point
    (OriginConflict otherwise). A service with a local frame, or none answering: `given`
    (a private agreement between the client and the feeds), or None."""
    stated = service_origin(client, timeout)
    if isinstance(stated, Origin):
        if given is not None and not given.same(stated):
            raise OriginConflict(f"--origin {given.text()} disagrees with the service's "
                                 f"origin {stated.text()} (every position would shift; "
                                 "leave --origin out to take the service's)")
        return stated, "service"
    return given, "option" if given is not None else "none"


def _text(origin: Origin | None) -> str:
    return "local" if origin is None else origin.text()


def parse_origin(text: str) -> list[float]:
    """`--origin LAT,LON,ALT` (degrees, degrees, metres) as an option's type: the wire's
    one check of an origin (`wire.parse_origin`)."""
    try:
        origin = parse_origin_text(text)
    except Rejected as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return [origin.lat, origin.lon, origin.alt]


def deployment_origin(session: Any, ns: str, given: list[float] | None, prog: str
                      ) -> tuple[float, float, float] | None:
    """The origin to draw with (lat, lon, alt), or None (positions stay in ENU metres):
    the service's; `given` (`--origin`) where the service states none; a `given` that
    disagrees with the service's ends the program with one line (exit 2)."""
    from zenoh_track.clients.lib.session import Client

    try:
        origin, _ = agreed_origin(Client(session, ns, own=False),
                                  Origin(*given) if given else None, timeout=2.0)
    except OriginConflict as exc:
        fail(str(exc), prog)
    return None if origin is None else (origin.lat, origin.lon, origin.alt)
