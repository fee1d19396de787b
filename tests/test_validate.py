"""Unit tests of zenoh_track.validate.parse_measurement against PROTOCOL.md (labelled
measurements on `<ns>/meas/<sensor>/<target>`)."""

from __future__ import annotations

import math

import msgpack
import pytest

from zenoh_track.wire import Measurement, Rejected, pack, parse_clock, parse_measurement

DEFAULTS = (10.0, 0.01, 0.02, 5.0)  # (sr, saz, sel, sigma) used when a message gives none


def parse(msg, sensor="radar-1", target="tgt_7"):
    return parse_measurement(sensor, target, pack(msg), DEFAULTS)


def rejected(msg, *words, sensor="radar-1", target="tgt_7", payload=None):
    """Assert rejection and that the reason names every word (the offending field)."""
    data = pack(msg) if payload is None else payload
    with pytest.raises(Rejected) as info:
        parse_measurement(sensor, target, data, DEFAULTS)
    reason = str(info.value)
    for w in words:
        assert w in reason, f"{w!r} not in reason {reason!r}"
    return reason


# ---------------------------------------------------------------- accepted
def test_polar_2d_defaults():
    m = parse({"t": 1.5, "r": 1000.0, "az": 0.25})
    assert m == Measurement("radar-1", "tgt_7", 1.5, 2, True, (1000.0, 0.25), (10.0, 0.01),
                            (0.0, 0.0, 0.0), None)


def test_polar_2d_with_sigmas():
    m = parse({"t": 0.0, "r": 1000.0, "az": -3.0, "sr": 2.0, "saz": 0.003})
    assert (m.dim, m.polar, m.values, m.sigmas) == (2, True, (1000.0, -3.0), (2.0, 0.003))


def test_polar_2d_ignores_sel_without_el():
    m = parse({"t": 0.0, "r": 1000.0, "az": 1.0, "sel": 0.5})
    assert m.dim == 2 and m.sigmas == (10.0, 0.01)


def test_polar_3d_defaults():
    m = parse({"t": 2.0, "r": 5000.0, "az": 1.0, "el": 0.3})
    assert (m.dim, m.polar, m.values, m.sigmas) == (3, True, (5000.0, 1.0, 0.3),
                                                    (10.0, 0.01, 0.02))


def test_polar_3d_with_sigmas_and_partial_sigmas():
    m = parse({"t": 2.0, "r": 5000.0, "az": 1.0, "el": 0.3, "sr": 1.0, "saz": 0.1,
               "sel": 0.2})
    assert m.sigmas == (1.0, 0.1, 0.2)
    m = parse({"t": 2.0, "r": 5000.0, "az": 1.0, "el": 0.3, "saz": 0.1})
    assert m.sigmas == (10.0, 0.1, 0.02)  # the absent ones take the defaults


def test_polar_zero_range_and_zero_sigmas_and_el_past_zenith():
    # r = 0 and zero noise are legal (>= 0); noise may carry el a little past 90 deg
    m = parse({"t": 0.0, "r": 0.0, "az": 0.0, "el": 1.6, "sr": 0.0, "saz": 0.0, "sel": 0.0})
    assert m.values == (0.0, 0.0, 1.6) and m.sigmas == (0.0, 0.0, 0.0)


def test_integers_accepted_as_floats():
    m = parse({"t": 3, "r": 100, "az": 0, "el": 0, "sr": 1})
    assert m.t == 3.0 and isinstance(m.t, float)
    assert all(isinstance(v, float) for v in m.values + m.sigmas)


@pytest.mark.parametrize(("pos", "sigma", "dim", "expected"), [
    ([1.0, 2.0], None, 2, (5.0, 5.0)),  # absent: the default sigma on every axis
    ([1.0, 2.0], 3.0, 2, (3.0, 3.0)),  # scalar: the same on every axis
    ([1.0, 2.0], [1.0, 2.0], 2, (1.0, 2.0)),  # list: one per axis
    ([1.0, 2.0], 0.0, 2, (0.0, 0.0)),  # 0: exact position
    ([1.0, 2.0, 3.0], None, 3, (5.0, 5.0, 5.0)),
    ([1.0, 2.0, 3.0], 0, 3, (0.0, 0.0, 0.0)),
    ([1.0, 2.0, 3.0], [1.0, 2.0, 3.0], 3, (1.0, 2.0, 3.0)),
    ([1.0, 2.0, 3.0], [0.5], 3, (0.5, 0.5, 0.5)),
])
def test_cartesian_forms(pos, sigma, dim, expected):
    msg = {"t": 4.0, "pos": pos}
    if sigma is not None:
        msg["sigma"] = sigma
    m = parse(msg)
    assert (m.dim, m.polar, m.values, m.sigmas) == (dim, False, tuple(pos), expected)


def test_sensor_pos_and_seq():
    m = parse({"t": 1.0, "r": 10.0, "az": 0.0, "sensor_pos": [1.0, -2.0, 3.5], "seq": 42})
    assert m.sensor_pos == (1.0, -2.0, 3.5) and m.seq == 42
    m = parse({"t": 1.0, "pos": [0.0, 0.0], "sensor_pos": [0, 0, 0], "seq": 0})
    assert m.sensor_pos == (0.0, 0.0, 0.0) and m.seq == 0


def test_unknown_keys_ignored():
    base = {"t": 1.0, "pos": [1.0, 2.0, 3.0], "sigma": 1.0}
    extra = {**base, "foo": "bar", "nested": {"a": [1, 2]}, "blob": b"\x00\x01", "n": None}
    assert parse(extra) == parse(base)


def test_non_string_keys_rejected():
    """The contract's maps have string keys; unknown string keys are ignored."""
    payload = msgpack.packb({"t": 1.0, "pos": [1.0, 2.0], 7: "x"}, use_bin_type=True)
    rejected(None, "map keys must be strings", payload=payload)
    assert parse({"t": 1.0, "pos": [1.0, 2.0], "colour": "red"}).values == (1.0, 2.0)


def test_chunks_with_digits_dash_underscore():
    m = parse({"t": 0.0, "pos": [0.0, 0.0]}, sensor="Radar_01-b", target="0")
    assert (m.sensor, m.target) == ("Radar_01-b", "0")


# ---------------------------------------------------------------- rejected
@pytest.mark.parametrize("msg", [[1, 2], 3, "t", None, 1.5, True, b"bytes"])
def test_not_a_map(msg):
    rejected(msg, "map")


@pytest.mark.parametrize("payload", [
    b"",  # empty
    b"\xc1",  # reserved, never valid MessagePack
    b"\x82\xa1t",  # map of 2 truncated after the first key
    b"\x81\xa1t\xcb\x00",  # float64 truncated
    b"\x80\x80",  # a valid empty map followed by extra data
])
def test_garbage_bytes(payload):
    with pytest.raises(Rejected):
        parse_measurement("s", "t", payload, DEFAULTS)


def test_missing_t():
    rejected({"r": 1.0, "az": 0.0}, "'t'")
    rejected({"pos": [1.0, 2.0]}, "'t'")


def test_t_wrong_type():
    rejected({"t": "1.0", "pos": [1.0, 2.0]}, "'t'")
    rejected({"t": None, "pos": [1.0, 2.0]}, "'t'")
    rejected({"t": [1.0], "pos": [1.0, 2.0]}, "'t'")


def test_both_polar_and_pos():
    rejected({"t": 0.0, "r": 1.0, "az": 0.0, "pos": [1.0, 2.0]}, "pos", "r")
    rejected({"t": 0.0, "az": 0.0, "pos": [1.0, 2.0]}, "pos")


def test_neither_polar_nor_pos():
    rejected({"t": 0.0}, "pos", "r")
    rejected({"t": 0.0, "el": 0.1, "sigma": 1.0}, "pos", "r")


def test_incomplete_polar():
    rejected({"t": 0.0, "r": 1.0}, "az")
    rejected({"t": 0.0, "az": 1.0, "el": 0.0}, "r")


@pytest.mark.parametrize(("field", "bad"), [
    ("t", math.nan), ("t", math.inf), ("r", math.inf), ("r", math.nan), ("az", math.nan),
    ("el", -math.inf), ("sr", math.nan), ("saz", math.inf), ("sel", math.nan),
])
def test_polar_non_finite(field, bad):
    msg = {"t": 0.0, "r": 100.0, "az": 0.0, "el": 0.0, field: bad}
    rejected(msg, f"'{field}'")


@pytest.mark.parametrize(("field", "bad"), [
    ("pos", [math.nan, 0.0]), ("pos", [0.0, 0.0, math.inf]), ("sigma", math.inf),
    ("sigma", [1.0, math.nan]), ("sensor_pos", [0.0, math.inf, 0.0]),
])
def test_cartesian_non_finite(field, bad):
    msg = {"t": 0.0, "pos": [0.0, 0.0], field: bad}
    rejected(msg, f"'{field}'")


@pytest.mark.parametrize(("field", "bad"), [
    ("r", -5.0), ("sr", -1.0), ("saz", -0.1), ("sel", -1e-9),
])
def test_negative_polar(field, bad):
    rejected({"t": 0.0, "r": 100.0, "az": 0.0, "el": 0.1, field: bad}, f"'{field}'")


@pytest.mark.parametrize("bad", [-1.0, [1.0, -1.0], [-0.5]])
def test_negative_sigma(bad):
    rejected({"t": 0.0, "pos": [0.0, 0.0], "sigma": bad}, "'sigma'")


@pytest.mark.parametrize(("msg", "field"), [
    ({"t": 0.0, "pos": [1.0]}, "pos"),
    ({"t": 0.0, "pos": [1.0, 2.0, 3.0, 4.0]}, "pos"),
    ({"t": 0.0, "pos": []}, "pos"),
    ({"t": 0.0, "pos": 5.0}, "pos"),
    ({"t": 0.0, "pos": {"x": 1.0, "y": 2.0}}, "pos"),
    ({"t": 0.0, "pos": [1.0, 2.0, 3.0], "sigma": [1.0, 2.0]}, "sigma"),
    ({"t": 0.0, "pos": [1.0, 2.0], "sigma": [1.0, 2.0, 3.0]}, "sigma"),
    ({"t": 0.0, "pos": [1.0, 2.0], "sigma": []}, "sigma"),
    ({"t": 0.0, "pos": [1.0, 2.0], "sensor_pos": [1.0, 2.0]}, "sensor_pos"),
    ({"t": 0.0, "r": 1.0, "az": 0.0, "sensor_pos": [1.0, 2.0, 3.0, 4.0]}, "sensor_pos"),
    ({"t": 0.0, "r": 1.0, "az": 0.0, "sensor_pos": 0.0}, "sensor_pos"),
])
def test_wrong_list_lengths(msg, field):
    rejected(msg, f"'{field}'")


@pytest.mark.parametrize(("msg", "field"), [
    ({"t": True, "pos": [0.0, 0.0]}, "t"),
    ({"t": 0.0, "r": True, "az": 0.0}, "r"),
    ({"t": 0.0, "r": 1.0, "az": False}, "az"),
    ({"t": 0.0, "r": 1.0, "az": 0.0, "el": True}, "el"),
    ({"t": 0.0, "r": 1.0, "az": 0.0, "sr": False}, "sr"),
    ({"t": 0.0, "pos": [True, 0.0]}, "pos"),
    ({"t": 0.0, "pos": [0.0, 0.0], "sigma": True}, "sigma"),
    ({"t": 0.0, "pos": [0.0, 0.0], "sigma": [False, 1.0]}, "sigma"),
    ({"t": 0.0, "pos": [0.0, 0.0], "sensor_pos": [0.0, 0.0, True]}, "sensor_pos"),
    ({"t": 0.0, "pos": [0.0, 0.0], "seq": True}, "seq"),
])
def test_bool_values(msg, field):
    rejected(msg, f"'{field}'")


@pytest.mark.parametrize("seq", [1.5, "3", [1]])
def test_seq_not_integer(seq):
    rejected({"t": 0.0, "pos": [0.0, 0.0], "seq": seq}, "'seq'")


@pytest.mark.parametrize(("sensor", "target", "which"), [
    ("a/b", "t1", "sensor"),
    ("a b", "t1", "sensor"),
    ("", "t1", "sensor"),
    ("s*", "t1", "sensor"),
    ("s1", "x.y", "target"),
    ("s1", "é", "target"),
    ("s1", "", "target"),
    ("s1", "$*", "target"),
])
def test_bad_key_chunks(sensor, target, which):
    rejected({"t": 0.0, "pos": [0.0, 0.0]}, which, sensor=sensor, target=target)


@pytest.mark.parametrize(("sensor", "target"), [("s1", "tgt\n"), ("radar\n", "t1")])
def test_chunk_with_trailing_newline_rejected(sensor, target):
    rejected({"t": 0.0, "pos": [0.0, 0.0]}, sensor=sensor, target=target)


def test_rejected_is_value_error():
    assert issubclass(Rejected, ValueError)


# ---------------------------------------------------------------- clock message
def test_parse_clock():
    assert parse_clock(pack({"t": 12.5, "extra": 1})) == 12.5
    for bad in ({"x": 1.0}, {"t": math.nan}, {"t": True}, [1.0]):
        with pytest.raises(Rejected):
            parse_clock(pack(bad))
    with pytest.raises(Rejected):
        parse_clock(b"\xc1")


# ---------------------------------------------------------------- fast path
FULL = {"t": 3.0, "r": 5000.0, "az": 1.0, "el": 0.3, "sr": 1.0, "saz": 0.1, "sel": 0.2,
        "seq": 4}
VARIANTS = [
    {}, {"seq": None}, {"t": 3}, {"r": 5000}, {"sel": 0}, {"r": -1.0}, {"saz": -0.1},
    {"el": math.nan}, {"t": math.inf}, {"az": True}, {"seq": 1.5}, {"seq": True},
    {"r": 1e308, "t": 1e308, "az": 1e308},  # finite; a naive sum overflows
    {"pos": [1.0, 2.0, 3.0]}, {"sensor_pos": [0.0, 0.0, 10.0]}, {"extra": 1},
    {"r": "5000"}, {"sel": [0.1]},
]


@pytest.mark.parametrize("change", VARIANTS)
@pytest.mark.parametrize("drop", [None, "sel", "seq", "t", "el"])
def test_fast_path_agrees_with_the_full_check(change, drop):
    from zenoh_track.wire import parse_full
    msg = {**FULL, **change}
    if drop:
        msg.pop(drop, None)
    data = pack(msg)
    outcomes = []
    for fn in (parse_measurement, parse_full):
        try:
            outcomes.append(fn("radar-1", "tgt_7", data, DEFAULTS))
        except Rejected as exc:
            outcomes.append(str(exc))
    assert outcomes[0] == outcomes[1]
