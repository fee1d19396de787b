"""The input limits of docs/protocol.md §4: every bad input is refused with a reason
whose code (`reason_code`) is one of the documented set, never `other`."""

from __future__ import annotations

import math

import msgpack
import pytest

from zenoh_track.wire import (
    MAX_MEAS_BYTES,
    MAX_ROWS,
    MAX_SCAN_BYTES,
    REASON_CODES,
    Rejected,
    f64_bin,
    pack,
    parse_clock,
    parse_measurement,
    parse_plots,
    reason_code,
)

NOISE = (10.0, 0.01, 0.01, 1.0)
OK = {"t": 1.0, "r": 1000.0, "az": 0.5, "el": 0.2}


def refuse(payload: bytes) -> Rejected:
    with pytest.raises(Rejected) as info:
        parse_measurement("s", "x", payload, NOISE)
    assert info.value.code != "other", str(info.value)
    return info.value


@pytest.mark.parametrize(("change", "code", "words"), [
    ({"el": 2.0}, "out_of_range", "field 'el' must be <="),
    ({"el": -1.7}, "out_of_range", "field 'el' must be >="),
    ({"az": 7.0}, "out_of_range", "field 'az' must be <="),
    ({"r": -1.0}, "out_of_range", "field 'r' must be >= 0.0"),
    ({"r": 2e9}, "out_of_range", "field 'r' must be <="),
    ({"saz": 2.0}, "out_of_range", "field 'saz' must be <="),
    ({"sel": -0.1}, "out_of_range", "field 'sel' must be >= 0.0"),
    ({"t": 1e300}, "time_out_of_range", "outside the plausible range"),
    ({"t": -2e10}, "time_out_of_range", "outside the plausible range"),
    ({"t": 2**64 - 1}, "time_out_of_range", "outside the plausible range"),
    ({"t": math.nan}, "not_finite", "not finite"),
    ({"r": "1000"}, "bad_type", "must be a number"),
    ({"seq": -1}, "out_of_range", "'seq' must be in"),
    ({"seq": 2**60}, "out_of_range", "'seq' must be in"),
    ({"sensor_pos": [0.0, 0.0, 1e10]}, "out_of_range", "'sensor_pos' must be <="),
])
def test_polar_out_of_range(change, code, words):
    exc = refuse(pack({**OK, **change}))
    assert exc.code == code and words in str(exc), str(exc)


@pytest.mark.parametrize(("msg", "code"), [
    ({"t": 1.0, "pos": [0.0, 1e10]}, "out_of_range"),
    ({"t": 1.0, "pos": [0.0, 1.0], "sigma": 2e9}, "out_of_range"),
    ({"t": 1.0, "pos": [0.0, 1.0], "sigma": [1.0, -1.0]}, "out_of_range"),
])
def test_cartesian_out_of_range(msg, code):
    assert refuse(pack(msg)).code == code


def test_bounds_are_inclusive_and_noise_zero_is_exact():
    m = parse_measurement("s", "x", pack({**OK, "el": 1.62, "az": -6.3, "saz": 0.0,
                                          "sr": 0.0}), NOISE)
    assert m.values == (1000.0, -6.3, 1.62) and m.sigmas[:2] == (0.0, 0.0)


def test_oversized_and_malformed_payloads():
    big = pack({**OK, "note": "x" * MAX_MEAS_BYTES})
    exc = refuse(big)
    assert exc.code == "too_large" and f"limit of {MAX_MEAS_BYTES} bytes" in str(exc)
    for payload, code in ((b"", "not_a_map"), (b"\xc1", "not_msgpack"),
                          (pack([1, 2]), "not_a_map"),  # type: ignore[arg-type]
                          (msgpack.packb({1: 2}), "not_a_map"),
                          (pack(OK)[:-3], "not_msgpack"),
                          (b"\xdd\xff\xff\xff\xff", "not_msgpack")):
        assert refuse(payload).code == code
    with pytest.raises(Rejected) as info:
        parse_clock(pack({"t": 1e11}))
    assert info.value.code == "time_out_of_range"


def test_oversized_scans():
    with pytest.raises(Rejected) as info:
        parse_plots("s", b"\x80" + b"\x00" * MAX_SCAN_BYTES, NOISE)
    assert info.value.code == "too_large"
    n = MAX_ROWS + 1
    with pytest.raises(Rejected) as info:
        parse_plots("s", pack({"t": 1.0, "r": f64_bin([1.0] * n), "az": f64_bin([0.0] * n)}),
                    NOISE)
    assert info.value.code == "too_large" and "more than the limit" in str(info.value)


def test_scan_rows_out_of_range_are_refused_alone():
    s = parse_plots("s", pack({"t": 1.0, "r": f64_bin([1.0, 2.0, 3.0]),
                               "az": f64_bin([0.0, 9.0, 0.0]),
                               "el": f64_bin([0.0, 0.0, -2.0])}), NOISE)
    assert s.index == (0,)
    assert [reason_code(r) for _, r in s.rejected] == ["out_of_range"] * 2
    s = parse_plots("s", pack({"t": 1.0, "dets": [{"r": 1.0, "az": 0.0, "el": 2.0},
                                                  {"r": 1.0, "az": 0.0}]}), NOISE)
    assert s.index == (1,) and "field 'el' must be <=" in s.rejected[0][1]


def test_every_code_documented():
    doc = open("docs/reference/errors.md", encoding="utf-8").read()  # the error reasons
    for code, _ in REASON_CODES:
        assert f"`{code}`" in doc, code


def test_codes_of_batched_scan_rows():
    assert reason_code("row 3 (tgt-7): field 'r' must be >= 0.0, got -1.0") == "out_of_range"
    assert reason_code("row 0 (a): field 't' is not finite or out of bounds (nan)") \
        == "time_out_of_range"
    assert reason_code("bin 't' has 9 bytes, not 2 float64 (one per id)") == "bad_type"
    assert reason_code("bin 'r' has 3 rows, 'ids' 2") == "bad_type"
    assert reason_code("batched scan needs 'ids', a list of target ids (strings)") \
        == "missing_field"
