"""Loopback fixtures: real service processes and real Zenoh sessions on 127.0.0.1."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from zenoh_track.clients.procs import stop
from zenoh_track.estimation.catalog import FilterSpec
from zenoh_track.tracking.display import DisplayConfig
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import Keys, free_port, peer_config, unpack, wait_for_tracker


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


class ServiceProc:
    """`python -m zenoh_track` as a separate process on a free loopback port."""

    def __init__(self, *extra: str, ns: str = "track") -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.ns = ns
        self.keys = Keys(ns)
        cmd = [sys.executable, "-m", "zenoh_track", "-l", self.endpoint, "--ns", ns, *extra]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})

    def feed(self, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "zenoh_track.clients.feed", *args, "-e", self.endpoint,
               "--ns", self.ns]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=True)

    def stop(self) -> str:
        """Terminate the service (then kill it); its stderr."""
        return stop(self.proc)


@pytest.fixture
def service_factory() -> Iterator:
    procs: list[ServiceProc] = []
    sessions: list[zenoh.Session] = []

    def start(*extra: str, ns: str = "track") -> tuple[ServiceProc, zenoh.Session]:
        svc = ServiceProc(*extra, ns=ns)
        procs.append(svc)
        session = client_session(svc.endpoint)
        sessions.append(session)
        if not wait_for_tracker(session, svc.keys, 1, timeout=30):
            pytest.fail(f"service did not come up: {svc.stop()[-3000:]}")
        return svc, session

    yield start
    for s in sessions:
        s.close()
    for p in procs:
        p.stop()


DISPLAY_OPTIONS = {"blend", "blend_speed", "rate", "lag", "coast_after"}


def make_tracker(order: int = 2, q: float | None = None, **kw: Any) -> Tracker:
    """A single-model tracker (order 2: CV, 3: CA) whose config also takes the display's
    options (for the unit tests of the tracker and of the display state)."""
    disp = DisplayConfig(**{k: kw.pop(k) for k in list(kw) if k in DISPLAY_OPTIONS})
    return Tracker(TrackerConfig(filter=FilterSpec({2: "cv", 3: "ca"}[order], q), **kw,
                                 display=disp))


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels() -> None:
    """Compile the kernels once, before any service process starts (on a fresh clone it
    takes tens of seconds; the processes then load them from the cache), and let them
    serve in this process as in a service."""
    from zenoh_track.estimation import imm_jit, jit
    from zenoh_track.tracking import frame

    jit.load([imm_jit, frame])


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--update-digests", action="store_true", default=False,
                     help="tests/test_same_bytes.py: write the output digests of this run "
                          "to tests/data/same_bytes.json instead of comparing")
