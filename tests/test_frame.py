"""The frames' fast form (`tracking.frame.FrameColumns`: the display's inputs kept
batch-last, refreshed for the rows that changed) against the plain forms it replaces
(`display.predicted_at`, `status.status_codes` on the store's rows), through the Tracker:
the same positions, velocities, ages and status codes to the bit, sigmas to 1e-12
relative, whatever happened to the tracks between two frames. And the frame's body
(`encode.pack_frame`, one join) against msgpack's own packing of the same map."""

from __future__ import annotations

import numpy as np
import pytest
from reference.record import track
from test_checkpoint import busy_tracker, polar

from zenoh_track import defaults
from zenoh_track.adapter.encode import pack_frame
from zenoh_track.estimation.catalog import FilterSpec
from zenoh_track.tracking import checkpoint, frame
from zenoh_track.tracking.deleter import UpdateTimeDeleter
from zenoh_track.tracking.display import predicted_at
from zenoh_track.tracking.status import status_codes
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import STATUSES, pack, unpack


def reference(tracker: Tracker, t: float) -> dict[str, tuple]:
    """Every live track at t by the plain forms: pos, vel, sigma, age, status code."""
    out = {}
    disp = tracker.display
    for arrays in tracker.store.layouts.values():
        rows, ids = arrays.live()
        if not len(rows):
            continue
        pos, vel, var = predicted_at(arrays.x[rows], arrays.t[rows],
                                     disp.columns(arrays).axis_cov[rows], t, disp.q,
                                     arrays.order, arrays.dim)
        age = np.maximum(t - arrays.t[rows], 0.0)
        codes = status_codes(arrays, rows, age, disp.config.coast_after)
        sigma = np.sqrt(np.maximum(var, 0.0))
        for i, k in enumerate(ids):
            out[k] = (pos[i], vel[i], sigma[i], age[i], int(codes[i]))
    return out


def assert_frame(tracker: Tracker, t: float) -> None:
    snap = tracker.snapshot(t)
    want = reference(tracker, t)
    assert sorted(snap.ids) == sorted(want) and len(snap.ids) == len(want)
    for i, k in enumerate(snap.ids):
        pos, vel, sigma, age, code = want[k]
        assert np.array_equal(snap.pos[i], pos) and np.array_equal(snap.vel[i], vel), k
        assert snap.age[i] == age and snap.codes[i] == code, k
        assert snap.status[i] == STATUSES[code] and snap.shown[i] == "prediction"
        assert snap.sigma[i] == pytest.approx(sigma, rel=1e-12, abs=0), k


@pytest.fixture(params=[7, frame.CHUNK])  # 7: many chunks, ragged last one
def chunk(request, monkeypatch):
    monkeypatch.setattr(frame, "CHUNK", request.param)
    return request.param


@pytest.mark.parametrize("name", ["imm", "cv", "ca"])
def test_frames_equal_the_plain_prediction_as_tracks_come_change_and_go(name, chunk):
    """2-D and 3-D labelled tracks and tracks of unlabelled scans (their own status),
    updated, deleted (gaps in the rows), re-added in freed rows, drawn at instants before,
    between and long after their updates (coasting, tentative and confirmed)."""
    tr = busy_tracker(name)
    for t in (3.0, 3.4, 5.0, 11.0, 2.5):
        assert_frame(tr, t)
    track(tr, [polar(f"a{i}", 4.0, 5300 + 100 * i, 0.1 * i) for i in (0, 2, 3)])
    assert_frame(tr, 4.0)
    tr.remove(["a0", "b1"])
    assert_frame(tr, 4.5)
    track(tr, [polar("new", 4.6, 7000.0, 0.3), polar("a1", 4.6, 5100.0, 0.1)])
    for t in (4.6, 4.7, 9.0, 40.0):
        assert_frame(tr, t)


@pytest.mark.parametrize("threads", [1, 3])
def test_frames_follow_many_updates_beyond_one_chunk(chunk, threads, monkeypatch):
    """The default IMM, more tracks than one chunk, some updated between frames; the
    draw's rows split over threads or not."""
    monkeypatch.setattr(defaults, "KERNEL_THREADS", threads)
    monkeypatch.setattr(defaults, "PARALLEL_ROWS", 5)
    tr = Tracker.from_config()
    n = 2 * frame.CHUNK + 5 if chunk < 100 else 300
    rng = np.random.default_rng(3)
    r, az = rng.uniform(5e3, 8e4, n), rng.uniform(-3, 3, n)
    for k in range(4):
        pick = range(n) if k < 3 else range(0, n, 3)
        track(tr, [polar(f"s{i}", k + 0.01 * (i % 7), r[i] + 20 * k, az[i]) for i in pick])
        for dt in (0.0, 1 / 30, 0.5, 2.9):
            assert_frame(tr, k + dt)


def test_frames_read_a_restored_tracker():
    """A checkpoint restored into a fresh tracker is drawn as the one it was taken of."""
    tr = busy_tracker()
    back = Tracker.from_config(TrackerConfig(filter=FilterSpec("imm")))
    checkpoint.load(back, checkpoint.dump(tr))
    for t in (3.5, 20.0):
        assert_frame(back, t)
        a, b = tr.snapshot(t), back.snapshot(t)
        order = [b.ids.index(k) for k in a.ids]
        assert np.array_equal(a.pos, b.pos[order]) and np.array_equal(a.codes, b.codes[order])


def test_frame_columns_refresh_rows_whose_time_moved():
    """A row whose store time changed behind the display's back is read again."""
    tr = busy_tracker()
    tr.snapshot(3.0)
    arrays = tr.store.layout(3)
    row = arrays.live()[0][0]
    arrays.x[row, 0] += 123.0
    arrays.t[row] += 0.25
    assert_frame(tr, 3.5)


def test_a_row_reused_at_the_same_time_is_read_again():
    """A track deleted and another started in its row with the same time: the display's
    `initiate` marks the row (its time alone would not tell)."""
    tr = Tracker.from_config()
    track(tr, [polar("a", 1.0, 5000.0, 0.1), polar("b", 1.0, 6000.0, 0.2)])
    assert_frame(tr, 1.5)
    tr.remove(["a"])
    track(tr, [polar("z", 1.0, 9000.0, -0.4)])
    assert tr.store.where["z"][1] == 0
    assert_frame(tr, 1.5)


def test_pack_frame_is_msgpack_of_the_same_map_whatever_the_arrays_layout():
    rng = np.random.default_rng(0)
    ids = [f"t{i}" for i in range(40)]
    pos, vel = rng.normal(size=(40, 3)), rng.normal(size=(3, 40)).T  # vel: transposed
    sigma, status = rng.uniform(size=40).astype(np.float32), rng.integers(0, 3, 40)
    want = pack({"t": 2.5, "ids": ids, "pos": pos.astype("<f8").tobytes(),
                 "vel": np.ascontiguousarray(vel, "<f8").tobytes(),
                 "sigma": sigma.astype("<f8").tobytes(), "status": status.astype("u1").tobytes()})
    assert pack_frame(2.5, pack(ids), pos, vel, sigma, status) == want
    assert pack_frame(0.0, pack([]), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                      np.zeros(0, np.uint8)) == pack({"t": 0.0, "ids": [], "pos": b"",
                                                      "vel": b"", "sigma": b"", "status": b""})
    assert pack_frame(2.5, pack(ids), pos, vel, sigma, status, "shard-a") == pack(
        {**unpack(want), "instance": "shard-a"})


def test_update_time_deleter_takes_the_tracks_the_plain_rule_takes():
    """The early exit (none due: the oldest live track is not) against the rule on every
    row, with freed rows holding older times than any live one."""
    tr = busy_tracker()
    arrays = tr.store.layout(2)
    rows = arrays.live()[0]
    deleter = UpdateTimeDeleter(2.0)
    for now in (3.0, 4.99, 5.0, 5.01, 6.0, 100.0):
        plain = [k for k, r in zip(arrays.live()[1], rows.tolist(), strict=True)
                 if now - arrays.t[r] > 2.0]
        got = [k for k in deleter.delete_tracks(tr.store, now) if k in arrays.live()[1]]
        assert got == plain
    assert UpdateTimeDeleter(2.0).delete_tracks(Tracker.from_config().store, 1e9) == []


@pytest.mark.parametrize("order,dim", [(3, 3), (3, 2), (2, 3), (2, 2)])
def test_the_plain_draw_that_serves_before_the_compiled_one_gives_the_same_bits(order, dim):
    """`frame.draw_plain` (NumPy, serving while the kernels compile: `estimation.jit`)
    against the compiled `frame_kernel.draw` on random columns, rows in any order, times
    before and after the tracks' own, a negative variance clipped."""
    from zenoh_track.tracking.frame_kernel import draw

    rng = np.random.default_rng(order * 10 + dim)
    cap, n = 300, order * dim
    x, tt = rng.normal(0, 1e4, (n, cap)), rng.uniform(0, 100, cap)
    a = rng.normal(0, 50, (len(frame.AXIS_ENTRIES[order]), cap)) ** 2
    a[0, :5] = -1e9  # a variance below zero: sigma 0
    base, limit = rng.integers(0, 3, cap).astype(np.uint8), rng.uniform(0.5, 5, cap)
    rows = rng.permutation(cap)[:200].astype(np.int64)
    outs = []
    for fn in (draw, frame.draw_plain):
        got = (np.zeros((200, 3)), np.zeros((200, 3)), np.empty(200), np.empty(200),
               np.empty(200, np.uint8))
        fn(x, tt, a, base, limit, rows, 60.0, 0.7, dim, order, *got)
        outs.append(got)
    for fast, plain in zip(*outs, strict=True):
        np.testing.assert_array_equal(fast, plain)
