"""The reorder buffer of unlabelled scans: the documented release policy."""

from __future__ import annotations

from zenoh_track.adapter.reorder import ReorderBuffer


def feed(buf: ReorderBuffer, items) -> list:
    out = []
    for sensor, t in items:
        if buf.late(t) is None:
            out += [i for _, i in buf.push(sensor, t, (sensor, t))]
        else:
            out.append(("late", t))
    return out


def test_one_sensor_waits_only_through_the_warm_up():
    buf = ReorderBuffer(0.5)
    out = feed(buf, [("a", 0.0), ("a", 1.0), ("a", 2.0), ("a", 3.0)])
    assert out == [("a", 0.0), ("a", 1.0), ("a", 2.0), ("a", 3.0)]
    assert len(buf) == 0


def test_two_sensors_out_of_order_come_out_in_time_order():
    buf = ReorderBuffer(0.5)
    items = [(s, t) for k in range(4) for s, t in (("b", k + 0.3), ("a", float(k)))]
    out = feed(buf, items)
    times = [t for _, t in out]
    assert times == sorted(times) and "late" not in [s for s, _ in out]
    assert times == [0.0, 0.3, 1.0, 1.3, 2.0, 2.3, 3.0]  # b's 3.3 waits for a's next
    assert [t for _, (_, t) in buf.advance(4.0, flush=True)] == [3.3]


def test_a_silent_sensor_holds_nobody_back_longer_than_the_lag():
    buf = ReorderBuffer(0.5)
    feed(buf, [("a", 0.0), ("b", 0.1)])
    out = feed(buf, [("a", 1.0), ("a", 2.0), ("a", 3.0)])  # b falls silent at 0.1
    assert [t for _, t in out] == [0.0, 0.1, 1.0, 2.0]  # 3.0 waits until 3.5
    assert [t for _, t in feed(buf, [("a", 3.5)])] == [3.0]  # and 3.5 waits until 4.0


def test_late_scan_is_refused_with_a_reason():
    buf = ReorderBuffer(0.5)
    feed(buf, [("a", 0.0), ("a", 1.0), ("a", 2.0)])
    reason = buf.late(0.5)
    assert reason is not None and reason.startswith("late scan: t=0.500000")
    assert buf.late(2.0) is None  # simultaneous with the newest released: still in time
