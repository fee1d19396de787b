"""The merge of several instances' frames into one picture per display instant
(`clients/lib/merge.py`): the union at every instant, no flicker, a late or skipping
instance, the hold, an instance gone or stalled; frames packed by the service's own
encoder and decoded as every client decodes them."""

from __future__ import annotations

import numpy as np
import pytest

from zenoh_track.adapter.encode import pack_frame
from zenoh_track.clients.lib.frames import Frame
from zenoh_track.clients.lib.merge import Merge
from zenoh_track.wire import pack

RATE = 30.0


def frame(instance: str, n: int, ids: list[str], speed: float = 10.0) -> Frame:
    """Instance `instance`'s frame at instant n: tracks moving east at `speed` from x = 0
    at t = 0."""
    t = n / RATE
    k = len(ids)
    pos = np.zeros((k, 3))
    pos[:, 0] = speed * t
    vel = np.zeros((k, 3))
    vel[:, 0] = speed
    body = pack_frame(t, pack(ids), pos, vel, np.ones(k), np.ones(k, np.uint8), instance)
    return Frame.from_payload(body)


A = [f"t-{i}0" for i in range(5)]
B = [f"t-{i}1" for i in range(3)]


def test_one_instance_passes_each_frame_as_it_came() -> None:
    m = Merge()
    for n in range(5):
        f = frame("a", n, A)
        assert m.add(f, wall=n / RATE) == [f]  # the very object: no wait, no copy


def test_two_instances_give_the_union_once_per_instant_in_any_order() -> None:
    m = Merge()
    m.add(frame("b", 0, B), 0.0, draw=False)  # a late joiner's replies
    m.add(frame("a", 0, A), 0.0, draw=False)
    drawn = m.ready(0.0)
    for n in range(1, 10):
        pair = [frame("a", n, A), frame("b", n, B)]
        for f in pair if n % 2 else pair[::-1]:
            drawn += m.add(f, wall=n / RATE)
    assert [round(f.t * RATE) for f in drawn] == list(range(10))
    for f in drawn:
        assert sorted(f.id_list) == sorted(A + B) and f.instances == ("a", "b")
        np.testing.assert_allclose(f.pos[:, 0], 10.0 * f.t)


def test_an_instance_one_instant_behind_holds_the_instant_not_the_count() -> None:
    """b draws each instant after a has drawn the next one: every picture holds both."""
    m = Merge()
    m.add(frame("a", 0, A), 0.0, draw=False)
    m.add(frame("b", 0, B), 0.0, draw=False)
    drawn = m.ready(0.0)
    for n in range(2, 8):
        drawn += m.add(frame("a", n, A), n / RATE)
        drawn += m.add(frame("b", n - 1, B), n / RATE + 0.001)
    assert [round(f.t * RATE) for f in drawn] == list(range(7))
    assert {len(f) for f in drawn} == {len(A) + len(B)}


def test_an_instance_that_skips_an_instant_does_not_hold_it() -> None:
    m = Merge(hold=None)
    m.add(frame("a", 0, A), 0.0, draw=False)
    m.add(frame("b", 0, B), 0.0, draw=False)
    drawn = m.ready(0.0)
    for n in (1, 2, 3):
        drawn += m.add(frame("a", n, A), n / RATE)
    assert len(drawn) == 1  # b holds 1/30 s up (no hold bound here)
    drawn += m.add(frame("b", 3, B), 0.2)  # b was late: 1 and 2 skipped
    assert [round(f.t * RATE) for f in drawn] == [0, 1, 2, 3]
    one = drawn[1]  # b's frame at 0 moved on to 1/30 s
    assert sorted(one.id_list) == sorted(A + B)
    np.testing.assert_allclose(one.pos[:, 0], 10.0 / RATE)


def test_the_hold_draws_an_instant_a_slow_instance_has_not_reached() -> None:
    m = Merge(hold=0.25)
    assert len(m.add(frame("b", 0, B), 0.0)[0]) == len(B)
    assert len(m.add(frame("a", 0, A), 0.0)[0]) == len(A) + len(B)  # 0 drawn again
    assert m.add(frame("a", 1, A), 0.01) == []  # b has not drawn 1/30 s yet
    assert m.deadline(0.01) == pytest.approx(0.26)
    assert m.ready(0.2) == []
    (late,) = m.ready(0.3)
    assert late.t == 1 / RATE and sorted(late.id_list) == sorted(A + B)
    assert m.add(frame("b", 1, B), 0.31) == []  # that instant is drawn: not again


def test_an_instance_gone_leaves_the_picture_at_once_and_its_late_frames_too() -> None:
    m = Merge()
    m.add(frame("a", 0, A), 0.0)
    m.add(frame("b", 0, B), 0.0)
    (again,) = m.gone("b", 0.05)
    assert again.t == 0.0 and sorted(again.id_list) == sorted(A)
    assert m.add(frame("b", 1, B), 0.06) == []  # in flight when its token went
    (next_,) = m.add(frame("a", 1, A), 0.07)
    assert next_.id_list == A
    m.alive("b")  # back (a restart under the same name)
    m.add(frame("b", 2, B), 0.1)
    (both,) = m.add(frame("a", 2, A), 0.1)
    assert len(both) == len(A) + len(B)


def test_an_instance_stopped_leaves_after_stale_seconds() -> None:
    m, drawn = Merge(hold=0.25, stale=2.0), []
    drawn += m.add(frame("b", 0, B), 0.0)
    for n in range(0, 90):  # a goes on for 3 s; b drew once
        drawn += m.add(frame("a", n, A), n / RATE)
    counts = [(round(f.t * RATE), len(f)) for f in drawn]
    assert all(c == 8 for n, c in counts if 0 < n / RATE < 2.0 - 0.25)
    assert all(c == 5 for n, c in counts if n / RATE > 2.0 + 1 / RATE)
    assert m.instances == ("a", "b")  # still held: it comes back when its frames do


def test_a_new_timeline_starts_the_merge_afresh() -> None:
    m = Merge()
    for n in range(60, 63):
        m.add(frame("a", n, A), n / RATE)
    (f,) = m.add(frame("a", 0, A), 3.0)  # a replay again from t = 0
    assert f.t == 0.0


def test_a_picture_or_any_view_of_it_kept_is_never_overwritten() -> None:
    """The merge reuses the memory of pictures nobody holds any more, and only theirs."""
    m = Merge()
    m.add(frame("a", 0, A), 0.0, draw=False)
    m.add(frame("b", 0, B), 0.0, draw=False)
    kept = m.ready(0.0)[0]
    column = kept.pos[:, 0]  # a view of a picture, the picture itself kept too
    column_only = None
    blocks = set()
    for n in range(1, 40):
        m.add(frame("a", n, A), n / RATE)
        (pic,) = m.add(frame("b", n, B), n / RATE)
        blocks.add(id(pic.pos.base))
        if n == 5:
            column_only = pic.vel[:, 0] * 0 + pic.pos[:, 0]  # a copy, then a view alone
            view = pic.pos[:, 0]
            want = view.copy()
        del pic
    np.testing.assert_array_equal(kept.pos[:, 0], 0.0)
    np.testing.assert_array_equal(column, 0.0)
    np.testing.assert_array_equal(view, want)
    np.testing.assert_allclose(column_only, 50.0 / RATE)
    assert len(blocks) <= 4  # the rest reused
