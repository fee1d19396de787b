"""Answer `get <ns>/origin` (contract 1.2): the deployment's geodetic frame, stated once
by the service so that every gateway and display of the namespace uses the same one. The
answer never changes while the service runs, so it is given on Zenoh's thread, not
queued behind the inputs."""

from __future__ import annotations

from typing import Any

import zenoh

from ..wire import Keys, Origin, origin_message
from .publish import MSGPACK


class OriginQueryable:
    """The queryable on `<ns>/origin`: `{frame: "enu", lat, lon, alt, datum}` or
    `{frame: "local"}` when the service was given no origin."""

    def __init__(self, session: zenoh.Session, keys: Keys, origin: Origin | None) -> None:
        self.key, self.payload = keys.origin, origin_message(origin)
        self.queryable = session.declare_queryable(keys.origin, self._answer)

    def _answer(self, query: Any) -> None:
        query.reply(self.key, self.payload, encoding=MSGPACK)

    def close(self) -> None:
        self.queryable.undeclare()
