"""Operator mistakes: one line on stderr, exit status 2, no traceback (real processes)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from zenoh_track.wire import free_port

pytestmark = pytest.mark.slow


def run(*args: str, program: str = "track-service", timeout: float = 60) -> tuple[int, str]:
    """The installed console script `program` (beside this interpreter) with `args`."""
    p = subprocess.run([str(Path(sys.executable).parent / program), *args],
                       capture_output=True, text=True, timeout=timeout,
                       env={**os.environ, "PYTHONUNBUFFERED": "1"})
    return p.returncode, p.stderr


def one_line(rc: int, err: str, *words: str) -> None:
    assert rc == 2, (rc, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in lines[0], lines[0]


def test_port_already_taken(service_factory):
    svc, _ = service_factory()
    one_line(*run("-l", svc.endpoint), "track-service: cannot listen on",
             svc.endpoint, "already in use")


def test_router_not_reached_after_retries():
    endpoint = f"tcp/127.0.0.1:{free_port()}"  # nobody listens there
    one_line(*run("--mode", "client", "-e", endpoint, "--connect-timeout", "1.5"),
             f"cannot reach {endpoint} after 1.5 s of retries")
    one_line(*run("radar3d", "--mode", "client", "-e", endpoint, "--connect-timeout", "1",
                  program="track-feed"), "track-feed: cannot reach", endpoint)


def test_unreadable_files(tmp_path):
    one_line(*run("-c", str(tmp_path / "missing.json5")),
             "cannot load the Zenoh configuration", "missing.json5", "No such file")
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    one_line(*run("-c", str(bad)), "cannot load the Zenoh configuration")
    one_line(*run("--sensors", str(tmp_path / "none.json")),
             "cannot read --sensors file", "No such file")
    sensors = tmp_path / "sensors.json"
    sensors.write_text("[1, 2]")
    one_line(*run("--sensors", str(sensors)), "--sensors", "not a JSON map")
    sensors.chmod(0)
    if os.geteuid() != 0:  # root reads anything
        one_line(*run("--sensors", str(sensors)), "Permission denied")
