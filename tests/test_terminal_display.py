"""track-display: the table's sorting, filtering and paging, the health line, the keys;
and the program itself against a real service, as text (`--once`) and in a terminal
(a pty: keys typed, screens read)."""

from __future__ import annotations

import os
import re
import select
import subprocess
import sys
import time

import pytest
from conftest import Collector

from zenoh_track.clients.display.display import handle
from zenoh_track.clients.display.model import Frame, Health, Table, fmt_t
from zenoh_track.clients.lib.process import stop
from zenoh_track.wire import f64_bin, pack


def frame_msg(t: float, ids: list[str], pos: list[list[float]], vel: list[list[float]],
              sigma: list[float], status: bytes | None = None) -> dict:
    msg = {"t": t, "ids": ids, "pos": f64_bin([c for p in pos for c in p]),
           "vel": f64_bin([c for v in vel for c in v]), "sigma": f64_bin(sigma)}
    if status is not None:
        msg["status"] = status
    return msg


def table_of(n: int = 25, **kw) -> Table:
    ids = [f"t-{i:03d}" for i in range(n)]
    pos = [[1000.0 * i, -50.0 * i, 10.0] for i in range(n)]
    vel = [[0.0, float((7 * i) % n), 0.0] for i in range(n)]  # speeds 0..n-1, shuffled
    table = Table(**kw)
    table.on_frame(Frame.decode(frame_msg(10.466666666666667, ids, pos, vel,
                                          [float(i) for i in range(n)],
                                          bytes(i % 3 for i in range(n)))))
    for i in range(0, n, 2):  # every other track was updated; the rest: age unknown
        table.on_update(ids[i], 10.0)
    return table


def test_sort_filter_and_pages():
    table = table_of(page_size=10)
    v = table.view()
    assert (v.total, v.matched, v.pages) == (25, 25, 3)
    assert [r["id"] for r in v.rows] == [f"t-{i:03d}" for i in range(10)]
    table.set_sort("speed")
    table.set_sort("speed")  # twice: descending
    speeds = [float(r["speed"]) for r in table.view().rows]
    assert speeds == sorted(speeds, reverse=True) and speeds[0] == 24.0
    table.turn(5)  # past the end: the last page
    v = table.view()
    assert (v.page, v.first, len(v.rows)) == (2, 20, 5)
    table.set_filter(" t-01 ")
    v = table.view()
    assert v.matched == 10 and all(r["id"].startswith("t-01") for r in v.rows)
    assert v.page == 0  # a new filter shows its first page
    table.set_sort("age")
    ages = [r["age"] for r in table.view().rows]
    assert ages[:5] == ["0.5"] * 5 and ages[5:] == ["-"] * 5  # unknown ages last
    table.set_filter("nothing")
    assert table.view().rows == [] and table.view().pages == 1


def test_numbers_are_readable_and_status_comes_from_the_frame():
    row = table_of().view().rows[1]
    assert row == {"id": "t-001", "x": "1,000", "y": "-50", "z": "10", "range": "1.00",
                   "speed": "7.0", "heading": "0", "sigma": "1.0", "status": "confirmed",
                   "age": "-"}
    assert fmt_t(10.466666666666667) == "10.467 s"
    v = table_of().view()
    assert {r["status"] for r in v.rows} == {"tentative", "confirmed", "coasting"}


def test_frames_of_protocol_1_have_no_status_and_deleted_tracks_leave():
    table = table_of()
    table.on_frame(Frame.decode(frame_msg(11.0, ["t-000"], [[0, 0, 0]], [[0, 0, 0]], [1.0])))
    v = table.view()
    assert [r["id"] for r in v.rows] == ["t-000"] and v.rows[0]["status"] == "-"
    assert v.rows[0]["age"] == "1.0"
    assert set(table.updated) == {"t-000"}
    table.on_frame(Frame.decode(frame_msg(9.0, [], [], [], [])))  # older: ignored
    assert table.view().total == 1


def test_health_line_rates_and_a_missing_tracker():
    h = Health()
    assert h.line("ns1") == ("no tracker alive on 'ns1'", False)
    h.alive.add("abc")
    base = {"instance": "abc", "clock": "lockstep", "rate": 30.0, "uptime_s": 3725.2,
            "meas_accepted": 12345, "meas_rejected": 10, "frames_published": 300, "queue": 2}
    h.on_status(base, wall=100.0)
    h.on_status({**base, "meas_rejected": 16, "frames_published": 360}, wall=102.0)
    line, ok = h.line("ns1")
    assert ok and "tracker abc alive" in line and "up 1:02:05" in line
    assert "accepted 12,345" in line and "rejected 16 (3.0/s)" in line
    assert "frames 360 (30.0/s)" in line
    h.on_status({**base, "instance": "other"}, wall=103.0)  # a restart: no rate across it
    assert h.rejects_per_s == 3.0


def test_keys():
    table = table_of(page_size=10)
    editing, quit_ = handle("/", table, None)
    assert editing == "" and not quit_
    for k in "t-02":
        editing, _ = handle(k, table, editing)
    editing, _ = handle("x", table, editing)
    editing, _ = handle("backspace", table, editing)
    editing, _ = handle("enter", table, editing)
    assert editing is None and table.filter == "t-02"
    handle("c", table, None)
    assert table.filter == ""
    handle("6", table, None)
    assert (table.sort, table.reverse) == ("speed", False)
    handle("6", table, None)
    assert table.reverse
    handle("n", table, None)
    handle("pgdn", table, None)
    assert table.view().page == 2
    handle("p", table, None)
    assert table.view().page == 1
    handle("G", table, None)
    assert table.view().page == 2
    handle("g", table, None)
    assert table.page == 0
    handle("s", table, None)
    assert table.sort == "heading"
    assert handle("q", table, None) == (None, True)
    editing, _ = handle("/", table, None)
    assert handle("esc", table, editing) == (None, False) and table.filter == ""


# ------------------------------------------------------------------ the real program
def bad_measurements(session, n: int) -> None:
    for _ in range(n):
        session.put("track/meas/radar9/bad", pack({"r": 1.0}))  # no t: rejected


@pytest.mark.slow
def test_once_prints_the_sorted_filtered_page_and_the_health(service_factory):
    svc, s = service_factory("--clock", "realtime")
    feed = subprocess.Popen([sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm",
                             "--targets", "20",
                             "--duration", "60", "--realtime", "-e", svc.endpoint],
                            stdout=subprocess.DEVNULL)
    try:
        frames = Collector(s, "track/frame")
        assert frames.wait_for(lambda ss: any(len(b[2]["ids"]) == 20 for b in ss), 60)
        bad_measurements(s, 3)
        out = subprocess.run([sys.executable, "-m", "zenoh_track.clients.display.display",
                             "--once", "-e",
                              svc.endpoint, "--sort", "speed", "--reverse", "--rows", "6",
                              "--filter", "swarm-0001"],
                             capture_output=True, text=True, timeout=60)
    finally:
        stop(feed)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert re.match(r"track-display  ns=track  t=[\d,]+\.\d{3} s  tracks=20  shown 1-6 of 10 "
                    r" page 1/2  sort speed ↓  filter 'swarm-0001'", lines[0]), lines[0]
    assert "alive" in lines[1] and re.search(r"rejected 3 \([\d.]+/s\)", lines[1]), lines[1]
    rows = [ln.split() for ln in lines if ln.strip().startswith("swarm-")]
    assert len(rows) == 6 and all(r[0].startswith("swarm-0001") for r in rows)
    speeds = [float(r[5]) for r in rows]
    assert speeds == sorted(speeds, reverse=True)
    assert all(r[8] in ("confirmed", "tentative", "coasting") for r in rows)
    assert not any(re.search(r"\d\.\d{4,}", ln) for ln in lines)  # no raw floats


ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]|\x1b[()][A-Z0-9]|\x1b[=>]")


class Terminal:
    """A program in a pseudo-terminal: what it drew (escape codes removed), keys typed."""

    def __init__(self, cmd: list[str]) -> None:
        self.master, slave = os.openpty()
        os.set_blocking(self.master, False)
        env = {**os.environ, "TERM": "xterm-256color", "COLUMNS": "140", "LINES": "30"}
        self.proc = subprocess.Popen(cmd, stdin=slave, stdout=slave, stderr=subprocess.PIPE,
                                     env=env, close_fds=True)
        os.close(slave)
        self.seen = ""

    def wait_for(self, pattern: str, timeout: float = 30.0) -> bool:
        """Until the screen text since the last call matches `pattern`."""
        deadline = time.monotonic() + timeout
        start = len(self.seen)
        while time.monotonic() < deadline:
            if re.search(pattern, self.seen[start:], re.S):
                return True
            ready, _, _ = select.select([self.master], [], [], 0.2)
            if ready:
                try:
                    self.seen += ANSI.sub("", os.read(self.master, 1 << 16).decode(
                        errors="replace"))
                except OSError:
                    break
        return bool(re.search(pattern, self.seen[start:], re.S))

    def type(self, keys: str) -> None:
        os.write(self.master, keys.encode())

    def close(self) -> str:
        err = stop(self.proc, timeout=5)
        os.close(self.master)
        return err


@pytest.mark.slow
def test_keys_in_a_terminal(service_factory):
    svc, s = service_factory("--clock", "realtime")
    feed = subprocess.Popen([sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm",
                             "--targets", "12",
                             "--duration", "60", "--realtime", "-e", svc.endpoint],
                            stdout=subprocess.DEVNULL)
    term = Terminal([sys.executable, "-m", "zenoh_track.clients.display.display", "-e",
                    svc.endpoint])
    try:
        assert term.wait_for(r"tracks=12 .*swarm-00011", 60), term.seen[-2000:]
        term.type("/00003\r")  # filter by id
        assert term.wait_for(r"shown 1-1 of 1 .*filter '00003'.*swarm-00003"), term.seen[-2000:]
        term.type("c6")  # clear, sort by speed
        assert term.wait_for(r"shown 1-12 of 12 .*sort speed ↑"), term.seen[-2000:]
        term.type("q")
        term.proc.wait(timeout=10)
        assert term.proc.returncode == 0
    finally:
        err = term.close()
        stop(feed)
    assert "Traceback" not in err, err


