"""A connection to a track service: one Zenoh session from the usual options (connect,
listen, config file, TLS; multicast scouting off unless a config file turns it on), and
the queries every client needs (`status`, `tracks/**`, the liveliness of the service)."""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import TYPE_CHECKING, Any

import zenoh

from zenoh_track.clients.lib.merge import HOLD, STALE
from zenoh_track.wire import (
    DEFAULT_NS,
    Keys,
    patient,
    stamping,
    unpack,
    wait_for_tracker,
    zenoh_config,
)
from zenoh_track.wire.cli import zenoh_reason

if TYPE_CHECKING:
    from zenoh_track.clients.lib.feed import Feed
    from zenoh_track.clients.lib.frames import Frame
    from zenoh_track.clients.lib.picture import Picture


@dataclass(frozen=True)
class TLS:
    """TLS for `tls/` endpoints: the CA that signed the other side's certificate, and for
    mutual TLS this side's certificate and key (PEM files; deploy/secure/)."""

    root_ca: str
    cert: str | None = None
    key: str | None = None

    def apply(self, conf: Any) -> None:
        conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(self.root_ca))
        if (self.cert is None) != (self.key is None):
            raise ValueError("TLS: give both cert and key (mutual TLS) or neither")
        if self.cert is not None:
            conf.insert_json5("transport/link/tls/connect_certificate", json.dumps(self.cert))
            conf.insert_json5("transport/link/tls/connect_private_key", json.dumps(self.key))
            conf.insert_json5("transport/link/tls/enable_mtls", "true")


def _endpoints(value: str | Sequence[str] | None) -> list[str]:
    return [] if value is None else [value] if isinstance(value, str) else list(value)


def session_config(connect: str | Sequence[str] | None = None,
                   listen: str | Sequence[str] | None = None, config: str | None = None,
                   mode: str | None = None, tls: TLS | None = None) -> Any:
    """The zenoh.Config of these options, as every program of the project builds it
    (`wire.zenoh_config`): without any endpoint, connect to tcp/127.0.0.1:7447. Without
    a config file, BLOCK puts wait for a slow service and samples are timestamped."""
    args = argparse.Namespace(connect=_endpoints(connect), listen=_endpoints(listen),
                              config=config, mode=mode)
    conf = zenoh_config(args)
    if config is None:
        stamping(patient(conf))
    if tls is not None:
        tls.apply(conf)
    return conf


class Client:
    """A session with one namespace of a track service; a context manager that closes
    the session (when it opened it) and everything opened from it."""

    def __init__(self, session: Any, ns: str = DEFAULT_NS, own: bool = True) -> None:
        self.session = session
        self.keys = Keys(ns)
        self.own = own
        self._opened: list[Feed | Picture] = []

    def feed(self, sensor: str = "feed", check: bool = True) -> Feed:
        """A Feed publishing as sensor `sensor` (`check`: against the contract first)."""
        from zenoh_track.clients.lib.feed import Feed

        feed = Feed(self, sensor, check)
        self._opened.append(feed)
        return feed

    def picture(self, maxlen: int = 64, on_frame: Callable[[Frame], Any] | None = None,
                hold: float | None = HOLD, stale: float | None = STALE) -> Picture:
        """A Picture of `frame`, every instance's merged: at most `maxlen` pictures queued
        for `next`/iteration; `on_frame`, `hold`, `stale` as `Picture`'s."""
        from zenoh_track.clients.lib.picture import Picture

        pic = Picture(self, maxlen, on_frame, hold, stale)
        self._opened.append(pic)
        return pic

    def wait_for_service(self, count: int = 1, timeout: float = 30.0) -> None:
        """Block until `count` services of the namespace are alive (their liveliness
        tokens); TimeoutError after `timeout` s."""
        if not wait_for_tracker(self.session, self.keys, count, timeout):
            raise TimeoutError(f"no track service alive on {self.keys.alive()} after "
                               f"{timeout:g} s")

    def status(self, timeout: float = 5.0) -> dict[str, Any]:
        """The service's counters (docs/protocol.md, `status`); TimeoutError without reply."""
        for reply in self.session.get(self.keys.status, timeout=timeout):
            if reply.ok is not None:
                body = unpack(reply.ok.payload.to_bytes())
                if isinstance(body, dict):
                    return body
        raise TimeoutError(f"no reply to {self.keys.status} within {timeout:g} s")

    def statuses(self, timeout: float = 5.0) -> list[dict[str, Any]]:
        """The counters of every instance of the namespace, one map each (sorted by
        `instance`): all replies, none consolidated away (every instance answers on
        the same key)."""
        out = []
        for reply in self.session.get(self.keys.status, target=zenoh.QueryTarget.ALL,
                                      consolidation=zenoh.ConsolidationMode.NONE,
                                      timeout=timeout):
            if reply.ok is not None:
                try:
                    body = unpack(reply.ok.payload.to_bytes())
                except ValueError:
                    continue  # not a status this version reads
                if isinstance(body, dict):
                    out.append(body)
        return sorted(out, key=lambda s: str(s.get("instance", "")))

    def tracks(self, timeout: float = 5.0) -> dict[str, dict[str, Any]]:
        """The current state of every track, by id (`get <ns>/tracks/**`)."""
        out: dict[str, dict[str, Any]] = {}
        for reply in self.session.get(self.keys.tracks("**"), target=zenoh.QueryTarget.ALL,
                                      timeout=timeout):
            if reply.ok is not None:
                out[str(reply.ok.key_expr).rsplit("/", 1)[1]] = unpack(
                    reply.ok.payload.to_bytes())
        return out

    def close(self) -> None:
        for opened in reversed(self._opened):
            opened.close()
        self._opened.clear()
        if self.own:
            self.session.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def connect(connect: str | Sequence[str] | None = None, *,
            listen: str | Sequence[str] | None = None, config: str | None = None,
            mode: str | None = None, tls: TLS | None = None, ns: str = DEFAULT_NS,
            wait: float | None = None) -> Client:
    """Open a Client: `connect`/`listen` endpoints (e.g. "tcp/127.0.0.1:7447"), a Zenoh
    `config` file, a `mode` (peer, client, router), `tls` for tls/ endpoints. `wait`:
    block that many seconds at most for a service to be alive (TimeoutError). Raises
    ConnectionError when Zenoh cannot open the session."""
    try:
        session = zenoh.open(session_config(connect, listen, config, mode, tls))
    except zenoh.ZError as exc:
        raise ConnectionError(f"cannot open the Zenoh session: {zenoh_reason(exc)}") from None
    client = Client(session, ns)
    if wait is not None:
        try:
            client.wait_for_service(timeout=wait)
        except TimeoutError:
            client.close()
            raise
    return client
