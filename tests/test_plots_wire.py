"""Unit tests of zenoh_track.wire.parse_plots: unlabelled scans on `<ns>/plots/<sensor>`, in the
`dets` form and the columnar form (bins of little-endian float64). Each detection must come
out exactly as `parse_full` makes the labelled measurement with the scan's fields plus the
detection's own: the same record, or the same reason prefixed `detection <i>: `."""

from __future__ import annotations

import dataclasses
import math
import random
import struct

import msgpack
import pytest
from reference.record import track_scan

from zenoh_track.wire import Measurement, PlotScan, Rejected, parse_full, parse_plots
from zenoh_track.wire import plots as plots_module

NOISE = (10.0, 0.01, 0.02, 5.0)  # (sr, saz, sel, sigma) when neither scan nor detection has one
NAN, INF = math.nan, math.inf
ORIGIN = (0.0, 0.0, 0.0)


def pk(msg) -> bytes:
    return msgpack.packb(msg, use_bin_type=True)


def f64(*values: float) -> bytes:
    return struct.pack(f"<{len(values)}d", *values)


def scan(msg, sensor="radar-1", noise=NOISE) -> PlotScan:
    return parse_plots(sensor, pk(msg), noise)


def labelled(fields, sensor="radar-1", noise=NOISE) -> Measurement | str:
    """parse_full's record (target blanked) or reason for one labelled message."""
    try:
        m = parse_full(sensor, "x", pk(fields), noise)
    except Rejected as exc:
        return str(exc)
    return dataclasses.replace(m, target="")


def outcomes(s: PlotScan) -> dict[int, Measurement | str]:
    """index -> record or reason (without the prefix) of every detection of a scan."""
    out: dict[int, Measurement | str] = dict(zip(s.index, s.detections, strict=True))
    for i, reason in s.rejected:
        prefix = f"detection {i}: "
        assert reason.startswith(prefix)
        out[i] = reason[len(prefix):]
    return out


def whole(msg, *words, payload=None, sensor="radar-1") -> str:
    """Assert the scan is rejected whole, with every word in the reason."""
    with pytest.raises(Rejected) as info:
        parse_plots(sensor, pk(msg) if payload is None else payload, NOISE)
    reason = str(info.value)
    for w in words:
        assert w in reason, f"{w!r} not in reason {reason!r}"
    return reason


def polar(*values, sigmas, sensor_pos=ORIGIN, t=1.0) -> Measurement:
    return Measurement("radar-1", "", t, len(values), True, values, sigmas, sensor_pos, None)


def cart(*values, sigmas, sensor_pos=ORIGIN, t=1.0) -> Measurement:
    return Measurement("radar-1", "", t, len(values), False, values, sigmas, sensor_pos, None)


# ---------------------------------------------------------------- `dets`, accepted
def test_dets_polar_2d_and_3d_defaults():
    s = scan({"t": 1.0, "dets": [{"r": 1000.0, "az": 0.5}, {"r": 2000.0, "az": -1.0, "el": 0.2}]})
    assert s == PlotScan("radar-1", 1.0, ORIGIN, (
        polar(1000.0, 0.5, sigmas=(10.0, 0.01)),
        polar(2000.0, -1.0, 0.2, sigmas=(10.0, 0.01, 0.02)),
    ), (0, 1), ())


def test_dets_cartesian_2d_and_3d():
    s = scan({"t": 2.0, "sigma": 1.5, "dets": [{"pos": [1.0, 2.0]}, {"pos": [1.0, 2.0, 3.0]}]})
    assert s.detections == (cart(1.0, 2.0, sigmas=(1.5, 1.5), t=2.0),
                            cart(1.0, 2.0, 3.0, sigmas=(1.5, 1.5, 1.5), t=2.0))


def test_scan_noise_detection_noise_and_defaults():
    s = scan({"t": 1.0, "sr": 3.0, "sel": 0.5, "sigma": [1.0, 2.0, 3.0], "dets": [
        {"r": 100.0, "az": 0.0, "el": 0.1},  # scan sr, sel; default saz
        {"r": 100.0, "az": 0.0, "el": 0.1, "sr": 7.0, "saz": 0.2},  # its own sr, saz
        {"pos": [1.0, 2.0, 3.0]},  # scan sigma per axis
        {"pos": [1.0, 2.0, 3.0], "sigma": 0.0},  # its own sigma, exact
        {"pos": [1.0, 2.0], "sigma": [4.0]},  # its own per-axis list of 1
    ]})
    assert [m.sigmas for m in s.detections] == [
        (3.0, 0.01, 0.5), (7.0, 0.2, 0.5), (1.0, 2.0, 3.0), (0.0, 0.0, 0.0), (4.0, 4.0)]


def test_sensor_pos_and_ints():
    s = scan({"t": 3, "sensor_pos": [100, -50.0, 2], "dets": [{"r": 5, "az": 1, "sr": 2}]})
    assert s.t == 3.0 and s.sensor_pos == (100.0, -50.0, 2.0)
    assert s.detections == (polar(5.0, 1.0, sigmas=(2.0, 0.01), sensor_pos=(100.0, -50.0, 2.0),
                                  t=3.0),)
    assert all(type(x) is float for x in s.detections[0].values + s.detections[0].sigmas)


def test_unknown_keys_ignored():
    s = scan({"t": 1.0, "seq": "x", "mode": [1], "dets": [
        {"r": 1.0, "az": 0.0, "t": "later", "seq": -1.5, "sensor_pos": 7, "snr": 12.0},
    ]})
    assert s.detections == (polar(1.0, 0.0, sigmas=(10.0, 0.01)),) and s.rejected == ()
    s = scan({"t": 1.0, "r": f64(1.0), "az": f64(0.0), "snr": f64(3.0), "dets_v": 2})
    assert s.detections == (polar(1.0, 0.0, sigmas=(10.0, 0.01)),)


def test_records_are_frozen_measurements():
    for m in (scan({"t": 1.0, "dets": [{"r": 1.0, "az": 0.0}]}).detections[0],
              scan({"t": 1.0, "r": f64(1.0), "az": f64(0.0)}).detections[0]):
        assert type(m) is Measurement and m == polar(1.0, 0.0, sigmas=(10.0, 0.01))
        assert hash(m) == hash(polar(1.0, 0.0, sigmas=(10.0, 0.01)))
        with pytest.raises(dataclasses.FrozenInstanceError):
            m.t = 2.0


def test_overflowing_sum_named_by_the_full_check():
    """Huge finite values: the quick checks cannot prove them finite, the full check names
    the bound they break."""
    s = scan({"t": 1.0, "dets": [{"r": 1e308, "az": 0.0}, {"r": 1e9, "az": 0.0, "sr": 1e9}]})
    assert s.rejected == ((0, "detection 0: field 'r' must be <= 1000000000.0, got 1e+308"),)
    assert s.detections == (polar(1e9, 0.0, sigmas=(1e9, 0.01)),)
    s = scan({"t": 1.0, "r": f64(1e308, 5.0), "az": f64(0.0, 0.0)})
    assert [i for i, _ in s.rejected] == [0]
    assert s.detections == (polar(5.0, 0.0, sigmas=(10.0, 0.01)),)


# ---------------------------------------------------------------- columnar, accepted
def test_columnar_polar_2d_and_3d():
    s = scan({"t": 1.0, "r": f64(1.0, 2.0), "az": f64(0.1, 0.2), "sr": 4})
    assert s.detections == (polar(1.0, 0.1, sigmas=(4.0, 0.01)),
                            polar(2.0, 0.2, sigmas=(4.0, 0.01)))
    s = scan({"t": 1.0, "r": f64(1.0, 2.0), "az": f64(0.1, 0.2), "el": f64(0.3, 0.4),
              "sel": f64(0.5, 0.6)})
    assert s.detections == (polar(1.0, 0.1, 0.3, sigmas=(10.0, 0.01, 0.5)),
                            polar(2.0, 0.2, 0.4, sigmas=(10.0, 0.01, 0.6)))
    assert s.index == (0, 1)


def test_columnar_cartesian_widths():
    s = scan({"t": 1.0, "pos": f64(1, 2, 3, 4, 5, 6), "dim": 2, "sigma": [1.0, 2.0]})
    assert s.detections == tuple(cart(x, y, sigmas=(1.0, 2.0))
                                 for x, y in ((1.0, 2.0), (3.0, 4.0), (5.0, 6.0)))
    s = scan({"t": 1.0, "pos": f64(1, 2, 3, 4, 5, 6), "dim": 3})
    assert s.detections == (cart(1.0, 2.0, 3.0, sigmas=(5.0,) * 3),
                            cart(4.0, 5.0, 6.0, sigmas=(5.0,) * 3))
    s = scan({"t": 1.0, "pos": f64(1, 2, 3, 4, 5, 6), "sigma": f64(0.0, 2.0, 3.0)})  # 3 rows of 2
    assert s.detections == (cart(1.0, 2.0, sigmas=(0.0, 0.0)), cart(3.0, 4.0, sigmas=(2.0, 2.0)),
                            cart(5.0, 6.0, sigmas=(3.0, 3.0)))


def test_columnar_sensor_pos():
    s = scan({"t": 1.0, "sensor_pos": [1.0, 2.0, 3.0], "r": f64(9.0), "az": f64(0.0)})
    assert s.detections == (polar(9.0, 0.0, sigmas=(10.0, 0.01), sensor_pos=(1.0, 2.0, 3.0)),)


def random_rows(rnd: random.Random, n: int, kind: str) -> list[dict]:
    rows = []
    for _ in range(n):
        if kind.startswith("polar"):
            row = {"r": rnd.uniform(0, 1e5), "az": rnd.uniform(-4, 4), "sr": rnd.uniform(0, 50),
                   "saz": rnd.uniform(0, 0.1), "sel": rnd.uniform(0, 0.1),
                   "sigma": rnd.uniform(0, 9)}
            if kind == "polar3":
                row["el"] = rnd.uniform(-1, 1.5)
        else:
            row = {"pos": [rnd.uniform(-1e4, 1e4) for _ in range(int(kind[-1]))],
                   "sigma": rnd.uniform(0, 9), "sr": rnd.uniform(0, 50)}
        rows.append(row)
    return rows


@pytest.mark.parametrize("kind", ["polar2", "polar3", "cart2", "cart3"])
@pytest.mark.parametrize("per_row_noise", [False, True])
def test_columnar_equals_dets(kind, per_row_noise):
    rnd = random.Random(hash((kind, per_row_noise)) & 0xFFFF)
    rows = random_rows(rnd, 50, kind)
    head = {"t": 12.5, "sensor_pos": [10.0, -20.0, 5.0]}
    noise_keys = [k for k in ("sr", "saz", "sel", "sigma") if k in rows[0]]
    if not per_row_noise:  # scan-wide noise: one number for all rows
        for row in rows:
            for k in noise_keys:
                row.pop(k)
        head |= {"sr": 2.0, "sigma": 0.5}
    dets = scan({**head, "dets": rows})
    columns = {k: f64(*(x for row in rows for x in (row[k] if k == "pos" else [row[k]])))
               for k in rows[0]}
    if kind.startswith("cart"):
        columns["dim"] = int(kind[-1])
    col = scan({**head, **columns})
    assert col == dets and len(col.detections) == 50 and col.rejected == ()
    assert list(col.detections) == [labelled({**head, **row}) for row in rows]


def test_empty_scans():
    empty = PlotScan("radar-1", 4.0, ORIGIN, (), (), ())
    assert scan({"t": 4.0, "dets": []}) == empty
    assert scan({"t": 4.0, "r": b"", "az": b""}) == empty
    assert scan({"t": 4.0, "r": b"", "az": b"", "el": b"", "sr": b""}) == empty
    assert scan({"t": 4.0, "pos": b""}) == empty
    assert scan({"t": 4.0, "pos": b"", "dim": 2, "sigma": b""}) == empty


def test_ten_thousand_columnar_rows():
    n = 10_000
    s = scan({"t": 1.0, "r": f64(*[float(i) for i in range(n)]), "az": f64(*[0.5] * n),
              "el": f64(*[0.1] * n)})
    assert len(s.detections) == n and s.index == tuple(range(n))
    assert s.detections[-1] == polar(n - 1.0, 0.5, 0.1, sigmas=(10.0, 0.01, 0.02))


# ---------------------------------------------------------------- whole-scan rejections
@pytest.mark.parametrize("msg, words", [
    ([1.0, 2.0], ["payload must be a MessagePack map"]),
    ({"dets": []}, ["missing required field 't'"]),
    ({"t": "now", "dets": []}, ["field 't' must be a number, got str"]),
    ({"t": NAN, "dets": []}, ["field 't' is not finite"]),
    ({"t": 1.0, "sensor_pos": [1.0, 2.0], "dets": []},
     ["field 'sensor_pos' must be a list of 3 numbers"]),
    ({"t": 1.0, "sensor_pos": [1.0, INF, 0.0], "dets": []}, ["'sensor_pos' is not finite"]),
    ({"t": 1.0, "sr": -1.0, "dets": []}, ["field 'sr' must be >= 0.0, got -1.0"]),
    ({"t": 1.0, "saz": "x", "dets": []}, ["field 'saz' must be a number, got str"]),
    ({"t": 1.0, "sel": NAN, "dets": []}, ["field 'sel' is not finite"]),
    ({"t": 1.0, "sr": f64(1.0), "dets": []}, ["field 'sr' must be a number, got bytes"]),
    ({"t": 1.0, "sigma": [1.0, 2.0, 3.0, 4.0], "dets": []},
     ["field 'sigma' must be a list of 1 or 2 or 3 numbers"]),
    ({"t": 1.0, "sigma": [1.0, -2.0], "dets": []}, ["field 'sigma' must be >= 0.0, got -2.0"]),
    ({"t": 1.0}, ["scan needs 'dets'", "columnar"]),
    ({"t": 1.0, "sr": f64(1.0)}, ["scan needs 'dets'"]),
    ({"t": 1.0, "dets": [], "r": f64(1.0), "az": f64(0.0)}, ["both 'dets' and columnar", "r, az"]),
    ({"t": 1.0, "dets": {"r": 1.0, "az": 0.0}}, ["field 'dets' must be a list", "got dict"]),
    ({"t": 1.0, "dets": None}, ["field 'dets' must be a list", "got NoneType"]),
    # columnar
    ({"t": 1.0, "r": f64(1.0, 2.0), "az": f64(0.0)}, ["unequal lengths", "r 2 rows", "az 1 rows"]),
    ({"t": 1.0, "r": f64(1.0), "az": f64(0.0), "sr": f64(1.0, 2.0)}, ["unequal", "sr 2 rows"]),
    ({"t": 1.0, "pos": f64(1, 2, 3, 4), "dim": 2, "sigma": f64(1.0)}, ["unequal", "pos 2 rows"]),
    ({"t": 1.0, "r": f64(1.0) + b"\0", "az": f64(0.0)}, ["bin 'r' has 9 bytes", "multiple of 8"]),
    ({"t": 1.0, "r": f64(1.0), "az": b"\0\0"}, ["bin 'az' has 2 bytes"]),
    ({"t": 1.0, "r": f64(1.0), "az": f64(0.0), "sel": b"\0" * 12}, ["bin 'sel' has 12 bytes"]),
    ({"t": 1.0, "pos": f64(1, 2, 3, 4), "dim": 3}, ["bin 'pos' has 32 bytes, not rows of 3"]),
    ({"t": 1.0, "pos": f64(1, 2, 3, 4), "dim": 4}, ["'dim'", "must be 2 or 3, got 4"]),
    ({"t": 1.0, "pos": f64(1, 2, 3, 4), "dim": "2"}, ["'dim'", "must be 2 or 3, got '2'"]),
    ({"t": 1.0, "pos": f64(1, 2, 3, 4), "dim": True}, ["'dim'", "must be 2 or 3, got True"]),
    ({"t": 1.0, "pos": f64(1, 2, 3, 4, 5, 6)}, ["'pos' needs 'dim'"]),
    ({"t": 1.0, "pos": f64(1, 2, 3, 4), "sigma": f64(1.0)},
     ["'pos' of 4 float64 is not 1 rows of 2 or 3", "'dim'"]),
    ({"t": 1.0, "pos": f64(1, 2, 3, 4), "sigma": b""}, ["is not 0 rows of 2 or 3"]),
    ({"t": 1.0, "r": f64(1.0)}, ["columnar polar scan needs both 'r' and 'az'"]),
    ({"t": 1.0, "az": f64(1.0)}, ["columnar polar scan needs both 'r' and 'az'"]),
    ({"t": 1.0, "el": f64(1.0)}, ["columnar polar scan needs both 'r' and 'az'"]),
    ({"t": 1.0, "r": f64(1.0), "az": f64(0.0), "pos": f64(1, 2, 3)}, ["either", "not both"]),
    ({"t": 1.0, "el": f64(0.0), "pos": f64(1, 2, 3)}, ["either", "not both"]),
    ({"t": 1.0, "r": [1.0], "az": f64(0.0)}, ["field 'r' must be a bin", "got list"]),
    ({"t": 1.0, "pos": "abc"}, ["field 'pos' must be a bin", "got str"]),
    ({"t": 1.0, "r": f64(1.0), "az": f64(0.0), "sr": "a"}, ["'sr' must be a number, got str"]),
    ({"t": 1.0, "r": f64(1.0), "az": f64(0.0), "saz": [0.1]}, ["'saz' must be a number, got list"]),
    ({"t": 1.0, "r": f64(1.0), "az": f64(0.0), "sr": -0.5}, ["'sr' must be >= 0.0, got -0.5"]),
])
def test_whole_scan_rejected(msg, words):
    whole(msg, *words)


@pytest.mark.parametrize("payload, words", [
    (b"", ["payload must be a MessagePack map"]),
    (b"\xc1", ["payload is not valid MessagePack"]),
    (b"\x81\xa1t", ["payload is not valid MessagePack"]),  # map cut short
    (pk({"t": 1.0, "dets": []}) + b"\x00", ["payload is not valid MessagePack"]),  # extra data
])
def test_garbage_bytes(payload, words):
    whole(None, *words, payload=payload)


def test_bad_sensor_chunk():
    whole({"t": 1.0, "dets": []}, "sensor chunk 'a/b' must be letters", sensor="a/b")
    whole({"t": 1.0, "dets": []}, "sensor chunk ''", sensor="")


def test_max_detections(monkeypatch):
    monkeypatch.setattr(plots_module, "MAX_DETECTIONS", 3)
    det = {"r": 1.0, "az": 0.0}
    assert len(scan({"t": 1.0, "dets": [det] * 3}).detections) == 3
    assert len(scan({"t": 1.0, "r": f64(1, 1, 1), "az": f64(0, 0, 0)}).detections) == 3
    whole({"t": 1.0, "dets": [det] * 4}, "scan has 4 detections, more than the limit of 3")
    whole({"t": 1.0, "dets": [7] * 4}, "scan has 4 detections")
    whole({"t": 1.0, "r": f64(1, 1, 1, 1), "az": f64(0, 0, 0, 0)}, "scan has 4 detections")
    whole({"t": 1.0, "pos": f64(*[0.0] * 8), "dim": 2}, "scan has 4 detections")


def test_max_detections_documented_value():
    assert plots_module.MAX_DETECTIONS == 100_000


def test_random_bytes_never_crash():
    rnd = random.Random(7)
    for _ in range(300):
        data = bytes(rnd.randrange(256) for _ in range(rnd.randrange(1, 40)))
        try:
            assert isinstance(parse_plots("s", data, NOISE), PlotScan)
        except Rejected:
            pass


# ---------------------------------------------------------------- per-detection rejections
BAD_DETECTIONS = [
    {"r": -1.0, "az": 0.0},
    {"r": NAN, "az": 0.0},
    {"r": 1.0, "az": -INF},
    {"r": 1.0, "az": 0.0, "el": INF},
    {"r": "far", "az": 0.0},
    {"r": True, "az": 0.0},
    {"r": None, "az": 0.0},
    {"az": 0.0},
    {"r": 1.0},
    {"el": 0.1},
    {},
    {"r": 1.0, "az": 0.0, "pos": [1.0, 2.0]},
    {"r": 1.0, "az": 0.0, "sr": -1.0},
    {"r": 1.0, "az": 0.0, "saz": NAN},
    {"r": 1.0, "az": 0.0, "el": 0.0, "sel": -0.1},
    {"r": 1.0, "az": 0.0, "el": "up"},
    {"r": 1.0, "az": 0.0, "el": None},
    {"pos": [1.0]},
    {"pos": [1.0, 2.0, 3.0, 4.0]},
    {"pos": "1,2"},
    {"pos": [1.0, NAN]},
    {"pos": [1.0, "2"]},
    {"pos": [1.0, 2.0], "sigma": -1.0},
    {"pos": [1.0, 2.0], "sigma": [1.0, 2.0, 3.0]},
    {"pos": [1.0, 2.0], "sigma": []},
    {"pos": [1.0, 2.0, 3.0], "sigma": [1.0, INF, 1.0]},
    {"pos": [1.0, 2.0], "sigma": "wide"},
]


@pytest.mark.parametrize("bad", BAD_DETECTIONS, ids=repr)
def test_bad_detection_set_aside(bad):
    head = {"t": 2.0, "sr": 3.0, "sensor_pos": [1.0, 2.0, 3.0]}
    good = [{"r": 10.0, "az": 0.1}, {"pos": [1.0, 2.0, 3.0]}]
    s = scan({**head, "dets": [good[0], bad, good[1]]})
    reason = labelled({**head, **bad})
    assert isinstance(reason, str)
    assert s.rejected == ((1, f"detection 1: {reason}"),)
    assert s.index == (0, 2)
    assert s.detections == tuple(labelled({**head, **g}) for g in good)


@pytest.mark.parametrize("bad", [7, "r=1", None, [1.0, 0.0], True])
def test_detection_not_a_map(bad):
    s = scan({"t": 1.0, "dets": [bad, {"r": 1.0, "az": 0.0}]})
    assert s.rejected == ((0, f"detection 0: must be a map {{r, az[, el]}} or {{pos}}, "
                              f"got {type(bad).__name__}"),)
    assert s.index == (1,)


def test_per_detection_noise_checked_like_a_message():
    """A 2-D polar detection's own bad `sel` is not read (as in a labelled message)."""
    s = scan({"t": 1.0, "dets": [{"r": 1.0, "az": 0.0, "sel": -1.0},
                                 {"pos": [0.0, 0.0], "el": "x"}]})
    assert s.rejected == () and s.index == (0, 1)


def test_columnar_bad_rows():
    s = scan({"t": 1.0, "r": f64(1.0, NAN, 3.0, -4.0, 5.0), "az": f64(0.0, 0.0, INF, 0.0, 0.0),
              "sr": f64(1.0, 1.0, 1.0, 1.0, -2.0)})
    assert s.index == (0,)
    assert s.rejected == ((1, "detection 1: field 'r' is not finite (nan)"),
                          (2, "detection 2: field 'az' is not finite (inf)"),
                          (3, "detection 3: field 'r' must be >= 0.0, got -4.0"),
                          (4, "detection 4: field 'sr' must be >= 0.0, got -2.0"))
    s = scan({"t": 1.0, "pos": f64(1, 2, 3, 4, INF, 6), "dim": 2, "sigma": f64(1.0, -1.0, 1.0)})
    assert s.index == (0,)
    assert [r for _, r in s.rejected] == ["detection 1: field 'sigma' must be >= 0.0, got -1.0",
                                          "detection 2: field 'pos' is not finite (inf)"]
    s = scan({"t": 1.0, "r": f64(1.0, 2.0), "az": f64(0.0, 0.0), "el": f64(0.0, NAN),
              "sel": f64(-1.0, 0.1), "sigma": f64(NAN, NAN)})  # sigma is not read for polar
    assert s.rejected == ((0, "detection 0: field 'sel' must be >= 0.0, got -1.0"),
                          (1, "detection 1: field 'el' is not finite (nan)"))


def test_columnar_bad_rows_match_parse_full():
    rnd = random.Random(3)
    n = 200
    r = [rnd.choice([1.0, 0.0, -0.0, -1.0, NAN, INF, 1e308, 5e3]) for _ in range(n)]
    az = [rnd.choice([0.5, -INF, -3.0]) for _ in range(n)]
    sr = [rnd.choice([1.0, -1e-9, NAN, 0.0]) for _ in range(n)]
    s = scan({"t": 1.0, "sel": 0.1, "r": f64(*r), "az": f64(*az), "sr": f64(*sr)})
    got = outcomes(s)
    assert sorted(got) == list(range(n)) and s.rejected
    for i in range(n):
        assert got[i] == labelled({"t": 1.0, "sel": 0.1, "r": r[i], "az": az[i], "sr": sr[i]})


def test_scan_sigma_list_of_wrong_width_rejects_each_row():
    want = "field 'sigma' must have 1 or 2 entries"
    for s in (scan({"t": 1.0, "sigma": [1.0, 2.0, 3.0], "pos": f64(1, 2, 3, 4), "dim": 2}),
              scan({"t": 1.0, "sigma": [1.0, 2.0, 3.0], "dets": [{"pos": [1, 2]}] * 2})):
        assert s.detections == () and s.rejected == ((0, f"detection 0: {want}"),
                                                     (1, f"detection 1: {want}"))


def test_bad_default_noise_rejects_rows_that_use_it():
    noise = (-1.0, 0.01, 0.02, NAN)
    for s in (scan({"t": 1.0, "r": f64(1.0), "az": f64(0.0)}, noise=noise),
              scan({"t": 1.0, "dets": [{"r": 1.0, "az": 0.0}]}, noise=noise)):
        assert s.rejected == ((0, "detection 0: field 'sr' must be >= 0.0, got -1.0"),)
    s = scan({"t": 1.0, "sr": 2.0, "dets": [{"r": 1.0, "az": 0.0}, {"pos": [0.0, 0.0]}]},
             noise=noise)
    assert s.index == (0,)
    assert s.rejected == ((1, "detection 1: field 'sigma' is not finite (nan)"),)


VALUES = [1.0, 0.0, -1.0, 2, -3, NAN, INF, 1e308, True, None, "x", [], [1.0], [1.0, 2.0],
          [1.0, 2.0, 3.0], [1, NAN], [1.0, 2.0, 3.0, 4.0], {"a": 1}, b"\0" * 8]


def test_random_detections_match_parse_full():
    """Random detections of every shape: each outcome is parse_full's on the merged map."""
    rnd = random.Random(11)
    keys = ("r", "az", "el", "pos", "sr", "saz", "sel", "sigma")
    for _ in range(40):
        head = {"t": rnd.choice([0.0, 5, 1e9])}
        if rnd.random() < 0.5:
            head["sensor_pos"] = [1.0, 2.0, 3.0]
        for k in ("sr", "saz", "sel", "sigma"):
            if rnd.random() < 0.3:
                head[k] = rnd.choice([0.0, 0.5, 1])
        if rnd.random() < 0.3:
            head["sigma"] = rnd.choice([[1.0], [1.0, 2.0], [1.0, 2.0, 3.0]])
        dets = []
        for _ in range(20):
            det = {k: rnd.choice(VALUES) for k in keys if rnd.random() < 0.4}
            if rnd.random() < 0.5:  # a well-formed shape, its noise drawn from VALUES
                shape = rnd.choice([{"r": 5.0, "az": 1.0}, {"r": 5.0, "az": 1.0, "el": 0.1},
                                    {"pos": [1.0, 2.0]}, {"pos": [1.0, 2.0, 3.0]}])
                for k in ("r", "az", "el") if "pos" in shape else ("pos",):
                    det.pop(k, None)
                det |= shape
            dets.append(det)
        s = scan({**head, "dets": dets})
        got = outcomes(s)
        assert sorted(got) == list(range(len(dets)))
        for i, det in enumerate(dets):
            assert got[i] == labelled({**head, **det}), (head, det)


def test_scan_mixing_dimensions_is_tracked_in_two_parts():
    """A scan of 2-D and 3-D detections: each part with the tracks of its dimension
    (it crashed the associator and lost the worker's batch once)."""
    from conftest import make_tracker

    tracker = make_tracker()
    s = scan({"t": 1.0, "dets": [{"r": 1000.0, "az": 0.5}, {"pos": [1.0, 2.0, 3.0]},
                                 {"r": 2000.0, "az": 0.1, "el": 0.2}]})
    outcomes, _ = track_scan(tracker, s)
    assert [o.reason for o in outcomes] == [None] * 3
    assert {a.dim: len(a.rows()) for a in tracker.store.layouts.values()} == {2: 1, 3: 2}
    outcomes, _ = track_scan(tracker, scan({"t": 2.0, "dets": [{"pos": [1.0, 2.0, 3.0]},
                                                              {"r": 1000.0, "az": 0.5}]}))
    assert [o.reason for o in outcomes] == [None] * 2 and len(tracker) == 3
