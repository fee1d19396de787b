"""Single messages checked together (`wire.parse_singles`, what the service's worker does
with what it takes from its channel) give exactly what `parse_measurement` gives on each:
the same messages rejected with the same reasons, the same values (through
`MeasurementBatch.of_scan`, against `MeasurementBatch.of` on the records), the same seq."""

from __future__ import annotations

import math
import random

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from payloads import bad_measurement, measurement

from service import defaults
from service.estimation.measurements import MeasurementBatch
from service.wire import Rejected, pack, parse_measurement, parse_singles

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
