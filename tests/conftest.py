"""Loopback fixtures: real service processes and real Zenoh sessions on 127.0.0.1 (the
service processes are the pytest plugin's, docs/client.md)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import pytest
import zenoh

from zenoh_track.clients import ServiceProcess
from zenoh_track.estimation.catalog import FilterSpec
from zenoh_track.tracking.display import DisplayConfig
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import peer_config, unpack

pytest_plugins = ["zenoh_track.clients.pytest_plugin", "pytester"]


def client_session(endpoint: str) -> zenoh.Session:
    return zenoh.open(peer_config(endpoint))


class Collector:
    """Subscribes a key expression and keeps every sample (key, kind, decoded map)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.samples: list[tuple[str, str, Any]] = []
        self.cond = threading.Condition()
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, s: Any) -> None:
        body = unpack(s.payload.to_bytes()) if s.kind == zenoh.SampleKind.PUT else None
        with self.cond:
            kind = "PUT" if s.kind == zenoh.SampleKind.PUT else "DELETE"
            self.samples.append((str(s.key_expr), kind, body))
            self.cond.notify_all()

    def wait_for(self, pred, timeout: float = 60.0) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: pred(self.samples), timeout)

    def bodies(self) -> list[Any]:
        with self.cond:
            return [b for _, kind, b in self.samples if kind == "PUT"]


def ServiceProc(*extra: str, ns: str = "track") -> ServiceProcess:  # noqa: N802
    """`python -m zenoh_track` on a free loopback port (the plugin's ServiceProcess), the
    service's own default clock unless `extra` says `--clock`."""
    return ServiceProcess(*extra, ns=ns, clock=None)


@pytest.fixture
def service_factory(track_service_factory) -> Callable[..., tuple[ServiceProcess, zenoh.Session]]:
    """`start(*extra, ns="track")`: a service of these options, alive, and a session
    connected to it (the plugin's `track_service_factory`, the service's default clock)."""
    def start(*extra: str, ns: str = "track") -> tuple[ServiceProcess, zenoh.Session]:
        svc = track_service_factory(*extra, ns=ns, clock=None)
        return svc, svc.client.session

    return start


DISPLAY_OPTIONS = {"blend", "blend_speed", "rate", "lag", "coast_after"}


def make_tracker(order: int = 2, q: float | None = None, **kw: Any) -> Tracker:
    """A single-model tracker (order 2: CV, 3: CA) whose config also takes the display's
    options (for the unit tests of the tracker and of the display state)."""
    disp = DisplayConfig(**{k: kw.pop(k) for k in list(kw) if k in DISPLAY_OPTIONS})
    return Tracker.from_config(TrackerConfig(filter=FilterSpec({2: "cv", 3: "ca"}[order], q), **kw,
                                 display=disp))


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels() -> None:
    """Compile the kernels once, before any service process starts (on a fresh clone it
    takes tens of seconds; the processes then load them from the cache), and let them
    serve in this process as in a service."""
    from zenoh_track.estimation import jit
    from zenoh_track.tracking.compiled import KERNELS

    jit.load(KERNELS)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--update-digests", action="store_true", default=False,
                     help="tests/test_same_bytes.py: write the output digests of this run "
                          "to tests/data/same_bytes.json instead of comparing")
