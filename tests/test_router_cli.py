"""`track-router`: its config (file, then command line) and its operator errors."""

from __future__ import annotations

import json
import subprocess
import sys
import time

from routers import DEPLOY, ENV, RouterProc

from zenoh_track import router
from zenoh_track.wire import DEFAULT_ENDPOINT, free_port


def conf_of(*argv: str) -> dict:
    conf = router.router_config(router.parser().parse_args(list(argv)))
    return {k: json.loads(conf.get_json(k)) for k in
            ("mode", "listen/endpoints", "connect/endpoints", "scouting/multicast/enabled")}


def test_router_config_from_file_and_command_line():
    bare = conf_of()
    assert bare == {"mode": "router", "listen/endpoints": [DEFAULT_ENDPOINT],
                    "connect/endpoints": [], "scouting/multicast/enabled": False}
    from_file = conf_of("-c", str(DEPLOY / "router.json5"))
    assert from_file["listen/endpoints"] == ["tcp/0.0.0.0:7447"]
    moved = conf_of("-c", str(DEPLOY / "router.json5"), "-l", "tcp/127.0.0.1:9",
                    "-e", "tcp/127.0.0.1:10")
    assert moved["listen/endpoints"] == ["tcp/127.0.0.1:9"]
    assert moved["connect/endpoints"] == ["tcp/127.0.0.1:10"]


def run_router(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "zenoh_track.router", *argv],
                          capture_output=True, text=True, timeout=60, env=ENV)


def test_router_refuses_a_taken_port_and_a_bad_file_in_one_line(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    first = RouterProc(DEPLOY / "router.json5", endpoint)
    first.start()
    try:
        t0 = time.monotonic()
        second = run_router("-l", endpoint)
        assert second.returncode != 0 and time.monotonic() - t0 < 30
        assert "Traceback" not in second.stderr
        lines = second.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("track-router: cannot listen on"), \
            second.stderr
        assert second.returncode == 2
    finally:
        first.stop()
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    out = run_router("-c", str(bad))
    assert out.returncode != 0 and "Traceback" not in out.stderr
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1
    assert out.stderr.startswith("track-router: cannot load the Zenoh configuration"), out.stderr
    missing = run_router("-c", str(tmp_path / "none.json5"))
    assert missing.returncode == 2 and "Traceback" not in missing.stderr
    assert missing.stderr.startswith("track-router: cannot read the Zenoh configuration")
