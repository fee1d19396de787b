"""Time faults and oversized input through the running service (docs/protocol.md §4.1,
§6.1): real processes, real Zenoh on loopback."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zenoh

from zenoh_track.wire import MAX_ROWS, f64_bin, pack, unpack

pytestmark = pytest.mark.slow
BLOCK = zenoh.CongestionControl.BLOCK


class Watch:
    """errors/ codes by input key, tracks/ puts and deletes by id, frames (t, wall)."""

    def __init__(self, s: zenoh.Session) -> None:
        self.cond = threading.Condition()
        self.errors: list[tuple[str, str]] = []
        self.tracks: list[tuple[str, str, dict | None]] = []
        self.frames: list[tuple[float, float]] = []
        self.subs = [s.declare_subscriber("track/errors/**", self._err),
                     s.declare_subscriber("track/tracks/*", self._trk),
                     s.declare_subscriber("track/frame", self._frm)]

    def _err(self, x: zenoh.Sample) -> None:
        b = unpack(x.payload.to_bytes())
        with self.cond:
            self.errors.append((b["key"], b["code"]))
            self.cond.notify_all()

    def _trk(self, x: zenoh.Sample) -> None:
        put = x.kind == zenoh.SampleKind.PUT
        with self.cond:
            self.tracks.append((str(x.key_expr).rsplit("/", 1)[1], "PUT" if put else "DELETE",
                                unpack(x.payload.to_bytes()) if put else None))
            self.cond.notify_all()

    def _frm(self, x: zenoh.Sample) -> None:
        t = unpack(x.payload.to_bytes())["t"]
        with self.cond:
            self.frames.append((t, time.monotonic()))
            self.cond.notify_all()

    def wait(self, pred, timeout: float = 30.0) -> bool:
        with self.cond:
            return self.cond.wait_for(pred, timeout)

    def codes(self) -> list[str]:
        with self.cond:
            return [c for _, c in self.errors]


def status(s: zenoh.Session, timeout: float = 10.0) -> dict:
    """The status reply; fails the test if none comes within `timeout` s."""
    replies = [r for r in s.get("track/status", timeout=timeout) if r.ok is not None]
    assert replies, f"no status reply within {timeout} s"
    return unpack(replies[0].ok.payload.to_bytes())


def meas(s: zenoh.Session, target: str, t: float, x: float = 0.0, sensor: str = "r1") -> None:
    s.put(f"track/meas/{sensor}/{target}", pack({"t": t, "pos": [x, 100.0, 50.0],
                                                 "sigma": 5.0}), congestion_control=BLOCK)


def test_absurd_far_duplicate_and_late_times_lockstep(service_factory):
    svc, s = service_factory("--clock", "lockstep", "--filter", "cv", "--no-display-keys")
    w = Watch(s)
    for k in range(6):
        meas(s, "a", float(k), 10.0 * k)
    meas(s, "a", 1e300)  # today's stall: every display instant up to 1e300
    meas(s, "a", 6.0 + 1e9)  # in range, but 1e9 s from the picture
    meas(s, "a", 5.0, 50.0)  # the same sensor again at the track's time: a duplicate
    meas(s, "a", 5.0, 50.0, sensor="r2")  # another sensor at that time: applied
    meas(s, "a", 4.5, 45.0)  # older than the track's last update
    st = status(s)
    assert w.wait(lambda: len(w.errors) >= 4)
    assert w.codes() == ["time_out_of_range", "time_far", "duplicate", "out_of_sequence"]
    assert st["meas_accepted"] == 7 and st["meas_rejected"] == 4
    for k in range(6, 9):
        meas(s, "a", float(k), 10.0 * k)
    s.put("track/clock", pack({"t": 9.0}), congestion_control=BLOCK)
    st = status(s)
    assert st["frames_published"] == 9 * 30 and st["frames_skipped"] == 0
    assert st["timeline_jumps"] == 0 and st["rejected_by_reason"] == {
        "time_out_of_range": 1, "time_far": 1, "duplicate": 1, "out_of_sequence": 1}
    assert w.wait(lambda: [b for _, kind, b in w.tracks if kind == "PUT"][-1]["updates"] == 10)
    last = [b for _, kind, b in w.tracks if kind == "PUT"][-1]
    assert abs(last["vel"][0] - 10.0) < 0.5


def test_jumps_of_hours_lockstep(service_factory):
    """Three hours forward and back: no flood of frames, stale tracks deleted, the tracks
    of the abandoned timeline dropped, frames resumed; status answered throughout."""
    svc, s = service_factory("--clock", "lockstep", "--filter", "cv", "--no-display-keys")
    w = Watch(s)
    for k in range(6):
        meas(s, "a", float(k), 10.0 * k)
    jump = 3 * 3600.0
    for k in range(12):  # a feed whose clock jumped 3 h ahead
        meas(s, "b", jump + k, 10.0 * k)
    st = status(s)
    assert w.wait(lambda: len(w.errors) >= 9)
    assert w.codes() == ["time_far"] * 9  # nine refused, the tenth starts a new timeline
    assert st["timeline_jumps"] == 1 and st["tracks"] == 1  # "a" was stale at the jump
    assert w.wait(lambda: ("a", "DELETE", None) in w.tracks)
    assert st["frames_published"] <= 6 * 30 + 2 * 30  # up to t = 5, then from the jump
    frames = [t for t, _ in w.frames]
    assert max(frames) < jump + 12 and not [t for t in frames if 6.0 <= t < jump + 9]
    assert st["frames_skipped"] >= 30 * (jump - 6)  # not published: no flood
    for k in range(12):  # and back again: the 3-h timeline is abandoned
        meas(s, "c", 100.0 + k, 10.0 * k)
    st = status(s)
    assert w.wait(lambda: len(w.errors) >= 18)
    assert w.codes()[9:] == ["time_far"] * 9 and st["timeline_jumps"] == 2
    assert w.wait(lambda: ("b", "DELETE", None) in w.tracks)
    assert st["tracks"] == 1  # "c"
    assert w.wait(lambda: any(100.0 <= t < 112.0 for t, _ in w.frames))
    def c_states() -> list[dict]:
        return [b for tid, kind, b in w.tracks if tid == "c" and kind == "PUT"]

    assert w.wait(lambda: len(c_states()) == 3)  # the tenth and the two after it
    assert c_states()[-1]["updates"] == 3 and np.isfinite(c_states()[-1]["P"]).all()


def test_a_feed_ahead_cannot_stall_lockstep(service_factory):
    """Feed B's clock runs ahead of feed A's: 1 h ahead it is refused and the frames follow
    A; 100 s ahead it pulls the frames, and A's measurements are still applied."""
    svc, s = service_factory("--clock", "lockstep", "--filter", "cv", "--no-display-keys",
                             "--delete-after", "1000")
    w = Watch(s)
    for k in range(10):
        meas(s, "a", float(k), 10.0 * k, sensor="A")
        meas(s, "b", 3600.0 + k, 10.0 * k, sensor="B")
    st = status(s)
    assert w.wait(lambda: len(w.errors) >= 10)
    assert w.codes() == ["time_far"] * 10 and st["timeline_jumps"] == 0
    assert st["frames_published"] == 9 * 30  # the frames follow A
    for k in range(10, 20):
        meas(s, "a", float(k), 10.0 * k, sensor="A")
        meas(s, "b", 100.0 + k, 10.0 * k, sensor="B")
    st = status(s)
    assert st["tracks"] == 2 and len(w.errors) == 10  # nothing refused this time
    # pulled ahead by B, not stalled
    assert w.wait(lambda: max(t for t, _ in w.frames) >= 100.0 + 18)
    # A's measurements, behind the picture, all applied
    assert w.wait(lambda: [b["updates"] for tid, kind, b in w.tracks
                           if tid == "a" and kind == "PUT"][-1] == 20)


def test_oversized_inputs_refused_and_service_answers(service_factory):
    svc, s = service_factory("--clock", "lockstep")
    w = Watch(s)
    meas(s, "a", 1.0)
    s.put("track/plots/big", b"\x81\xa1t" + b"\x00" * 30_000_000, congestion_control=BLOCK)
    s.put("track/meas/r1/a", pack({"t": 2.0, "pos": [0.0, 0.0, 0.0], "pad": "x" * 70_000}),
          congestion_control=BLOCK)
    n = MAX_ROWS + 1
    s.put("track/plots/rows", pack({"t": 2.0, "r": f64_bin([1.0] * n),
                                    "az": f64_bin([0.0] * n)}), congestion_control=BLOCK)
    st = status(s, timeout=30)
    assert w.wait(lambda: len(w.errors) >= 3)
    assert w.codes() == ["too_large"] * 3 and st["meas_rejected"] == 3
    meas(s, "a", 2.0, 5.0)
    assert status(s)["meas_accepted"] == 2


def test_realtime_frames_survive_time_faults(service_factory):
    """A realtime service fed at 10 Hz gets t = 1e300, a far time, garbage, then a feed
    that jumps 3 h ahead and later back: the frames never stop, the picture follows."""
    svc, s = service_factory("--clock", "realtime", "--filter", "cv", "--no-display-keys")
    w = Watch(s)
    base, w0 = 1000.0, time.time()
    phase = {"offset": 0.0, "prefix": "p"}
    stop = threading.Event()

    def feed() -> None:
        while not stop.is_set():
            t = base + phase["offset"] + time.time() - w0
            for i in range(3):
                meas(s, f"{phase['prefix']}{i}", t, 100.0 * i + 10.0 * (t - base))
            time.sleep(0.1)

    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    def tracked(prefix: str, since: int = 0) -> bool:  # this phase's tracks updated
        return {f"{prefix}{i}" for i in range(3)} <= {k for k, kind, _ in w.tracks[since:]
                                                       if kind == "PUT"}

    try:
        assert w.wait(lambda: tracked("p"))
        meas(s, "p0", 1e300)
        meas(s, "p0", 1e8)
        s.put("track/meas/r1/p0", b"\xc1\xc1", congestion_control=BLOCK)
        assert w.wait(lambda: len(w.errors) >= 3)
        seen = len(w.tracks)  # the feed's own times taken again (the far one not in a row)
        assert w.wait(lambda: tracked("p", seen))
        phase.update(offset=3 * 3600.0, prefix="h")  # the feed's clock jumps 3 h ahead
        assert w.wait(lambda: tracked("h"))  # the new timeline taken
        phase.update(offset=0.0, prefix="q")  # and back
        assert w.wait(lambda: tracked("q"))

        def back_a_second() -> bool:  # a second of frames since the last 3 h ahead
            ahead = [wall for t, wall in w.frames if t > base + 3600.0]
            return bool(ahead) and w.frames[-1][1] - ahead[-1] > 1.0

        assert w.wait(back_a_second)
        st = status(s)
    finally:
        stop.set()
        feeder.join()
    assert st["timeline_jumps"] == 2, st
    assert w.wait(lambda: len(w.errors) >= 3 + 2 * 9), w.codes()
    codes = w.codes()
    assert codes[:3] == ["time_out_of_range", "time_far", "not_msgpack"], codes
    assert codes.count("time_far") == 1 + 2 * 9, codes
    frames = np.array(w.frames)
    walls = frames[:, 1]
    # never stopped: 30 Hz, and no gap of a second even on a loaded machine (before the
    # time policy, one t = 1e300 stopped them for good)
    assert np.diff(walls).max() < 1.0, np.diff(walls).max()
    assert len(walls) > 10 * (walls[-1] - walls[0]), len(walls)
    late = frames[walls > walls[-1] - 1.0, 0]
    assert (abs(late - (base + time.time() - w0)) < 5.0).all()  # back on the base timeline
    # each abandoned timeline's tracks deleted
    assert w.wait(lambda: {"p0", "h0"} <= {tid for tid, kind, _ in w.tracks
                                           if kind == "DELETE"})
    assert st["tracks"] == 3
