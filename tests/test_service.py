"""Loopback integration: the real service process, a real feed, real Zenoh sessions."""

from __future__ import annotations

import math

import numpy as np
import pytest
import zenoh
from conftest import Collector

from zenoh_track.wire import decode_frame, pack, unpack

pytestmark = pytest.mark.slow

REFERENCE_CMKF_RMSE = 1.07 * 108.0  # SCENARIOS.md B: UCM-CMKF at 1.07 x a 108 m bound


def frames_done(t_end: float):
    return lambda ss: any(b is not None and b["t"] >= t_end - 1e-9 for _, _, b in ss)


def by_key(collector: Collector) -> dict[tuple[str, float], dict]:
    return {(k.rsplit("/", 1)[1], round(b["t"], 6)): b for k, kind, b in collector.samples
            if kind == "PUT"}


def test_radar3d_lockstep_accuracy_and_frames(service_factory):
    svc, s = service_factory("--clock", "lockstep", "--filter", "cv")
    tracks = Collector(s, "track/tracks/*")
    truth = Collector(s, "track/truth/*")
    frames = Collector(s, "track/frame")
    runs = 100
    svc.feed("radar3d", "--runs", str(runs), "--truth", "--seed", "7")
    # the feed's closing clock message (t = 200) releases every frame before t = 200
    assert frames.wait_for(frames_done(199 + 29 / 30))
    # every measurement's tracks/ message (another key than frame: not ordered with it)
    assert tracks.wait_for(lambda smp: len(smp) >= runs * 200)
    est, tru = by_key(tracks), by_key(truth)
    assert len(tru) == runs * 200
    sq = np.zeros((200, runs))
    for (tid, t), b in tru.items():
        e = est[(tid, t)]  # every measurement accepted, one tracks/ message each
        sq[int(round(t)), int(tid.split("-")[1])] = np.sum(
            (np.array(e["pos"]) - np.array(b["pos"])) ** 2)
    rmse = math.sqrt(sq[20:].mean())
    assert abs(rmse / REFERENCE_CMKF_RMSE - 1) < 0.15, rmse
    # 30 Hz lockstep frames: every instant n/30 from 0 to just before 200, once, in order
    ts = [b["t"] for b in frames.bodies()]
    assert len(ts) == 200 * 30
    assert np.allclose(np.diff(ts), 1 / 30) and ts[0] == 0.0
    last = frames.bodies()[-1]
    assert len(last["ids"]) == runs and len(last["pos"]) == runs * 3 * 8


def test_frames_between_scans_are_predictions(service_factory):
    """Scenario A (exact positions, CA model): frames at scan instants equal the
    measurement; frames between scans are predictions from the earlier scan."""
    svc, s = service_factory("--clock", "lockstep", "--filter", "ca")
    frames = Collector(s, "track/frame")
    display = Collector(s, "track/display/*")
    truth = Collector(s, "track/truth/*")
    svc.feed("display", "--truth")
    assert frames.wait_for(frames_done(56 + 29 / 30))
    tru = {round(b["t"], 6): b for b in truth.bodies()}
    fr = {round(b["t"], 6): decode_frame(b)[0] for b in frames.bodies() if b["ids"]}
    for t in range(3, 57):
        assert np.allclose(fr[float(t)]["pos"], tru[float(t)]["pos"], atol=1e-3)
    # between scans the frame moves on the filter's own prediction: constant acceleration
    p = np.array([fr[round(10 + j / 30, 6)]["pos"] for j in range(30)])
    second = p[2:] - 2 * p[1:-1] + p[:-2]
    assert np.allclose(second, second[0], atol=1e-9)
    disp = display.bodies()
    assert all(np.isfinite(d["pos"]).all() and np.isfinite(d["sigma"]) for d in disp)
    assert {d["status"] for d in disp} >= {"tentative", "confirmed"}
    # the frame's status bin says what display/ says at the same instant
    shown = {(round(d["t"], 6), d["id"]): d["status"] for d in disp}
    framed = {(round(b["t"], 6), r["id"]): r["status"]
              for b in frames.bodies() for r in decode_frame(b)}
    assert framed == shown


def test_status_query_errors_and_recovery(service_factory):
    svc, s = service_factory("--clock", "lockstep")
    errors = Collector(s, "track/errors/**")
    tracks = Collector(s, "track/tracks/*")
    put = lambda key, msg: s.put(key, msg, congestion_control=zenoh.CongestionControl.BLOCK)  # noqa: E731
    for t in range(5):
        put("track/meas/r1/tgt", pack({"t": float(t), "pos": [100.0 * t, 0.0, 1000.0],
                                       "sigma": 5.0}))
    put("track/meas/r1/tgt", pack({"t": 5.0, "pos": [float("nan"), 0.0, 0.0]}))
    put("track/meas/r1/tgt", b"\xc1 not msgpack")
    put("track/meas/r1/tgt", pack({"t": 5.0, "pos": [500.0, 0.0], "sigma": 5.0}))  # 2-D vs 3-D
    put("track/meas/bad/sensor/extra", pack({"t": 5.0, "pos": [0.0, 0.0, 0.0]}))
    put("track/meas/r1/tgt", pack({"t": 5.0, "pos": [500.0, 0.0, 1000.0], "sigma": 5.0}))
    assert errors.wait_for(lambda ss: len(ss) >= 4)
    assert tracks.wait_for(lambda ss: len(ss) >= 6)
    reasons = [b["reason"] for b in errors.bodies()]
    assert any("not finite" in r for r in reasons)
    assert any("MessagePack" in r for r in reasons)
    assert any("3-D track" in r for r in reasons)
    assert any("<ns>/meas/<sensor>/<target>" in r for r in reasons)
    assert all(set(b) >= {"key", "reason", "t_wall"} for b in errors.bodies())
    last = tracks.bodies()[-1]
    assert last["updates"] == 6 and np.allclose(last["vel"], [100.0, 0.0, 0.0], atol=1.0)
    replies = list(s.get("track/status", timeout=10))
    st = unpack(replies[0].ok.payload.to_bytes())
    assert {"tracks", "meas_accepted", "meas_rejected", "frames_published", "uptime_s",
            "version"} <= set(st)
    assert st["tracks"] == 1 and st["meas_accepted"] == 6 and st["meas_rejected"] == 4
    assert st["frames_published"] == 5 * 30  # instants before t = 5
    got = [unpack(r.ok.payload.to_bytes()) for r in s.get("track/tracks/**", timeout=10)]
    assert [g["id"] for g in got] == ["tgt"] and len(got[0]["P"]) == len(got[0]["x"]) ** 2


def test_stale_track_deleted(service_factory):
    svc, s = service_factory("--clock", "lockstep", "--delete-after", "3")
    display = Collector(s, "track/display/*")
    for t in range(3):
        s.put("track/meas/r1/gone", pack({"t": float(t), "pos": [0.0, 10.0 * t]}),
              congestion_control=zenoh.CongestionControl.BLOCK)
    s.put("track/clock", pack({"t": 10.0}), congestion_control=zenoh.CongestionControl.BLOCK)
    assert display.wait_for(lambda ss: any(kind == "DELETE" for _, kind, _ in ss))
    st = unpack(next(iter(s.get("track/status", timeout=10))).ok.payload.to_bytes())
    assert st["tracks"] == 0 and st["tracks_deleted"] == 1, st


def test_scenarios_run_through_feed(service_factory):
    svc, s = service_factory("--clock", "lockstep")
    frames = Collector(s, "track/frame")
    # one timeline: each feed starts after the last (a restart 800 s back would be a
    # time fault, docs/protocol.md §6.1)
    for args, t0 in ((("display",), "0"), (("maneuver", "--runs", "3"), "100"),
                     (("swarm", "--targets", "50", "--duration", "10"), "1000")):
        svc.feed(*args, "--t0", t0)
    st = unpack(next(iter(s.get("track/status", timeout=10))).ok.payload.to_bytes())
    assert st["meas_rejected"] == 0
    # display's track ends at 56 s and is deleted during maneuver's 800 s
    assert st["tracks"] + st["tracks_deleted"] == 1 + 3 + 50
    assert frames.samples


def test_realtime_frames_follow_wall_clock(service_factory):
    svc, s = service_factory("--clock", "realtime")
    frames = Collector(s, "track/frame")
    svc.feed("swarm", "--targets", "20", "--duration", "2", "--realtime", "--t0", "1000")
    assert frames.wait_for(lambda ss: sum(1 for b in ss if b[2]["ids"]) >= 30, timeout=30)
    ts = np.array([b["t"] for b in frames.bodies()])
    n = np.round(ts * 30)
    assert np.allclose(ts * 30, n, atol=1e-6)  # display instants are multiples of 1/30
    assert (np.diff(n) >= 1).all()  # never repeated, never out of order
    assert ts[0] >= 999.0
