"""track-record / track-replay: the MCAP format (written, read back, the display channel),
and through real processes on loopback: a lockstep service fed a replay of a recorded
feed publishes byte-identical `tracks/`."""

from __future__ import annotations

import io
import json
import math
import subprocess
import sys
import time
from collections import Counter, defaultdict

import numpy as np
import pytest
import zenoh
from conftest import Collector, ServiceProc, client_session
from foxglove_client import message_class

from zenoh_track.clients.feeds.replay import remapper
from zenoh_track.clients.lib.scene import SCENE_SCHEMA, TOPIC, headings, schema
from zenoh_track.clients.record.files import Recording, RecordingWriter, payload_time_ns
from zenoh_track.clients.record.record import distinct
from zenoh_track.wire import (
    MSGPACK_ENCODING,
    PROTOCOL_VERSION,
    f64_bin,
    pack,
    unpack,
    wait_for_tracker,
)

MP = MSGPACK_ENCODING


def frame(t: float, ids: list[str], pos: list[float], vel: list[float], sigma: list[float]
          ) -> bytes:
    return pack({"t": t, "ids": ids, "pos": f64_bin(pos), "vel": f64_bin(vel),
                 "sigma": f64_bin(sigma)})


def test_samples_come_back_byte_for_byte_with_their_times():
    out = io.BytesIO()
    w = RecordingWriter(out, "track", ["track/**"], scene_hz=2.0)
    meas = pack({"t": 5.0, "r": 1000.0, "az": 0.5})
    w.write("track/meas/r1/a", "put", MP, meas, 1_000, None)
    w.write("track/meas/r1/a", "put", MP, pack({"t": 6.5}), 1_000, 42)  # same receive time
    w.write("track/tracks/a", "delete", "zenoh/bytes", b"", 900, None)  # clock stepped back
    w.write("track/status", "put", "application/json", b'{"x": 1}', 2_000, None)
    w.finish(received=4)
    rec = Recording(io.BytesIO(out.getvalue()))
    assert rec.namespace == "track"
    assert rec.meta["zenoh-track"]["protocol"] == str(PROTOCOL_VERSION)
    assert json.loads(rec.meta["zenoh-track"]["keys"]) == ["track/**"]
    assert rec.meta["zenoh-track-end"]["received"] == rec.meta["zenoh-track-end"]["written"] \
        == "4"
    got = list(rec.samples(set(rec.channels)))
    assert [(s.key, s.kind, s.encoding, s.payload) for _, s in got] == [
        ("track/meas/r1/a", "put", MP, meas), ("track/meas/r1/a", "put", MP, pack({"t": 6.5})),
        ("track/tracks/a", "delete", "zenoh/bytes", b""),
        ("track/status", "put", "application/json", b'{"x": 1}')]
    logs = [s.log_time for _, s in got]
    assert logs == [1_000, 1_001, 1_002, 2_000]  # receive order kept, strictly increasing
    # publish time: the Zenoh timestamp when there is one, else the payload's t, else log
    assert [s.publish_time for _, s in got] == [5_000_000_000, 42, 1_002, 2_000]
    chans = {c.key: c for c in rec.channels.values()}
    assert chans["track/meas/r1/a"].count == 2
    summary = rec.reader.get_summary()
    encodings = {ch.topic: ch.message_encoding for ch in summary.channels.values()}
    assert encodings["track/meas/r1/a"] == "msgpack"
    assert encodings["track/status"] == "json"


def test_payload_time_reads_t_first_maps_and_any_other_map():
    assert payload_time_ns(pack({"t": 1.25, "x": 2})) == 1_250_000_000
    assert payload_time_ns(pack({"x": 2, "t": 3})) == 3_000_000_000  # t not first, an int
    assert payload_time_ns(pack({"t": float("nan")})) is None
    assert payload_time_ns(pack({"t": -4.0})) == 0  # before the epoch: clamped
    assert payload_time_ns(b"\xc1 junk") is None
    assert payload_time_ns(b"") is None


def test_frames_give_a_foxglove_scene_at_the_asked_rate():
    out = io.BytesIO()
    w = RecordingWriter(out, "ns1", ["ns1/**"], scene_hz=2.0, scene_marker=50.0)
    w.write("ns1/display/a", "put", MP, pack({"t": 0.0, "status": "confirmed"}), 1, None)
    ids, pos, vel = ["a", "b"], [1.0, 2.0, 3.0, -5.0, 0.0, 0.0], [0.0, 100.0, 0.0, 0, 0, 0]
    for k in range(31):  # 30 Hz frames over one second
        w.write("ns1/frame", "put", MP, frame(k / 30, ids, pos, vel, [400.0, 3.0]), 10 + k,
                None)
    w.finish(received=32)
    assert w.scenes == 3  # t = 0, 0.5 and 1.0
    rec = Recording(io.BytesIO(out.getvalue()))
    assert rec.other and list(rec.other.values()) == [TOPIC]
    scenes = [(sch, ch, m) for sch, ch, m in rec.reader.iter_messages() if ch.topic == TOPIC]
    assert len(scenes) == 3
    sch, ch, m = scenes[1]
    assert sch.name == SCENE_SCHEMA and sch.encoding == "protobuf"
    assert sch.data == schema(SCENE_SCHEMA)
    assert ch.message_encoding == "protobuf"
    assert m.publish_time == 500_000_000
    update = message_class(SCENE_SCHEMA, sch.data).FromString(m.data)
    assert update.deletions[0].type == 1  # all: ended tracks disappear
    confirmed, unknown = update.entities  # a by its display/ status, b without one
    assert (confirmed.id, unknown.id) == ("tracks/confirmed", "tracks/unknown")
    assert (confirmed.timestamp.seconds, confirmed.timestamp.nanos) == (0, 500_000_000)
    a = confirmed.cubes[0].pose.position
    assert (a.x, a.y, a.z) == (1.0, 2.0, 3.0)
    assert confirmed.spheres[0].size.x == 800.0  # 2 sigma
    assert not unknown.spheres  # sigma 3 m: within the 50 m cube
    assert unknown.cubes[0].size.x == 50.0
    assert [t.text for t in confirmed.texts] == ["a"]
    assert confirmed.cubes[0].color.g > confirmed.cubes[0].color.r  # confirmed: green
    assert not unknown.arrows  # standing still
    q = confirmed.arrows[0].pose.orientation
    assert rotate_x(q) == pytest.approx((0.0, 1.0, 0.0))  # +x turned to the velocity


def test_the_scene_of_several_instances_holds_every_instance_s_tracks():
    """Two instances' frames, each with its own tracks, arriving in either order: every
    instant's scene holds both (the client library's merge on the receive times; the
    first instant is drawn again when the second instance's first frame comes)."""
    out = io.BytesIO()
    w = RecordingWriter(out, "ns1", ["ns1/**"], scene_hz=2.0)
    for k in range(31):
        bodies = [pack({**unpack(frame(k / 30, [name], [float(k), 0.0, 0.0],
                                       [30.0, 0.0, 0.0], [1.0])), "instance": inst})
                  for name, inst in (("a0", "shard-a"), ("b1", "shard-b"))]
        for body in bodies if k % 2 else bodies[::-1]:
            w.write("ns1/frame", "put", MP, body, 10 + 2 * k, None)
    w.finish(received=62)
    rec = Recording(io.BytesIO(out.getvalue()))
    last: dict[int, list[str]] = {}  # the last scene of each instant
    for sch, ch, m in rec.reader.iter_messages(log_time_order=True):
        if ch.topic == TOPIC:
            update = message_class(SCENE_SCHEMA, sch.data).FromString(m.data)
            last[m.publish_time] = sorted(t.text for e in update.entities for t in e.texts)
    assert sorted(last) == [0, 500_000_000, 1_000_000_000]
    assert all(ids == ["a0", "b1"] for ids in last.values()), last


def rotate_x(q) -> tuple[float, float, float]:
    """The unit x vector rotated by quaternion q."""
    x, y, z, w = q.x, q.y, q.z, q.w
    return (1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y))


@pytest.mark.parametrize("v", [(1, 0, 0), (-1, 0, 0), (0, 0, 2), (3, -4, 5), (-1, 1e-12, 0)])
def test_arrow_heading_turns_x_onto_the_velocity(v):
    n = math.sqrt(sum(c * c for c in v))
    q = headings(np.array([v], dtype=float))[0]
    quat = type("Q", (), dict(zip("xyzw", [0.0, *q], strict=True)))
    assert rotate_x(quat) == pytest.approx(tuple(c / n for c in v), abs=1e-9)


def test_remap_moves_whole_prefixes_only():
    remap = remapper(["track=replay", "a/b=c"])
    assert remap("track/meas/r1/x") == "replay/meas/r1/x"
    assert remap("track") == "replay"
    assert remap("tracks/x") == "tracks/x"  # a prefix of chunks, not of characters
    assert remap("a/b/c") == "c/c"
    with pytest.raises(SystemExit, match="OLD=NEW"):
        remapper(["track"])


def test_overlapping_key_expressions_are_recorded_once():
    assert distinct(["track/**", "track/meas/**", "other/x"]) == ["track/**", "other/x"]
    assert distinct(["a/*", "a/*", "a/b"]) == ["a/*"]


# ------------------------------------------------------------------ through processes
class RecorderProc:
    """`track-record` as a Zenoh client of a service; `done()` waits for it to stop."""

    def __init__(self, endpoint: str, path: str, *keyexprs: str, ns: str = "track",
                 until: tuple[str, str] = ("--idle", "3")) -> None:
        self.path = path
        cmd = [sys.executable, "-m", "zenoh_track.clients.record.record", "-o", path, "--mode",
               "client",
               "-e", endpoint, "--ns", ns, *until, *keyexprs]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        line = self.proc.stderr.readline()  # its subscriptions are declared
        assert line.startswith("track-record: recording"), line + self.proc.stderr.read()

    def done(self, timeout: float = 120) -> str:
        out, err = self.proc.communicate(timeout=timeout)
        assert self.proc.returncode == 0, err
        return out


def tracks_by_key(path: str, ns: str) -> tuple[dict[str, list], Counter]:
    """`tracks/` samples of a recording per track (kind, payload), and counts per kind
    of key (meas, clock, tracks, ...)."""
    with open(path, "rb") as f:
        rec = Recording(f)
        per: dict[str, list] = defaultdict(list)
        kinds: Counter = Counter()
        for ch, s in rec.samples(set(rec.channels)):
            what = ch.key.split("/")[1]
            kinds[what] += 1
            if what == "tracks":
                per[ch.key.split("/", 1)[1]].append((s.kind, s.payload))
    return per, kinds


@pytest.mark.slow
def test_replayed_feed_gives_byte_identical_tracks(tmp_path):
    """Record a feed and the tracks of a lockstep service; replay the feed, remapped to
    another namespace, into a fresh lockstep service: every track's `tracks/` messages
    are the same bytes, and nothing recorded was lost."""
    first, second = str(tmp_path / "first.mcap"), str(tmp_path / "second.mcap")
    svc = ServiceProc("--clock", "lockstep")
    svc2 = None
    try:
        with client_session(svc.endpoint) as s:
            assert wait_for_tracker(s, svc.keys, 1, timeout=60)
            rec = RecorderProc(svc.endpoint, first, "track/meas/**", "track/clock",
                               "track/tracks/**", "track/frame")
            fed = svc.feed("swarm", "--targets", "20", "--duration", "30")
            status = next(iter(s.get("track/status", timeout=10))).ok.payload.to_bytes()
        summary = rec.done()
        sent = int(fed.stdout.split(": ")[2].split()[0])  # "track-feed: swarm: N measurements"
        accepted = unpack(status)["meas_accepted"]
        per1, kinds1 = tracks_by_key(first, "track")
        assert kinds1["meas"] == sent == accepted and kinds1["clock"] == 1
        assert kinds1["tracks"] == accepted  # one tracks/ message per accepted measurement
        assert kinds1["frame"] > 0 and "scene updates" in summary
        received, rest = summary.split(" samples received, ")
        assert received.split()[-1] == rest.split()[0]  # "N received, N written"

        svc2 = ServiceProc("--clock", "lockstep", ns="replay")
        with client_session(svc2.endpoint) as s2:
            assert wait_for_tracker(s2, svc2.keys, 1, timeout=60)
        rec2 = RecorderProc(svc2.endpoint, second, "replay/tracks/**", ns="replay")
        out = subprocess.run([sys.executable, "-m", "zenoh_track.clients.feeds.replay", first,
                             "--feed",
                              "--remap", "track=replay", "--fast", "-e", svc2.endpoint],
                             capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        assert out.stdout.startswith(f"track-replay: {sent + 1} samples"), out.stdout
        rec2.done()
        per2, kinds2 = tracks_by_key(second, "replay")
        assert kinds2["tracks"] == kinds1["tracks"]
        assert per2.keys() == per1.keys()
        for key, msgs in per1.items():
            assert per2[key] == msgs, key  # byte for byte, in order
    finally:
        svc.stop()
        if svc2 is not None:
            svc2.stop()


@pytest.mark.slow
def test_whole_session_replay_is_paced_and_remapped(tmp_path, service_factory):
    """A recorded session replayed without a service, into another namespace, at twice
    the recorded pace: every sample arrives, in order, within the scaled time span."""
    path = str(tmp_path / "session.mcap")
    svc, s = service_factory("--clock", "realtime")
    svc.feed("swarm", "--targets", "5", "--duration", "2", "--realtime")
    # a realtime service draws its tracks' frames as long as it runs: 3 s of them
    RecorderProc(svc.endpoint, path, "track/frame", until=("--duration", "3")).done()
    with open(path, "rb") as f:
        recording = Recording(f)
        frames = [sm.payload for _, sm in recording.samples(set(recording.channels))]
        logs = [sm.log_time for _, sm in recording.samples(set(recording.channels))]
    span = (logs[-1] - logs[0]) / 1e9
    assert len(frames) > 30 and span > 1.0
    got = Collector(s, "again/frame")
    start = time.monotonic()
    out = subprocess.run([sys.executable, "-m", "zenoh_track.clients.feeds.replay", path, "--remap",
                          "track=again", "--speed", "2", "-e", svc.endpoint],
                         capture_output=True, text=True, timeout=60)
    took = time.monotonic() - start
    assert out.returncode == 0, out.stderr
    assert got.wait_for(lambda ss: len(ss) == len(frames), timeout=30)
    assert got.bodies() == [unpack(f) for f in frames]
    assert took >= span / 2 * 0.95  # paced: not as fast as possible


def test_replay_refuses_a_file_that_is_not_a_recording(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file")
    out = subprocess.run([sys.executable, "-m", "zenoh_track.clients.feeds.replay", str(bad),
                          "--trackers", "0"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode != 0 and "cannot read" in out.stderr



def test_plot_draws_the_confirmed_tracks_and_the_rates(tmp_path):
    """--plot: paths from the frames, never-confirmed tracks counted and left out."""
    from zenoh_track.clients.record.recording_plot import paths, rates

    path = tmp_path / "r.mcap"
    with open(path, "wb") as out:
        w = RecordingWriter(out, "track", ["track/**"], scene_hz=0)
        for k in range(40):
            body = unpack(frame(k / 30, ["a", "clutter"], [k, 0, 0, 5, 5, 0], [1, 0, 0] * 2,
                                [1.0, 1.0]))
            body["status"] = bytes([1 if k >= 20 else 0, 0])  # "a" confirmed from k = 20
            w.write("track/frame", "put", MP, pack(body), 10**9 * k, None)
            w.write("track/meas/r/a", "put", MP, pack({"t": k / 30}), 10**9 * k + 1, None)
        w.finish(80)
    with open(path, "rb") as f:
        rec = Recording(f)
        trails, tentative = paths(rec, set(rec.channels))
        _, per_kind = rates(rec, set(rec.channels))
    assert set(trails) == {"a", "clutter"} and len(trails["a"]) == 4  # every 10th frame
    assert tentative == {"clutter"}
    assert per_kind["meas"].sum() == 40 and per_kind["frame"].sum() == 40
    png = tmp_path / "r.png"
    out = subprocess.run([sys.executable, "-m", "zenoh_track.clients.feeds.replay", str(path),
                         "--plot",
                          str(png)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_replay_waits_until_its_keys_have_subscribers():
    """A put made before Zenoh knows of a subscriber reaches nobody: the replay first
    waits until each of its keys has one (matching status), and gives up after its
    timeout on a key nobody subscribes."""
    from zenoh_track.clients.feeds.replay import await_subscribers
    from zenoh_track.wire import free_port, listen_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    listener = zenoh.open(listen_config(endpoint))
    replayer = client_session(endpoint)
    try:
        keys = [zenoh.KeyExpr("again/frame"), zenoh.KeyExpr("again/tracks/a")]
        sub = listener.declare_subscriber("again/**", lambda _: None)
        assert await_subscribers(replayer, keys, 30.0) == 2
        sub.undeclare()
        start = time.monotonic()
        assert await_subscribers(replayer, [zenoh.KeyExpr("nobody/here")], 0.3) == 0
        assert time.monotonic() - start >= 0.3
    finally:
        replayer.close()
        listener.close()
