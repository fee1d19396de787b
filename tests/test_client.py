"""The client library (docs/client.md) against the real service: frames as NumPy columns
(against the wire's plain reading), a feed checked before sending and the service's
reports of what it refused, the picture's queue, the queries; and its types (mypy)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from zenoh_track.adapter.encode import pack_frame
from zenoh_track.clients import Client, Frame, Rejected, connect
from zenoh_track.wire import STATUSES, decode_frame, free_port, listen_config, pack, unpack

ROOT = Path(__file__).resolve().parent.parent


def frame_bytes(n: int, status: bool = True) -> bytes:
    rng = np.random.default_rng(n)
    pos, vel = rng.normal(0, 1e4, (n, 3)), rng.normal(0, 200, (n, 3))
    body = pack_frame(12.5, pack([f"t-{i}" for i in range(n)]), pos, vel,
                      rng.uniform(1, 50, n), rng.integers(0, 3, n))
    if not status:
        msg = unpack(body)
        del msg["status"]
        body = pack(msg)
    return body


@pytest.mark.parametrize("n", [0, 1, 7, 1000])
def test_frame_columns_match_the_wires_reading(n):
    """Frame.decode (NumPy views) gives, row by row, what wire.decode_frame gives."""
    body = frame_bytes(n)
    frame, rows = Frame.from_payload(body), decode_frame(unpack(body))
    assert len(frame) == len(rows) == n and frame.t == 12.5
    assert frame.pos.shape == frame.vel.shape == (n, 3) and frame.sigma.shape == (n,)
    for i, row in enumerate(rows):
        assert frame.ids[i] == row["id"] and frame.status[i] == row["status"]
        assert frame.pos[i].tolist() == row["pos"] and frame.vel[i].tolist() == row["vel"]
        assert frame.sigma[i] == row["sigma"]
    if n:
        assert frame.track("t-0")["pos"].tolist() == rows[0]["pos"]
        assert frame.index(f"t-{n - 1}") == n - 1
        assert frame.confirmed().sum() == sum(r["status"] == "confirmed" for r in rows)
    assert frame.track("absent") is None


def test_frame_without_status_and_broken_frames():
    frame = Frame.from_payload(frame_bytes(3, status=False))
    assert frame.status.tolist() == ["-"] * 3 and not frame.confirmed().any()
    msg = unpack(frame_bytes(3))
    for key, value, words in (("pos", msg["pos"][:-8], "'pos' does not hold 3 rows"),
                              ("ids", "abc", "list of strings"),
                              ("sigma", [1.0, 2.0, 3.0], "'sigma' does not hold")):
        with pytest.raises(ValueError, match=words):
            Frame.decode({**msg, key: value})
    for payload in (b"\x01", pack({"t": 1.0}), b""):
        with pytest.raises(ValueError):
            Frame.from_payload(payload)
    assert STATUSES[frame_bytes(1)[-1]] in STATUSES  # the status bin is the last byte


@pytest.fixture
def lonely() -> Client:
    """A client whose session listens on its own free port (nobody on the other side):
    what a feed checks, it checks before anything is sent."""
    import zenoh

    with Client(zenoh.open(listen_config(f"tcp/127.0.0.1:{free_port()}")), ns="lonely") as c:
        yield c


def test_a_feed_refuses_what_the_contract_refuses_naming_the_field(lonely):
    feed = lonely.feed("radar-1")
    cases = [
        (lambda: feed.measure("a", t=1.0, r=-5.0, az=0.1), "'r' must be >= 0"),
        (lambda: feed.measure("a", t=float("nan"), pos=[0, 0, 0]), "'t' is not finite"),
        (lambda: feed.measure("a", t=1.0), "exactly one of polar"),
        (lambda: feed.measure("a b", t=1.0, pos=[0, 0]), "target chunk 'a b'"),
        (lambda: feed.measure("a", t=1.0, pos=[0, 0, 0], sigma=-1.0), "'sigma'"),
        (lambda: feed.scan(1.0, ["a", "b"], r=[10.0, -1.0], az=[0.0, 0.1]),
         r"row 1 \(b\): field 'r' must be >= 0"),
        (lambda: feed.scan(1.0, ["a", "b"], r=[10.0], az=[0.0]), "bin 'r' has 1 rows, 'ids' 2"),
        (lambda: feed.plots(1.0, pos=np.zeros((2, 4))), "rows of 2 or 3"),
        (lambda: feed.plots(1.0, r=[10.0, 5.0], az=[0.0, 9.0]), "detection 1: field 'az'"),
    ]
    for send, words in cases:
        with pytest.raises(Rejected, match=words):
            send()
    # what passes the check: plain values, lists and arrays
    feed.measure("a", t=1.0, r=1000.0, az=0.5, el=0.1, sr=5.0)
    feed.measure("a", t=np.float64(2.0), pos=np.array([1.0, 2.0, 3.0]), sigma=[1.0, 2.0, 3.0])
    feed.scan([1.0, 2.0], ["a", "b"], pos=np.ones((2, 3)), sigma=np.array([1.0, 2.0]))
    feed.plots(1.0, r=np.array([]), az=np.array([]))
    feed.clock(3.0)


@pytest.mark.slow
def test_feed_picture_and_queries_against_a_service(track):
    """Measurements in three forms reach the picture; a refused one (sent unchecked) comes
    back on errors/; tracks() and status() answer; advance() returns the due frame."""
    feed, pic = track.feed, track.picture
    for k in range(5):
        feed.measure("plane-1", t=float(k), pos=[100.0 * k, 0.0, 1000.0], sigma=1.0)
    feed.scan(4.0, ["b-1", "b-2"], pos=np.array([[0.0, 5000.0, 100.0], [0.0, -5000.0, 100.0]]),
              sigma=2.0)
    feed.plots(4.0, pos=np.array([[9000.0, 9000.0, 0.0]]), sigma=3.0)
    frame = track.advance(5.0)
    assert frame.t == pytest.approx(5.0, abs=1e-9)
    row = frame.track("plane-1")
    assert row["status"] == "confirmed" and row["pos"] == pytest.approx([500.0, 0, 1000.0],
                                                                        abs=1.0)
    assert {"b-1", "b-2", "plane-1"} <= set(frame.ids.tolist()) and len(frame) == 4
    feed.check = False
    feed.measure("plane-1", t=5.5, r=-1.0, az=0.0)
    (error,) = feed.wait_for_errors(1)
    assert error["key"].endswith("/meas/feed/plane-1") and "'r' must be >= 0" in error["reason"]
    status = track.client.status()
    assert status["meas_rejected"] == 1 and status["meas_accepted"] == 8
    assert set(track.client.tracks()) == set(frame.ids.tolist())
    assert pic.latest() is frame or pic.latest().t >= frame.t
    with track.client.picture() as late:  # a late joiner has the picture at once
        assert late.latest().t == frame.t and late.latest().id_list == frame.id_list
    with pytest.raises(TimeoutError, match="condition not met"):
        track.wait_for(lambda f: "nobody" in f.id_list, timeout=0.5)


@pytest.mark.slow
def test_the_picture_queue_keeps_the_newest_for_a_slow_reader(track_service):
    with connect(track_service.endpoint, ns=track_service.ns, wait=30) as c:
        feed, pic = c.feed("radar"), c.picture(maxlen=5)
        feed.measure("x", t=0.0, pos=[0.0, 0.0, 0.0])
        feed.clock(2.0)  # 60 frames (t < 2) for a reader that reads none
        last = pic.wait_for(lambda f: f.t > 1.96)
        assert pic.received == 60 and len(pic.queue) == 5 and pic.dropped == 55
        times = [f.t for f in (pic.next(timeout=1) for _ in range(5))]
        assert times == sorted(times) and times[-1] == last.t
        with pytest.raises(TimeoutError):
            pic.next(timeout=0.2)
        pic.close()
        assert list(pic) == []  # iteration ends once closed


@pytest.mark.slow
def test_the_library_passes_mypy_strict(tmp_path):
    """`mypy --strict` on the library and the plugin. mypy reads packages from folders, so
    the import name is laid out as links to service/'s entries and clients/."""
    pkg = tmp_path / "zenoh_track"
    pkg.mkdir()
    for entry in (ROOT / "service").iterdir():
        if entry.name != "__pycache__":
            (pkg / entry.name).symlink_to(entry)
    (pkg / "clients").symlink_to(ROOT / "clients")
    out = subprocess.run([sys.executable, "-m", "mypy", "--strict", "--follow-imports=silent",
                          "--cache-dir", str(tmp_path / "cache"), "-p", "zenoh_track.clients.lib",
                          "-m", "zenoh_track.clients", "-m", "zenoh_track.clients.pytest_plugin",
                          "-m", "zenoh_track.clients.pytest_enable"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300,
                         env={**os.environ, "MYPYPATH": str(tmp_path)})
    assert out.returncode == 0, out.stdout + out.stderr
    found = re.search(r"Success: no issues found in (\d+) source files", out.stdout)
    lib = len(list((ROOT / "clients" / "lib").glob("*.py")))
    assert found and int(found.group(1)) >= lib + 3, out.stdout  # the library and the plugin
