"""Unlabelled scans through the real service over Zenoh on loopback: a reduced crossing
scenario with clutter from two radars at different positions and scan phases, sent out
of order within the reorder lag; labelled measurements in the same picture; bad
detections reported; deletions announced."""

from __future__ import annotations

import math
import struct

import msgpack
import numpy as np
import pytest
from conftest import Collector

from zenoh_track.wire import Keys, unpack

pytestmark = pytest.mark.slow

SIGMA = 25.0


def plots_payload(t: float, dets: np.ndarray, sensor_pos=(0.0, 0.0, 0.0),
                  columnar: bool = False) -> bytes:
    msg: dict = {"t": t, "sigma": SIGMA, "sensor_pos": list(sensor_pos)}
    if columnar:
        msg["pos"] = struct.pack(f"<{dets.size}d", *dets.ravel())
        msg["dim"] = dets.shape[1]  # extension: the width of the rows of a pos bin
    else:
        msg["dets"] = [{"pos": [float(x), float(y)]} for x, y in dets]
    return msgpack.packb(msg, use_bin_type=True)


def truth_at(t: float, n: int = 6) -> np.ndarray:
    """n targets at 120 m/s crossing near the origin at t = 10 s."""
    ang = np.arange(n) * math.pi / n
    vel = 120.0 * np.stack([np.cos(ang), np.sin(ang)], 1)
    return vel * (t - 10.0) + 30.0 * np.stack([np.sin(ang), -np.cos(ang)], 1)


def query(session, keys: Keys, what: str) -> list:
    return [unpack(r.ok.payload.to_bytes()) for r in session.get(what, timeout=10.0)
            if r.ok is not None]


def test_crossing_two_radars_out_of_order(service_factory):
    svc, s = service_factory("--clock", "lockstep", "--filter", "cv", "--pd", "0.9")
    keys = svc.keys
    errors = Collector(s, keys.errors("*"))
    deleted = Collector(s, keys.tracks("*"))
    rng = np.random.default_rng(5)
    pubs = {name: s.declare_publisher(keys.plots(name)) for name in ("north", "south")}
    for k in range(20):
        # radar "south" scans 0.3 s after "north"; its scan is sent first (out of order)
        for name, t in (("south", k + 0.3), ("north", float(k))):
            truth = truth_at(t)
            seen = rng.random(len(truth)) < 0.9
            dets = truth[seen] + rng.normal(0, SIGMA, (int(seen.sum()), 2))
            clutter = rng.uniform(-3000, 3000, (8, 2))
            pubs[name].put(plots_payload(t, np.vstack([dets, clutter]),
                                         columnar=(name == "south")))
    # one bad detection (negative sigma) and one malformed scan
    pubs["north"].put(msgpack.packb({"t": 20.0, "dets": [{"pos": [0.0, 0.0], "sigma": -1.0},
                                                         {"pos": [5.0, 5.0]}]},
                                    use_bin_type=True))
    pubs["north"].put(msgpack.packb({"t": 20.5, "dets": 7}, use_bin_type=True))
    s.put(keys.clock, msgpack.packb({"t": 20.6}))
    status = query(s, keys, keys.status)[0]
    assert status["scans_applied"] == 41 and status["scans_held"] == 0
    assert errors.wait_for(lambda xs: len(xs) >= 2, 30)
    reasons = [b["reason"] for b in errors.bodies()]
    assert any(r.startswith("detection 0:") for r in reasons)
    assert any("dets" in r for r in reasons)
    # a scan older than what was applied is refused, not applied out of order
    pubs["north"].put(plots_payload(3.0, truth_at(3.0)))
    assert errors.wait_for(lambda xs: any("late scan" in b["reason"]
                                          for _, _, b in xs if b), 30)
    states = query(s, keys, keys.tracks("**"))
    truth = truth_at(20.0)
    est = np.array([st["pos"][:2] for st in states if st["updates"] >= 5])
    dist = np.linalg.norm(est[:, None] - truth[None], axis=2)
    assert (dist.min(0) < 150).all(), dist.min(0)  # every target has an established track
    assert all(st["id"].split("-")[0] in ("north", "south") for st in states)
    # labelled measurements share the picture
    s.put(keys.meas("sim", "blue-1"), msgpack.packb({"t": 21.0, "pos": [1.0, 2.0, 3.0]}))
    s.put(keys.clock, msgpack.packb({"t": 21.0}))
    ids = {st["id"] for st in query(s, keys, keys.tracks("**"))}
    assert "blue-1" in ids and len(ids) > 6
    # after the targets fall silent, their tracks are deleted by misses and announced
    for k in range(21, 30):
        pubs["north"].put(plots_payload(float(k), np.zeros((0, 2))))
    s.put(keys.clock, msgpack.packb({"t": 30.0}))
    query(s, keys, keys.status)
    assert deleted.wait_for(lambda xs: sum(kind == "DELETE" and "/north-" in key
                                           for key, kind, _ in xs) >= 1, 30)
    left = {st["id"] for st in query(s, keys, keys.tracks("**"))}
    assert not any(i.startswith("north-") for i in left)
    assert "blue-1" in left
