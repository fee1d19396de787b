"""Unit tests of the display clocks (service/adapter/clocks.py) against the Clock
section of PROTOCOL.md; their one interface (`schedule.Clock`).

Display instants are n / rate. Lockstep: before an input at t, every instant strictly
before t (1 us tolerance) not yet published is due; the first input sets the start.
Realtime: simulation time = wall + offset, offset = max(t - wall) over a window, a jump
resets it, and due() returns at most one instant per call (the newest), counting the
ones it skipped. Wall times are passed explicitly; nothing sleeps.
"""

from __future__ import annotations

import numpy as np
import pytest

from zenoh_track.adapter import clocks as clock
from zenoh_track.adapter.plan import Frame, Plan
from zenoh_track.adapter.schedule import Clock

RATE = 30.0


def inst(*ns):
    return [n / RATE for n in ns]


# ---------------------------------------------------------------- lockstep
def test_first_input_sets_start_and_publishes_nothing():
    lk = clock.Lockstep(RATE)
    assert lk.due_before(0.1) == []


def test_instants_strictly_before_t():
    lk = clock.Lockstep(RATE)
    lk.due_before(0.1)  # start: 0.1 = 3/30 is the first instant, not yet published
    # instants n/30 < 0.2 = 6/30, from n = 3: 3, 4, 5 (not 6: it is the scan instant)
    assert lk.due_before(0.2) == inst(3, 4, 5)
    assert lk.due_before(0.2) == []  # none repeated
    # 0.2 + 0.5 us: 0.2 is within 1 us of t, so it is not "strictly before"
    assert lk.due_before(0.2 + 0.5e-6) == []
    # 0.2 + 2 us: now 0.2 is strictly before t
    assert lk.due_before(0.2 + 2e-6) == inst(6)
    assert lk.due_before(0.2 + 3e-6) == []


def test_input_going_back_in_time_publishes_nothing_and_repeats_nothing():
    lk = clock.Lockstep(RATE)
    lk.due_before(0.1)
    assert lk.due_before(0.2) == inst(3, 4, 5)
    assert lk.due_before(0.05) == []
    # 0.3 = 9/30: instants 6, 7, 8 are due, 3..5 are not repeated
    assert lk.due_before(0.3) == inst(6, 7, 8)


def test_start_between_instants():
    lk = clock.Lockstep(RATE)
    lk.due_before(0.105)  # 3/30 = 0.1 precedes the start and is never published
    assert lk.due_before(0.2) == inst(4, 5)


def test_exact_instant_input_frame_shows_the_update():
    # A scan at exactly t = 1.0 = 30/30: the frame at 1.0 is published only before the
    # next input, i.e. after the scan at 1.0 was applied.
    lk = clock.Lockstep(RATE)
    assert lk.due_before(1.0) == []
    assert lk.due_before(1.0) == []  # a second scan at the same instant
    assert lk.due_before(1.0 + 1 / 60) == inst(30)
    # next exact instant 31/30: due_before(31/30) must not include 31 itself
    assert lk.due_before(31 / RATE) == []
    assert lk.due_before(32 / RATE) == inst(31)


def test_first_input_tolerance():
    # First input 0.5 us after instant 30: that instant is not strictly before t (1 us
    # tolerance), so it is still due later. 2 us after: it is before the start.
    lk = clock.Lockstep(RATE)
    lk.due_before(1.0 + 0.5e-6)
    assert lk.due_before(1.05) == inst(30, 31)
    lk = clock.Lockstep(RATE)
    lk.due_before(1.0 + 2e-6)
    assert lk.due_before(1.05) == inst(31)


def test_accumulated_float_times_miss_and_repeat_nothing():
    # Scan times built by summing 0.1 (float error ~1e-14) and irregular gaps: the
    # concatenation of all due lists is every instant from the start to the last input,
    # in order, each once; after each call every instant < t - 1 us is published and
    # the next one is not.
    rng = np.random.default_rng(4)
    times, t = [], 0.0
    for _ in range(500):
        t += 0.1
        times.append(t)
    for gap in rng.uniform(0.0, 0.25, 500):
        t += gap
        times.append(t)
    lk = clock.Lockstep(RATE)
    lk.due_before(times[0])
    published: list[float] = []
    for t in times[1:]:
        due = lk.due_before(t)
        published += due
        if published:
            assert published[-1] < t - clock.TOL
        assert lk.next_n / RATE >= t - clock.TOL - 1e-12
    first = 3  # times[0] ~ 0.1 = 3/30
    assert published == [n / RATE for n in range(first, first + len(published))]
    assert lk.next_n == first + len(published)


def test_long_gap_is_capped():
    # A jump of 1000 s (30000 instants) replays only the newest MAX_GAP_FRAMES instants
    # and counts the rest: instants 0..29999 are before t = 1000; the cap keeps
    # 29999 - 18000 + 1 = 12000 .. 29999 and skips 12000.
    lk = clock.Lockstep(RATE)
    lk.due_before(0.0)
    due = lk.due_before(1000.0)
    assert len(due) == clock.MAX_GAP_FRAMES == 18000
    assert due[0] == 12000 / RATE and due[-1] == 29999 / RATE
    assert lk.skipped == 12000
    assert lk.due_before(1000.0 + 1 / 60) == inst(30000)


# ---------------------------------------------------------------- realtime
def test_nothing_before_first_input():
    rt = clock.Realtime(RATE)
    assert rt.due(1000.0) is None
    assert rt.next_deadline(1000.0) is None


def test_offset_is_max_of_t_minus_wall():
    rt = clock.Realtime(RATE, window=10.0, jump=2.0)
    rt.observe(100.0, 1000.0)  # offset 100 - 1000 = -900
    assert rt.offset == -900.0
    rt.observe(100.5, 1000.7)  # -900.2: a later-arriving (delayed) input, max stays -900
    assert rt.offset == -900.0
    rt.observe(101.1, 1001.0)  # -899.9 > -900: new max
    assert rt.offset == pytest.approx(-899.9, abs=1e-9)


def test_offset_window_expires_old_maximum():
    rt = clock.Realtime(RATE, window=10.0, jump=2.0)
    rt.observe(100.0, 1000.0)  # -900.0 at wall 1000
    rt.observe(104.5, 1005.0)  # -900.5 at wall 1005
    rt.observe(109.2, 1010.0)  # -900.8; wall 1000 is exactly 10 s old: still in window
    assert rt.offset == pytest.approx(-900.0)
    rt.observe(109.6, 1010.5)  # -900.9; wall 1000 < 1010.5 - 10 drops out -> max -900.5
    assert rt.offset == pytest.approx(-900.5)
    rt.observe(114.4, 1015.5)  # -901.1; wall 1005 < 1005.5 drops out -> max -900.8
    assert rt.offset == pytest.approx(-900.8)


def test_small_change_does_not_reset():
    rt = clock.Realtime(RATE, window=10.0, jump=2.0)
    rt.observe(100.0, 1000.0)
    rt.observe(98.6, 1000.5)  # -901.9: 1.9 s below the offset, within jump = 2
    assert rt.offset == -900.0


def test_jump_backwards_resets_offset_and_schedule():
    rt = clock.Realtime(RATE, window=10.0, jump=2.0)
    rt.observe(100.0, 1000.0)
    assert rt.due(1000.0) == 100.0  # n = 3000
    rt.observe(0.0, 1001.0)  # a new replay from t = 0: offset -1001, old max forgotten
    assert rt.offset == -1001.0
    assert rt.due(1001.0) == 0.0  # not blocked by the old last instant 3000
    assert rt.missed == 0


def test_jump_forwards_resets_without_counting_missed():
    rt = clock.Realtime(RATE, window=10.0, jump=2.0)
    rt.observe(100.0, 1000.0)
    assert rt.due(1000.0) == 100.0
    rt.observe(500.0, 1002.0)  # offset -502
    assert rt.offset == -502.0
    assert rt.due(1002.0) == 500.0
    assert rt.missed == 0  # the 12 000 instants between are a new timeline, not misses


def test_due_skips_and_counts_instead_of_bunching():
    rt = clock.Realtime(RATE)
    rt.observe(100.0, 1000.0)  # sim = wall - 900
    assert rt.due(1000.0) == 100.0  # 100 * 30 = instant 3000
    assert rt.due(1000.0) is None  # not repeated
    assert rt.due(1000.02) is None  # 100.02 * 30 = 3000.6 -> still 3000
    assert rt.due(1000.034) == 3001 / RATE  # 3001.02 -> 3001
    assert rt.missed == 0
    # The service stalls until 100.21 s sim (3006.3): one call returns only the newest
    # instant 3006, and 3002..3005 are counted as missed (4), not published in a burst.
    assert rt.due(1000.21) == 3006 / RATE
    assert rt.missed == 4
    assert rt.due(1000.22) is None


def test_next_deadline_absolute():
    rt = clock.Realtime(RATE)
    rt.observe(100.0, 1000.0)
    # before any frame: next instant after sim 100.01 (3000.3) is 3001 -> wall 3001/30 + 900
    assert rt.next_deadline(1000.01) == pytest.approx(3001 / RATE + 900.0, abs=1e-9)
    rt.due(1000.034)  # publishes 3001
    deadline = rt.next_deadline(1000.04)
    assert deadline == pytest.approx(3002 / RATE + 900.0, abs=1e-9)
    # at the deadline exactly, the instant is due (no float fall-through to None)
    assert rt.due(deadline) == 3002 / RATE


def test_realtime_long_run_monotonic_and_accounted():
    # Irregular wall ticks (some longer than a frame): published instants strictly
    # increase, and published + missed covers every instant from the first to the last.
    rng = np.random.default_rng(8)
    rt = clock.Realtime(RATE)
    rt.observe(50.0, 2000.0)
    wall, out = 2000.0, []
    for step in rng.uniform(0.005, 0.09, 2000):
        wall += step
        got = rt.due(wall)
        if got is not None:
            out.append(round(got * RATE))
    assert all(b > a for a, b in zip(out, out[1:], strict=False))
    assert len(out) + rt.missed == out[-1] - out[0] + 1
    assert rt.missed > 0  # steps up to 0.09 s > 1/30 s do skip instants


# ---------------------------------------------------------------- one interface
def protocol_members() -> list[str]:
    return sorted({*Clock.__annotations__, *(n for n in vars(Clock) if not n.startswith("_"))})


def test_both_clocks_answer_every_member_of_the_interface():
    """The worker asks the clock, never which clock it is: both have every member."""
    members = protocol_members()
    assert {"picture", "rows", "scan", "clock_message", "released", "apply", "end", "save",
            "load"} <= set(members)
    for c in (clock.make_clock("lockstep", RATE), clock.make_clock("realtime", RATE)):
        missing = [m for m in members if not hasattr(c, m)]
        assert not missing, (type(c).__name__, missing)
    with pytest.raises(ValueError):
        clock.make_clock("sundial", RATE)


def test_first_due_is_the_first_row_before_which_an_instant_falls_due():
    rng = np.random.default_rng(3)
    for lag, held in [(0.0, None), (0.05, None), (0.0, 1.3), (0.1, 0.9)]:
        lk = clock.Lockstep(RATE, lag)
        lk.due_before(0.5)
        t = np.sort(rng.uniform(0.4, 2.0, 60))
        for start in (1, 7, 59):
            want = next((i for i in range(start, len(t))
                         if lk.due_soon(t[i] if held is None else min(t[i], held))), None)
            assert lk.first_due(t, start, held) == want
        assert lk.first_due(t, 1, held) is not None  # the times run past an instant
    rt = clock.Realtime(RATE)
    rt.observe(100.0, 50.0)
    plan, frames = Plan(), Plan()
    rt.clock_message(plan, 200.0, 50.0, None)  # its instants fall due on the wall clock
    lk = clock.Lockstep(RATE)
    lk.due_before(2.0)
    lk.clock_message(frames, 3.0, 50.0, None)  # the lockstep's before an input
    assert not any(isinstance(s, Frame) for s in plan)
    assert [s.t for s in frames if isinstance(s, Frame)] == inst(*range(60, 90))


def test_the_lag_delays_the_instants_by_itself():
    lagged, plain = clock.Lockstep(RATE, lag=0.25), clock.Lockstep(RATE)
    for t in (1.0, 1.5, 2.0 + 1e-7, 3.3):
        assert lagged.due_before(t) == plain.due_before(t - 0.25)
    rt_lagged, rt = clock.Realtime(RATE, lag=0.25), clock.Realtime(RATE)
    for c in (rt_lagged, rt):
        c.observe(10.0, 1000.0)
    assert rt_lagged.due(1000.5) == rt.due(1000.5 - 0.25)


def test_the_picture_is_the_newest_input_in_lockstep_and_the_wall_clock_in_realtime():
    lk = clock.Lockstep(RATE)
    assert lk.picture(5.0, None) is None
    assert lk.picture(123.0, 3.0) == 3.0  # the newest input taken (`Admit.newest`)
    rt = clock.Realtime(RATE)
    assert rt.picture(5.0, None) is None
    rt.observe(10.0, 1000.0)
    assert rt.picture(1001.0, 99.0) == rt.sim_time(1001.0) == 11.0  # the wall clock's


def test_a_clock_resumes_from_its_saved_state_and_refuses_the_other_kinds():
    lk = clock.Lockstep(RATE)
    lk.due_before(1.0)
    lk.due_before(2.0)
    again = clock.Lockstep(RATE)
    saved = {**lk.save(), "picture_t": 2.0}  # the worker adds the picture's time
    assert again.load(saved, 0.0) == "; lockstep picture at t=2.000"
    assert again.next_n == lk.next_n
    assert again.due_before(2.1) == lk.due_before(2.1)
    rt = clock.Realtime(RATE)
    rt.observe(10.0, 1000.0)
    back = clock.Realtime(RATE)
    assert back.load(rt.save(), 2000.0).startswith("; realtime frames resume")
    assert back.picture(2000.0, None) == 1010.0
    fresh = clock.Realtime(RATE)
    assert fresh.load(lk.save(), 2000.0) == "" and fresh.offset is None
    assert clock.Lockstep(RATE).load(rt.save(), 0.0) == ""


class OnClock:
    """The clock recipe of docs/architecture.md's "Where to add": frames only when a clock
    message comes (every instant before its time), none before a measurement; a class
    satisfying `schedule.Clock`, registered in `clocks.CLOCKS`."""

    name, skipped, missed = "on-clock", 0, 0
    publishing = clock.Lockstep.publishing  # in line, nothing dropped

    def __init__(self, rate: float, lag: float = 0.0) -> None:
        self.instants = clock.Lockstep(rate, lag)  # its arithmetic of the instants

    def picture(self, wall, newest):
        return newest

    def timeout(self, wall):
        return 0.001

    def restart(self, t):
        self.instants.restart(t)

    def rows(self, plan, rows, walls, held):
        if self.instants.next_n is None:  # the first input sets the start
            self.instants.due_before(float(rows.batch.t[0]))
        plan.wait(rows)

    def scan(self, plan, t, wall, released, held):
        self.released(plan, released, held)

    def clock_message(self, plan, t, wall, held):
        for instant in self.instants.due_before(t):
            plan.frame(instant)

    def released(self, plan, scans, held):
        for key, scan in scans:
            plan.scan(key, scan)

    def apply(self, rows, frames, run, report):
        report(rows, run(rows, None))

    def end(self, plan, wall, admit, frames):
        plan.apply()

    def save(self):
        return {"kind": self.name}

    def load(self, saved, wall):
        return ""


def test_a_new_clock_is_one_class_and_one_registration(monkeypatch):
    """The recipe tried on a service with a real Zenoh session: measurements bring no
    frame; a clock message brings every instant before its time, showing them."""
    import zenoh

    from zenoh_track.adapter import TrackService
    from zenoh_track.adapter.ingest import ClockMessage, Singles
    from zenoh_track.tracking.tracker import Tracker
    from zenoh_track.wire import Keys, free_port, listen_config, pack

    assert not [m for m in protocol_members() if not hasattr(OnClock(RATE), m)]
    monkeypatch.setitem(clock.CLOCKS, "on-clock", OnClock)
    session = zenoh.open(listen_config(f"tcp/127.0.0.1:{free_port()}"))
    try:
        keys = Keys("oc")
        svc = TrackService(session, keys, Tracker.from_config(), clock="on-clock")
        for t in (0.0, 1.0, 2.0):
            svc._process([Singles.one(keys.meas("r1", "a"), pack({"t": t, "pos": [t, 0.0]}),
                                      100.0 + t)])
        assert svc.count.frames_published == 0 and len(svc.tracker) == 1
        svc._process([ClockMessage(keys.clock, pack({"t": 2.0}), 102.0)])
        assert svc.count.frames_published == 2 * RATE  # the instants of [0, 2)
        assert svc.out.latest[1].ids == ["a"]
        svc.close()
    finally:
        session.close()
