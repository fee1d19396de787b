"""Clients of the track service; they depend on zenoh_track.wire only.

The client library (docs/client.md) is importable from here, loaded on first use so that
the command-line tools and the pytest plugin stay cheap to import:
`from zenoh_track.clients import connect, Feed, Picture, Frame`."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from zenoh_track.clients.lib import (
        TLS,
        Client,
        Feed,
        Frame,
        Merge,
        Picture,
        Rejected,
        ServiceProcess,
        connect,
        session_config,
    )

__all__ = ["TLS", "Client", "Feed", "Frame", "Merge", "Picture", "Rejected",
           "ServiceProcess", "connect", "session_config"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from zenoh_track.clients import lib

        return getattr(lib, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
