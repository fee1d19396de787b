"""A machine's first start: the service is alive and tracking at once on the kernels'
NumPy forms while a child process compiles them (`estimation.jit`), then takes the
compiled ones. A cold cache is made by pointing Numba at an empty directory."""

from __future__ import annotations

import time

import pytest
import zenoh
from conftest import Collector

from zenoh_track.clients.lib import ServiceProcess
from zenoh_track.wire import pack, unpack

pytestmark = pytest.mark.slow


def status(s: zenoh.Session) -> dict:
    replies = [r for r in s.get("track/status", timeout=10.0) if r.ok is not None]
    assert replies, "no status reply"
    return unpack(replies[0].ok.payload.to_bytes())


def test_a_cold_cache_serves_at_once_and_takes_the_compiled_kernels_when_ready(tmp_path):
    svc = ServiceProcess(clock=None, env={"NUMBA_CACHE_DIR": str(tmp_path)})  # realtime
    try:
        s = svc.wait(timeout=60).session
        # alive while the child compiles: the cache was empty, compiling takes seconds
        assert status(s)["kernels"] == "compiling"
        got = Collector(s, "track/tracks/a1")
        for k in range(3):
            s.put("track/meas/r1/a1", pack({"t": float(k), "pos": [100.0 * k, 5.0, 1.0],
                                            "sigma": 10.0}))
        assert got.wait_for(lambda smp: at(smp, 2.0))
        assert status(s)["kernels"] == "compiling"  # tracked by the NumPy forms
        wait(lambda: status(s)["kernels"] == "compiled", 600)
        assert list(tmp_path.rglob("*.nbi")), "the child compiled into the cache"
        s.put("track/meas/r1/a1", pack({"t": 3.0, "pos": [300.0, 5.0, 1.0], "sigma": 10.0}))
        assert got.wait_for(lambda smp: at(smp, 3.0))  # and the compiled kernels go on
        assert at(got.samples, 3.0)["x"][0] == pytest.approx(300.0, abs=20.0)
    finally:
        svc.stop()


def at(samples: list, t: float) -> dict | None:
    """The `tracks/` body of time t among the samples, if any."""
    return next((b for _, _, b in samples if b is not None and b["t"] == t), None)


def wait(cond, timeout: float) -> None:
    """Ask again until a condition read by a query (the status) holds."""
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.2)  # between queries: nothing announces the kernels' state
