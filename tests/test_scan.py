"""Batched labelled scans, `<ns>/scan/<sensor>` (contract 1.1): each row means what the
single message would, a bad row is rejected alone, a malformed scan whole; through the
real service the batched feed gives the same tracks as the single messages."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import Collector

from zenoh_track.wire import Rejected, f64_bin, pack, parse_full, parse_measurement, parse_scan

NOISE = (10.0, 0.01, 0.01, 1.0)


def rows(n: int, seed: int = 1) -> list[dict]:
    rng = np.random.default_rng(seed)
    return [{"t": float(t), "r": float(r), "az": float(a), "el": float(e)}
            for t, r, a, e in zip(rng.uniform(0, 5, n), rng.uniform(1e3, 5e4, n),
                                  rng.uniform(-3, 3, n), rng.uniform(0, 1, n), strict=True)]


def scan(rs: list[dict], ids: list[str], **extra) -> bytes:
    msg = {"ids": ids, "t": f64_bin([m["t"] for m in rs]),
           **{k: f64_bin([m[k] for m in rs]) for k in ("r", "az", "el")}, "sr": 20.0,
           **extra}
    return pack(msg)


def test_each_row_is_the_single_message():
    rs = rows(50)
    rs[3]["r"] = -5.0
    rs[7]["az"] = math.nan
    ids = [f"x{i}" for i in range(50)]
    ids[11] = "bad id"
    got = parse_scan("radar1", scan(rs, ids), NOISE)
    assert [i for i, _ in got.rejected] == [3, 7, 11]
    good = [i for i in range(50) if i not in (3, 7, 11)]
    assert len(got.measurements) == len(good)
    for i, m in zip(good, got.measurements, strict=True):
        single = parse_measurement("radar1", ids[i], pack({**rs[i], "sr": 20.0}), NOISE)
        assert m == single
    for i, reason in got.rejected:
        with pytest.raises(Rejected) as exc:
            parse_full("radar1", ids[i], pack({**rs[i], "sr": 20.0}), NOISE)
        assert reason == f"row {i} ({ids[i]}): {exc.value}"


def test_one_time_for_all_rows_and_cartesian_rows():
    got = parse_scan("s", pack({"ids": ["a", "b", "c", "d"], "t": 2.5,
                                "pos": f64_bin([float(v) for v in range(12)]), "sigma": 3.0}),
                     NOISE)
    assert [m.t for m in got.measurements] == [2.5] * 4
    assert [m.values for m in got.measurements][1] == (3.0, 4.0, 5.0)
    assert got.measurements[0] == parse_measurement(
        "s", "a", pack({"t": 2.5, "pos": [0.0, 1.0, 2.0], "sigma": 3.0}), NOISE)
    assert not got.rejected


@pytest.mark.parametrize("msg, words", [
    ({"t": 1.0, "r": f64_bin([1.0]), "az": f64_bin([0.0])}, "ids"),
    ({"ids": ["a", "b"], "t": 1.0, "r": f64_bin([1.0]), "az": f64_bin([0.0, 1.0])}, "rows"),
    ({"ids": ["a"], "t": f64_bin([1.0, 2.0]), "r": f64_bin([1.0]), "az": f64_bin([0.0])}, "'t'"),
    ({"ids": ["a"], "t": 1.0, "r": b"\x00" * 7, "az": f64_bin([0.0])}, "multiple of 8"),
    ({"ids": ["a"], "t": 1.0}, "'r' and 'az'"),
])
def test_malformed_scan_is_rejected_whole(msg, words):
    with pytest.raises(Rejected, match=words):
        parse_scan("s", pack(msg), NOISE)


@pytest.mark.slow
def test_batched_feed_gives_the_single_messages_tracks(service_factory):
    out = {}
    for ns, extra in (("single", []), ("batched", ["--batched"])):
        svc, s = service_factory("--clock", "lockstep", ns=ns)
        tracks = Collector(s, f"{ns}/tracks/*")
        svc.feed("swarm", "--targets", "40", "--duration", "3", *extra)
        assert tracks.wait_for(lambda ss: len(ss) >= 160, timeout=30)
        out[ns] = {(b["id"], b["updates"]): b for b in tracks.bodies()}
        st = next(iter(s.get(f"{ns}/status", timeout=10))).ok.payload.to_bytes()
        assert b"meas_accepted" in st
    assert out["single"].keys() == out["batched"].keys() and len(out["single"]) == 160
    for k, a in out["single"].items():
        b = out["batched"][k]
        assert a["t"] == b["t"]
        np.testing.assert_allclose(a["x"], b["x"], rtol=1e-12)
        np.testing.assert_allclose(a["P"], b["P"], rtol=1e-9, atol=1e-9)
