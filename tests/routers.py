"""Loopback topologies behind a router: `track-router` processes, client sessions from the
deploy/ config files, and a collector that stamps each sample with its arrival time."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

from zenoh_track.clients.lib.process import stop
from zenoh_track.wire import quick_retry, unpack

ROOT = Path(__file__).resolve().parent.parent
DEPLOY = ROOT / "deploy"
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


class RouterProc:
    """`track-router -c CONFIG -l ENDPOINT` as a process; `start` returns once it listens."""

    def __init__(self, config: Path, endpoint: str) -> None:
        self.config, self.endpoint = config, endpoint
        self.proc: subprocess.Popen | None = None

    def start(self) -> float:
        """Start the router; the monotonic time at which it said it was listening."""
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "zenoh_track.router", "-c", str(self.config),
             "-l", self.endpoint], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, env=ENV)
        line = self.proc.stdout.readline()
        up = time.monotonic()
        if "listening on" not in line:
            raise RuntimeError(f"router did not start: {line!r} {stop(self.proc)[-2000:]}")
        return up

    def stop(self) -> str:
        err, self.proc = stop(self.proc), None
        return err


def client_conf(config: Path, endpoint: str) -> zenoh.Config:
    """A deploy/ client config with its connect endpoint moved to `endpoint` (and the
    programs' connect/retry where the file sets none)."""
    conf = zenoh.Config.from_file(str(config))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return quick_retry(conf)


class Stamped:
    """Every sample of a key expression as (monotonic arrival time, key, kind, body)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.samples: list[tuple[float, str, str, Any]] = []
        self.cond = threading.Condition()
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, s: Any) -> None:
        put = s.kind == zenoh.SampleKind.PUT
        body = unpack(s.payload.to_bytes()) if put else None
        with self.cond:
            self.samples.append((time.monotonic(), str(s.key_expr),
                                 "PUT" if put else "DELETE", body))
            self.cond.notify_all()

    def wait_for(self, pred, timeout: float) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: pred(self.samples), timeout)

    def snapshot(self) -> list[tuple[float, str, str, Any]]:
        with self.cond:
            return list(self.samples)


def ids_since(samples: list, t0: float) -> dict[str, float]:
    """Each key's last chunk -> arrival of its first PUT at or after monotonic t0."""
    out: dict[str, float] = {}
    for t, key, kind, _ in samples:
        if kind == "PUT" and t >= t0:
            out.setdefault(key.rsplit("/", 1)[1], t)
    return out
