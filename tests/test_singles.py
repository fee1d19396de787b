"""Single messages checked together (`wire.parse_singles`, what the service's worker does
with what it takes from its channel) give exactly what `parse_measurement` gives on each:
the same messages rejected with the same reasons, the same values (through
`MeasurementBatch.of_scan`, against `MeasurementBatch.of` on the records), the same seq."""

from __future__ import annotations

import math
import random

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from payloads import bad_measurement, measurement

from zenoh_track import defaults
from zenoh_track.adapter.layouts import by_layout
from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.wire import Rejected, pack, parse_measurement, parse_singles

NOISE = defaults.NOISE


def reference(sensors, targets, payloads):
    """Per message: its record, or the reason it is rejected."""
    out = []
    for s, k, p in zip(sensors, targets, payloads, strict=True):
        try:
            out.append(parse_measurement(s, k, p, NOISE))
        except Rejected as exc:
            out.append(str(exc))
    return out


def check(sensors, targets, payloads) -> None:
    ref = reference(sensors, targets, payloads)
    got = parse_singles(sensors, targets, payloads, NOISE)
    _check(ref, got)
    fast = by_layout(sensors, targets, payloads)  # the service's reading of one layout
    if fast is not None:
        _check(ref, fast)


def _check(ref, got) -> None:
    assert got.rejected == [(i, r) for i, r in enumerate(ref) if isinstance(r, str)]
    assert got.seqs == [None if isinstance(r, str) else r.seq for r in ref]
    seen = []
    for index, cols in got.parts:
        records = [ref[i] for i in index]
        assert len({m.dim for m in records}) == 1 and cols.ids == [m.target for m in records]
        a = MeasurementBatch.of_scan(cols)
        b = MeasurementBatch.of(records, records[0].dim)
        for name in ("t", "polar", "values", "sigmas", "origin"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        seen += index
    assert seen == [i for i, r in enumerate(ref) if not isinstance(r, str)]  # in order


def common(rng: random.Random, t: float) -> dict:
    return {"t": t, "r": rng.uniform(1e3, 1e5), "az": rng.uniform(-3, 3),
            "el": rng.uniform(0, 1), "sr": 10.0, "saz": 0.002, "sel": 0.002}


def test_common_form_in_bulk_with_seq_and_bad_ones_mixed_in():
    rng = random.Random(1)
    n = 300
    msgs = [common(rng, 5.0 + 0.001 * i) | ({"seq": i} if i % 2 else {}) for i in range(n)]
    msgs[7]["r"] = -1.0  # out of range
    msgs[8]["az"] = math.nan
    msgs[9]["el"] = 1  # an integer: the full check takes it
    msgs[10]["seq"] = -3
    msgs[11]["sr"] = True  # a bool is not a number
    msgs[12] = {"t": 5.0, "pos": [1.0, 2.0, 3.0]}  # Cartesian 3-D: a record in the columns
    msgs[13] = {"t": 5.0, "r": 1e4, "az": 0.1}  # 2-D polar: a part of its own
    del msgs[15]["sr"]  # the default noise: not the common form (with seq: 7 fields)
    payloads = [pack(m) for m in msgs]
    payloads[20] = payloads[20][:5]  # truncated
    targets = [f"x{i}" for i in range(n)]
    targets[30] = "bad/id"
    sensors = ["radar1"] * n
    sensors[40] = "r a"
    check(sensors, targets, payloads)
    got = parse_singles(sensors, targets, payloads, NOISE)
    assert [len(i) for i, _ in got.parts] == [9, 1, n - 14 - 3]  # 4 and 3 rejected


def test_every_message_good_is_one_part():
    rng = random.Random(2)
    payloads = [pack(common(rng, 1.0)) for _ in range(50)]
    got = parse_singles(["s"] * 50, [f"t{i}" for i in range(50)], payloads, NOISE)
    assert not got.rejected and [i for i, _ in got.parts] == [list(range(50))]
    check(["s"] * 50, [f"t{i}" for i in range(50)], payloads)


def test_nothing_in_nothing_out():
    got = parse_singles([], [], [], NOISE)
    assert got.parts == [] and got.rejected == [] and got.seqs == []


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(measurement(100.0).map(lambda m: (pack(m), None)),
                          bad_measurement(100.0)), min_size=1, max_size=12),
       st.randoms(use_true_random=False))
def test_any_mix_of_messages_as_each_alone(items, rng):
    payloads = [p for p, _ in items]
    targets = [rng.choice(["a", "b", "c-1", "x y"]) for _ in payloads]
    sensors = [rng.choice(["s1", "s2"]) for _ in payloads]
    check(sensors, targets, payloads)


def feed_form(rng: random.Random, t: float, seq: int | None) -> dict:
    m = common(rng, t)
    return m if seq is None else m | {"seq": seq}


@pytest.mark.parametrize("order", ["fields", "reversed", "shuffled"])
@pytest.mark.parametrize("first_seq", [None, 0, 50, 130, 60_000, 70_000, 2**40])
def test_one_layout_read_from_the_bytes_as_decoding_each(first_seq, order):
    """A feed's burst (one key order, seq of one width: fixint, uint8/16/32/64, or none)
    is read from the joined bytes (`layouts.by_layout`) with what decoding each gives."""
    rng = random.Random(3)
    n = 40
    seqs = [None if first_seq is None else first_seq + i for i in range(n)]
    names = list(feed_form(rng, 0.0, first_seq))
    if order != "fields":
        names = names[::-1] if order == "reversed" else rng.sample(names, len(names))
    payloads = [pack({k: m[k] for k in names})
                for m in (feed_form(rng, 7.0 + 0.01 * i, q) for i, q in enumerate(seqs))]
    targets = [f"x{i}" for i in range(n)]
    assert len({len(p) for p in payloads}) == 1
    got = by_layout(["r1"] * n, targets, payloads)
    assert got is not None and got.seqs == seqs
    check(["r1"] * n, targets, payloads)


def test_other_layouts_and_bad_values_take_the_full_check():
    rng = random.Random(4)
    n = 20
    base = [feed_form(rng, 3.0, 1000 + i) for i in range(n)]
    targets, sensors = [f"x{i}" for i in range(n)], ["r1"] * n

    def variant(i: int, m: dict) -> list[bytes]:
        out = [pack(x) for x in base]
        out[i] = pack(m) if isinstance(m, dict) else m
        return out

    reordered = dict(reversed(list(base[5].items())))  # same length, other key order
    cases = [
        variant(5, reordered),
        variant(6, base[6] | {"r": -1.0}),  # out of range
        variant(7, base[7] | {"az": math.nan}),
        variant(8, base[8] | {"el": math.inf}),
        variant(9, base[9] | {"seq": -5}),  # a negative seq (int8: another layout)
        variant(3, msgpack.packb(base[3], use_single_float=True)),  # float32 values
        variant(4, pack(base[4])[:-3] + b"\xd1" + pack(base[4])[-2:]),  # seq an int16
        variant(2, b"\x87" + pack(base[2])[1:]),  # a map header one entry short
    ]
    for payloads in cases:
        assert by_layout(sensors, targets, payloads) is None
        check(sensors, targets, payloads)
    bad_ids = list(targets)
    bad_ids[11] = "x y"
    payloads = [pack(x) for x in base]
    assert by_layout(sensors, bad_ids, payloads) is None
    check(sensors, bad_ids, payloads)
    mixed = ["r1"] * n
    mixed[12] = "r 2"
    assert by_layout(mixed, targets, payloads) is None
    check(mixed, targets, payloads)
