"""A batched labelled scan applied in one pass over its columns (`wire.parse_scan_columns`,
`MeasurementBatch.of_scan`, `Tracker.step` on `batches.Labelled`) gives exactly what its rows
give as single measurements: the same rows rejected with the same reasons, the same
tracks to the last bit (repeated targets, out-of-sequence and duplicate rows, a track of
the other dimension, the time policy), here and through the real service."""

from __future__ import annotations

import math
import random
import time

import numpy as np
import pytest
from reference.record import track

from zenoh_track import defaults
from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.tracking.batches import Labelled
from zenoh_track.tracking.tracker import Tracker
from zenoh_track.wire import (
    Rejected,
    f64_bin,
    pack,
    parse_measurement,
    parse_scan,
    parse_scan_columns,
    unpack,
)

NOISE = defaults.NOISE
BAD = {"r": [-5.0, math.nan, 1e12], "az": [math.inf, 99.0], "el": [math.nan, 4.0],
       "t": [math.nan, -math.inf], "sr": [-1.0, math.nan], "pos": [math.nan, 1e15],
       "sigma": [-2.0, math.inf]}


def polar_rows(rng: random.Random, n: int, t0: float, el: bool = True) -> list[dict]:
    out = []
    for i in range(n):
        row = {"t": t0 + 0.01 * i, "r": 1e3 + 500 * i + 20 * t0 + rng.gauss(0, 10),
               "az": -3 + 6 * i / max(n, 1) + 1e-4 * t0, "sr": 15.0 + rng.random()}
        if el:
            row["el"] = 0.05
        out.append(row)
    return out


def scan_msg(rows: list[dict], ids: list[str], noise_bins: bool = False, **extra) -> dict:
    msg: dict = {"ids": ids, "t": f64_bin([r["t"] for r in rows]), **extra}
    for k in ("r", "az", "el", "pos"):
        if k in rows[0]:
            flat = [v for r in rows for v in r[k]] if k == "pos" else [r[k] for r in rows]
            msg[k] = f64_bin(flat)
    for k in ("sr", "sigma"):
        if k in rows[0]:
            msg[k] = f64_bin([r[k] for r in rows]) if noise_bins else rows[0][k]
    return msg


def spoil(rng: random.Random, rows: list[dict], ids: list[str], k: int) -> None:
    """k rows get a bad value (or a bad id)."""
    for _ in range(k):
        i = rng.randrange(len(rows))
        field = rng.choice([f for f in BAD if f in rows[i]] + ["id"])
        if field == "id":
            ids[i] = rng.choice(["bad id", "", "a/b", "x" * 70 + "!"])
        elif field == "pos":
            rows[i]["pos"] = [*rows[i]["pos"][:-1], rng.choice(BAD["pos"])]
        else:
            rows[i][field] = rng.choice(BAD[field])


def assert_same_batch(a: MeasurementBatch, b: MeasurementBatch) -> None:
    for name in ("t", "polar", "values", "sigmas", "origin"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


@pytest.mark.parametrize("seed", range(12))
def test_columns_are_the_records(seed):
    rng = random.Random(seed)
    n = rng.choice([1, 7, 40])
    ids = [f"x{i}" for i in range(n)]
    if seed % 3 == 2:  # Cartesian, 2-D or 3-D, one sigma or per row
        d = 2 + seed % 2
        rows = [{"t": 1.0 + 0.01 * i, "pos": [100.0 * i, -50.0, 10.0][:d],
                 "sigma": 5.0 + i} for i in range(n)]
        extra = {"dim": d}
    else:
        rows = polar_rows(rng, n, 3.0, el=seed % 2 == 0)
        extra = {"sensor_pos": [10.0, 20.0, 5.0]} if seed % 4 == 0 else {}
    spoil(rng, rows, ids, rng.randrange(0, 4))
    payload = pack(scan_msg(rows, ids, noise_bins=seed % 2 == 1, **extra))
    try:
        ref = parse_scan("s", payload, NOISE)
    except Rejected as exc:
        with pytest.raises(Rejected, match=str(exc)[:30]):
            parse_scan_columns("s", payload, NOISE)
        return
    cols = parse_scan_columns("s", payload, NOISE)
    assert cols.rejected == ref.rejected
    assert cols.ids == [m.target for m in ref.measurements]
    if ref.measurements:
        assert_same_batch(MeasurementBatch.of_scan(cols),
                          MeasurementBatch.of(ref.measurements, ref.measurements[0].dim))


def scans(rng: random.Random) -> list[dict]:
    """Scans of 30 targets with repeats, out-of-sequence and duplicate rows, and a target
    that has a 2-D track."""
    out = []
    for k in range(4):
        rows = polar_rows(rng, 30, float(k))
        ids = [f"x{i}" for i in range(30)]
        if k == 2:
            rows.append({**rows[3], "t": rows[3]["t"] + 0.5})  # x3 again, later
            ids.append("x3")
            rows.append(dict(rows[4]))  # x4 again, same time: a duplicate
            ids.append("x4")
            rows.append({**rows[5], "t": 0.5})  # x5 before its last update
            ids.append("x5")
            rows.append(dict(rows[6], t=rows[6]["t"] + 0.2))
            ids.append("flat")  # has a 2-D track
        out.append(scan_msg(rows, ids))
    return out


def singles(msg: dict) -> list:
    """The rows of a scan message as single measurements (parse_measurement)."""
    cols = {k: np.frombuffer(v, "<f8").tolist() for k, v in msg.items() if isinstance(v, bytes)}
    out = []
    for i, target in enumerate(msg["ids"]):
        body = {k: c[i] for k, c in cols.items()}
        body.update({k: v for k, v in msg.items() if k not in cols and k != "ids"})
        out.append(parse_measurement("s", target, pack(body), NOISE))
    return out


def test_one_pass_gives_the_single_messages_tracks():
    rng = random.Random(3)
    msgs = scans(rng)
    flat = parse_measurement("s", "flat", pack({"t": 0.0, "pos": [1.0, 2.0], "sigma": 3.0}),
                             NOISE)
    one, many = Tracker.from_config(), Tracker.from_config()
    track(one, [flat])
    track(many, [flat])
    cut = random.Random(4)
    seen: set[str] = set()
    for msg in msgs:
        ms = singles(msg)
        reasons = {}
        i = 0
        while i < len(ms):  # the worker's batches: any sizes
            k = cut.randint(1, 12)
            outcomes, _ = track(one, ms[i:i + k])
            reasons.update({i + j: o.reason for j, o in enumerate(outcomes) if o.reason})
            i += k
        cols = parse_scan_columns("s", pack(msg), NOISE)
        assert not cols.rejected
        got = many.step(Labelled(["s"] * len(cols.ids), cols.ids, MeasurementBatch.of_scan(cols)))
        assert dict(got.rejected) == reasons
        assert got.accepted == len(ms) - len(reasons)
        seen |= {r.split(":")[0] for r in reasons.values()}
    assert seen == {
        "duplicate", "out of sequence", "3-D measurement for a 2-D track"}
    assert sorted(one.store.where) == sorted(many.store.where)
    for track_id, (a, row) in one.store.where.items():
        b, row_b = many.store.where[track_id]
        for name in ("x", "p", "t", "updates", "nis", "mode_x", "mode_p", "mode_prob"):
            assert getattr(a, name)[row].tobytes() == getattr(b, name)[row_b].tobytes(), name
    assert one.state("x3")["updates"] == 5  # repeated in scan 2: updated twice


@pytest.mark.slow
def test_service_takes_a_scan_as_its_single_messages(service_factory):
    """Through the real service (lockstep): the same tracks/ bodies to the bit, the same
    counts by reason, whether the rows come one message each or as scans (bad rows, a row
    far from the picture's time, repeats, duplicates, out-of-sequence rows)."""
    rng = random.Random(9)
    msgs = scans(rng)
    bad = msgs[3]
    rows = unpack(pack(bad))
    r = list(np.frombuffer(rows["r"], "<f8"))
    r[7] = math.nan  # a bad row
    t = list(np.frombuffer(rows["t"], "<f8"))
    t[8] = 1e6  # far from the picture's time
    bad["r"], bad["t"] = f64_bin(r), f64_bin(t)
    out = {}
    for ns in ("single", "batched"):
        svc, s = service_factory("--clock", "lockstep", ns=ns)
        total = 0
        s.put(f"{ns}/meas/s/flat", pack({"t": 0.0, "pos": [1.0, 2.0], "sigma": 3.0}))
        total += 1
        for msg in msgs:
            if ns == "batched":
                s.put(f"{ns}/scan/s", pack(msg))
            else:
                cols = {k: np.frombuffer(v, "<f8").tolist() for k, v in msg.items()
                        if isinstance(v, bytes)}
                for i, target in enumerate(msg["ids"]):
                    body = {k: c[i] for k, c in cols.items()}
                    body.update({k: v for k, v in msg.items() if k not in cols and k != "ids"})
                    s.put(f"{ns}/meas/s/{target}", pack(body))
            total += len(msg["ids"])
        end = time.monotonic() + 60
        while time.monotonic() < end:
            st = unpack(next(iter(s.get(f"{ns}/status", timeout=10))).ok.payload.to_bytes())
            if st["meas_accepted"] + st["meas_rejected"] >= total:
                break
            time.sleep(0.05)
        bodies = {}
        for reply in s.get(f"{ns}/tracks/**", timeout=10):
            body = unpack(reply.ok.payload.to_bytes())
            bodies[body["id"]] = body
        out[ns] = (st, bodies)
        svc.stop()
    (st1, b1), (st2, b2) = out["single"], out["batched"]
    assert st1["meas_accepted"] + st1["meas_rejected"] == total
    for k in ("meas_accepted", "meas_rejected", "rejected_by_reason", "tracks"):
        assert st1[k] == st2[k], k
    assert set(st1["rejected_by_reason"]) >= {"time_far", "duplicate", "out_of_sequence"}
    assert b1.keys() == b2.keys() and len(b1) == 31
    for k, a in b1.items():
        assert a == b2[k], k  # every number to the bit (msgpack floats are float64)


def test_an_update_in_parts_gives_the_same_tracks(monkeypatch):
    """A realtime service publishes a due frame between parts of a scan's update
    (`pause`): the tracks are those of the update in one part."""
    import zenoh_track.tracking.tracker as tracker_module

    rng = random.Random(5)
    msgs = scans(rng)
    whole, parts = Tracker.from_config(), Tracker.from_config()
    pauses = []
    monkeypatch.setattr(tracker_module, "PART", 7)
    monkeypatch.setattr(defaults, "KERNEL_THREADS", 1)  # a part of 7 rows per thread
    for msg in msgs:
        cols = parse_scan_columns("s", pack(msg), NOISE)
        a = whole.step(Labelled(["s"] * len(cols.ids), cols.ids, MeasurementBatch.of_scan(cols)))
        b = parts.step(Labelled(["s"] * len(cols.ids), cols.ids, MeasurementBatch.of_scan(cols)),
                          pause=lambda so_far: pauses.append(len(so_far.states)))
        assert a.rejected == b.rejected and a.accepted == b.accepted
    assert len(pauses) >= 3 * 4  # 30 rows in parts of 7: 4 pauses per scan after the first
    for track_id, (arr, row) in whole.store.where.items():
        arr_b, row_b = parts.store.where[track_id]
        for name in ("x", "p", "mode_p", "mode_prob"):
            assert getattr(arr, name)[row].tobytes() == getattr(arr_b, name)[row_b].tobytes()
