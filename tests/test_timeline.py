"""The time policy of docs/protocol.md §6.1, as `Timeline` decides it."""

from __future__ import annotations

from zenoh_track.adapter.clocks import Lockstep
from zenoh_track.adapter.timeline import Timeline


def test_near_inputs_taken_far_ones_refused():
    tl = Timeline(max_jump=600, confirm=3)
    assert tl.admit(0.0, None, 5) == (None, False)  # no picture time yet
    assert tl.admit(599.0, 0.0, 5) == (None, False)
    reason, jump = tl.admit(1e9, 0.0, 5)
    assert not jump and "from the picture's time" in reason and "2 more" in reason


def test_a_new_timeline_needs_inputs_in_a_row():
    tl = Timeline(max_jump=600, confirm=3)
    assert tl.admit(1e6, 0.0, 5)[0] is not None
    assert tl.admit(1e6 + 1, 0.0, 5)[0] is not None
    assert tl.admit(1.0, 0.0, 5) == (None, False)  # a near one: the count starts again
    assert tl.admit(1e6, 0.0, 5)[0] is not None
    assert tl.admit(1e6, 0.0, 5)[0] is not None
    assert tl.admit(1e6 + 2, 0.0, 5) == (None, True)
    assert tl.jumps == 1


def test_an_empty_picture_takes_any_time():
    tl = Timeline(max_jump=600, confirm=10)
    assert tl.admit(-5e9, 1e9, 0) == (None, True)


def test_lockstep_restart_skips_the_gap():
    clock = Lockstep(30.0)
    clock.due_before(0.0)
    assert len(clock.due_before(1.0)) == 30
    clock.restart(3600.0)
    assert clock.due_before(3600.0) == []  # the first input of the new timeline
    assert clock.skipped == 30 * 3599
    assert clock.due_before(3601.0)[0] == 3600.0
    clock.restart(10.0)  # backward: nothing skipped
    assert clock.due_before(10.0) == [] and clock.skipped == 30 * 3599
