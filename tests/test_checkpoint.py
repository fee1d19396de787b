"""tracking/checkpoint: the track table saved and restored (every column, every filter),
and the refusals of a corrupt or incompatible checkpoint (nothing changed)."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from reference.record import track, track_scan

from zenoh_track.estimation.catalog import FilterSpec
from zenoh_track.tracking import checkpoint
from zenoh_track.tracking.checkpoint import CheckpointError
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import DEFAULT_NS, Measurement, pack, parse_plots

NOISE = (10.0, 0.01, 0.01, 1.0)


def polar(target: str, t: float, r: float, az: float, el: float | None = None) -> Measurement:
    vals = (r, az) if el is None else (r, az, el)
    sig = (10.0, 0.01) if el is None else (10.0, 0.01, 0.01)
    return Measurement("radar", target, t, len(vals), True, vals, sig, (0.0, 0.0, 0.0), None)


def busy_tracker(name: str = "imm") -> Tracker:
    """Labelled 2-D and 3-D tracks and tracks of unlabelled scans, some deleted (free rows)."""
    tr = Tracker.from_config(TrackerConfig(filter=FilterSpec(name)))
    for k in range(4):
        t = float(k)
        track(tr, [polar(f"a{i}", t, 5000 + 100 * i + 50 * k, 0.1 * i) for i in range(6)]
                 + [polar(f"b{i}", t, 8000 + 30 * k, 0.2 * i, 0.05) for i in range(3)])
        scan = {"t": t, "dets": [{"r": 3000 + 40 * k + 500 * j, "az": 1.0 + 0.3 * j}
                                 for j in range(3)]}
        track_scan(tr, parse_plots("r2", pack(scan), NOISE))
    tr.remove(["a1", "a4"])
    return tr


def table(tr: Tracker) -> dict:
    """Every live track's saved columns (what the display makes again from them is
    not saved), by id (order of rows ignored)."""
    out = {}
    for dim, lay in tr.store.layouts.items():
        rows, ids = lay.live()
        for r, i in zip(rows.tolist(), ids, strict=True):
            out[i] = (dim, {k: np.array(getattr(lay, k)[r]) for k in lay.saved})
    return out


@pytest.mark.parametrize("name", ["imm", "cv", "ca", "vdf"])
def test_roundtrip_keeps_every_column_and_the_picture(name):
    tr = busy_tracker(name)
    data = checkpoint.dump(tr, extra={"clock": {"kind": "realtime", "offset": -3.5}})
    back = Tracker.from_config(TrackerConfig(filter=FilterSpec(name)))
    meta = checkpoint.load(back, data)
    assert meta["extra"] == {"clock": {"kind": "realtime", "offset": -3.5}}
    before, after = table(tr), table(back)
    assert set(before) == set(after) and len(after) == 6 - 2 + 3 + 3
    for i, (dim, cols) in before.items():
        assert after[i][0] == dim
        for k, v in cols.items():
            np.testing.assert_array_equal(after[i][1][k], v, err_msg=f"{i} {k}")
    assert back.memory() == tr.memory()
    # the picture drawn after the restore is the one the first tracker draws
    s1, s2 = tr.snapshot(10.0), back.snapshot(10.0)
    order = [s2.ids.index(i) for i in s1.ids]
    np.testing.assert_allclose(s2.pos[order], s1.pos, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s2.sigma[order], s1.sigma, rtol=1e-12)
    assert [s2.status[k] for k in order] == s1.status
    # the gap is predicted honestly: older instants show smaller sigma than later ones
    late = back.snapshot(40.0)
    assert (late.sigma[order] > s1.sigma * 1.5).all()
    # labelled tracks coast by age; tracks of scans keep their M-of-N status until the
    # next scan counts its miss (as after any pause of their sensor)
    assert all(st == "coasting" for i, st in zip(late.ids, late.status, strict=True)
               if not i.startswith("r2-"))
    # tracking carries on: the next measurement updates the restored track
    out, _ = track(back, [polar("a0", 4.0, 5200, 0.0)])
    assert out[0].reason is None and back.state("a0")["updates"] == 5


def test_unlabelled_ids_continue_after_restore():
    tr = busy_tracker("cv")
    back = Tracker.from_config(TrackerConfig(filter=FilterSpec("cv")))
    checkpoint.load(back, checkpoint.dump(tr))
    far = {"t": 4.0, "dets": [{"r": 90000.0, "az": -2.0}]}
    track_scan(back, parse_plots("r2", pack(far), NOISE))
    new = set(back.store.where) - set(tr.store.where)
    assert new == {f"r2-{tr.memory()['numbers']['r2'] + 1}"}


def rewrite(data: bytes, edit) -> bytes:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        files = {k: z[k] for k in z.files}
    edit(files)
    buf = io.BytesIO()
    np.savez(buf, **files)
    return buf.getvalue()


def set_meta(**kw):
    def edit(files):
        meta = json.loads(bytes(files["meta"]).decode())
        meta.update(kw)
        files["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    return edit


def nan_x(files):
    files["2/x"] = files["2/x"].copy()
    files["2/x"][0, 0] = np.nan


BAD = {
    "truncated": lambda d: d[: len(d) // 2],
    "not an archive": lambda d: b"hello" * 100,
    "empty": lambda d: b"",
    "version": lambda d: rewrite(d, set_meta(version=99)),
    "format": lambda d: rewrite(d, set_meta(format="other")),
    "non-finite state": lambda d: rewrite(d, nan_x),
    "missing column": lambda d: rewrite(d, lambda f: f.pop("3/p")),
    "bad id": lambda d: rewrite(d, lambda f: f.update({"2/ids": np.array(
        ["x/y"] + f["2/ids"].tolist()[1:])})),
    "wrong rows": lambda d: rewrite(d, lambda f: f.update({"2/t": f["2/t"][:-1]})),
    "no header": lambda d: rewrite(d, lambda f: f.pop("meta")),
    "pickled object": lambda d: rewrite(d, lambda f: f.update(
        {"2/t": np.array([object()] * len(f["2/t"]), dtype=object)})),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_corrupt_checkpoint_is_refused_and_changes_nothing(case):
    data = checkpoint.dump(busy_tracker("cv"))
    try:
        bad = BAD[case](data)
    except ValueError:  # np.savez refuses to write some of them: fine, nothing to read
        pytest.skip("the archive cannot be written")
    fresh = Tracker.from_config(TrackerConfig(filter=FilterSpec("cv")))
    with pytest.raises(CheckpointError) as err:
        checkpoint.load(fresh, bad)
    assert str(err.value) and "\n" not in str(err.value)
    assert len(fresh) == 0
    assert not fresh.memory()["numbers"]
    assert all(not len(lay.live()[0]) for lay in fresh.store.layouts.values())


def test_checkpoint_of_another_filter_is_refused():
    data = checkpoint.dump(busy_tracker("imm"))
    with pytest.raises(CheckpointError, match="filter is 'imm'"):
        checkpoint.load(Tracker.from_config(TrackerConfig(filter=FilterSpec("cv"))), data)
    with pytest.raises(CheckpointError, match="already holds"):
        checkpoint.load(busy_tracker("imm"), data)


def test_empty_tracker_roundtrip():
    data = checkpoint.dump(Tracker.from_config(), extra={"ns": DEFAULT_NS})
    back = Tracker.from_config()
    assert checkpoint.load(back, data)["extra"] == {"ns": DEFAULT_NS} and len(back) == 0
