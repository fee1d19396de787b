"""Soak, one minute (bench/bench_soak.py runs ten): the compose topology on loopback under
a realtime swarm, with a router restart, bad inputs, ghost targets that are deleted and a
slow subscriber. Nothing may be lost on the reliable keys outside the outage, every track
must come through, and at the end the service must still keep up."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
import bench_soak  # noqa: E402


@pytest.mark.slow
def test_one_minute_soak_with_faults():
    r = bench_soak.run(1.0, 100, log=lambda *_: None)
    print("\n" + bench_soak.report(r))
    assert r["alive"] and r["state_written"]
    assert r["gaps"] == 0  # no tracks/ update missing outside the outage
    assert r["errors_received"] == r["bad_sent"] == r["rejected"] > 30
    assert r["ghosts"] >= 8 and r["ghosts_deleted"] == r["ghosts"]
    assert r["ghosts_display_deleted"] == r["ghosts"]
    assert r["swarm_resumed"] == r["targets"] and r["swarm_deleted"] == 0
    assert r["tracks"] == r["targets"]
    assert r["slow_received"] > 0
    # at the end it still keeps up: tracks/ follow the measurements (not stalled), and
    # the memory has not run away
    assert not math.isnan(r["lat_last_p50"]) and r["lat_last_p50"] < 2.0
    assert r["rss_end_mb"] < r["rss_warm_mb"] + 100
