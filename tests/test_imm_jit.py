"""The IMM's compiled update (`estimation.imm_jit`) against the IMM's own textbook code
(`IMM.update` with a conversion that is not a `CMKFConversion`, the path any other
conversion takes): same posteriors, mode probabilities, NIS and finiteness mask, for
passes of any number of rows (blocks of `imm_jit.SMALL` or `imm_jit.BLOCK`, the last padded)."""

from __future__ import annotations

import copy
import dataclasses
import subprocess
import sys

import numpy as np
import pytest
from reference.record import track

from zenoh_track import defaults
from zenoh_track.estimation import blocks, imm_jit
from zenoh_track.estimation.catalog import FilterSpec
from zenoh_track.estimation.imm import IMM, ModeSet
from zenoh_track.estimation.measurements import MeasurementBatch
from zenoh_track.estimation.ucm import CMKFConversion
from zenoh_track.tracking.tracker import Tracker
from zenoh_track.wire import Measurement


def measurements(n: int, t: float, dim: int, rng: np.random.Generator) -> list[Measurement]:
    out = []
    for i in range(n):
        r, az = 2e3 + 1e3 * i + 30 * t + rng.normal(0, 20), 0.3 * i + 0.002 * t * t
        if i % 3 == 2:  # a Cartesian one now and then
            pos = (r * np.sin(az), r * np.cos(az), 500.0)[:dim]
            out.append(Measurement("s", f"x{i}", t + 0.01 * i, dim, False, pos,
                                   (15.0,) * dim, (0.0, 0.0, 0.0), None))
        else:
            vals = (r, az, 0.05)[:dim]
            out.append(Measurement("s", f"x{i}", t + 0.01 * i, dim, True, vals,
                                   (20.0, 0.004, 0.004)[:dim], (10.0, -5.0, 0.0), None))
    return out


def close(a: np.ndarray, b: np.ndarray, rel: float) -> bool:
    """Equal to `rel` of the largest entry of each row (covariances mix metres and m/s^2)."""
    a, b = a.reshape(len(a), -1), b.reshape(len(b), -1)
    scale = np.maximum(np.abs(b).max(1, keepdims=True), 1e-300)
    return bool((np.abs(a - b) <= rel * scale).all())


# the default's modes; with turns at +-2 deg/s; with the turn at its own rate (a seventh)
@pytest.mark.parametrize("modes", ["default", "turns", "turn-rate"])
@pytest.mark.parametrize("own_r", [False, True])  # one R for the modes, or each its own
@pytest.mark.parametrize("count", [40, 1, imm_jit.SMALL + 1, imm_jit.BLOCK, imm_jit.BLOCK + 1])
@pytest.mark.parametrize("dim", [3, 2])
def test_compiled_imm_is_the_textbook_imm(dim, count, own_r, modes):
    compare(dim, count, own_r, modes, 0.0)


@pytest.mark.parametrize("own_r", [False, True])
@pytest.mark.parametrize("dim", [3, 2])
def test_compiled_imm_is_the_textbook_imm_with_time_noise(dim, own_r):
    """Measurements with a stated sigma_t (some rows without: NaN, or 0): the time
    noise's mixture (`timing.mixture_update`, T = sigma_t^2 (v v' + P_vv) at the same
    prediction) in both."""
    compare(dim, imm_jit.BLOCK + 1, own_r, "default", 0.0, time_noise=True)


@pytest.mark.parametrize("own_r", [False, True])
@pytest.mark.parametrize("dim", [3, 2])
def test_compiled_imm_is_the_textbook_imm_after_a_long_gap(dim, own_r):
    """Measurements ~10 s after the tracks' last: the widest CV mode's noise is bounded
    (`imm.cv_noise`) in both."""
    compare(dim, imm_jit.BLOCK + 1, own_r, "default", 8.5)


def compare(dim: int, count: int, own_r: bool, modes: str, gap: float,
            time_noise: bool = False) -> None:
    """The update of `count` rows by both, `gap` s later than the scan after the last."""
    rng = np.random.default_rng(5)
    built = FilterSpec("imm", imm_turn=2.0 * (modes == "turns")).build()
    if modes == "turn-rate":
        built = dataclasses.replace(built, updater=ModeSet(manoeuvre=(
            *defaults.IMM_MANOEUVRE[:2], ("turn", 5.0), *defaults.IMM_MANOEUVRE[2:])).imm(
                imm_jit.CompiledIMM))
    tracker = Tracker.from_config(filter=built)
    assert tracker.updater.mode_conversion is False  # the default shares R
    imm = dataclasses.replace(tracker.updater, mode_conversion=own_r)
    assert imm_jit.applies(imm)
    for t in range(5):  # tracks with a history: modes apart, probabilities moved
        track(tracker, measurements(40, float(t), dim, rng))
    arrays = tracker.store.layout(dim)
    bad = min(7, count - 1)
    rows = arrays.live()[0][::-1][:count]  # store rows in any order
    if count > 1:
        arrays.mode_p[rows[bad], 1, 0, 0] = np.nan  # a row whose update cannot be finite
    batch = MeasurementBatch.of(measurements(40, 5.5 + gap, dim, rng)[::-1][:count], dim)
    if time_noise:
        batch.sigma_t = rng.uniform(0.05, 0.5, len(batch))
        batch.sigma_t[::5], batch.sigma_t[::7] = np.nan, 0.0
    dt = batch.t - arrays.t[rows]
    assert (dt * imm.modes[-1][2] > imm.dv_cap).any() == (gap > 0)  # the bound bites
    ref_arrays = copy.deepcopy(arrays)
    conversion = CMKFConversion(batch)
    fast = imm.update(arrays, rows, dt, conversion)
    ref = IMM.update(imm, ref_arrays, rows, dt, conversion)  # its NumPy code
    assert (fast[3] == ref[3]).all() and fast[3].sum() == len(rows) - (count > 1)
    ok = fast[3]
    for a, b, rel in zip(fast[:3], ref[:3], (1e-10, 1e-9, 1e-9), strict=True):
        assert close(a[ok], b[ok], rel)
    for name in ("mode_x", "mode_p", "mode_prob"):
        assert close(getattr(arrays, name)[rows[ok]], getattr(ref_arrays, name)[rows[ok]],
                     1e-9), name
        assert count == 1 or np.array_equal(  # the bad row kept its prior
            getattr(arrays, name)[rows[bad]], getattr(ref_arrays, name)[rows[bad]],
            equal_nan=True)
    p = fast[1][ok]
    assert (p == p.transpose(0, 2, 1)).all()  # exactly symmetric


@pytest.mark.parametrize("modes", ["default", "turns", "turn-rate"])
@pytest.mark.parametrize("count", [1, imm_jit.SMALL + 1, imm_jit.BLOCK + 1])
@pytest.mark.parametrize("dim", [3, 2])
def test_compiled_prediction_is_the_textbook_prediction(dim, count, modes):
    """What the association gates with (`IMM.predicted`: the predicted mode probabilities
    and each mode's prediction from its mixed initial condition; `IMM.gate_moments`: the
    mixture's and its widest mode's moments), compiled and in NumPy,
    over short and long gaps (the CV modes' noise bound biting), the store untouched."""
    rng = np.random.default_rng(8)
    imm, tracker = design_of(modes)
    for t in range(5):
        track(tracker, measurements(40, float(t), dim, rng))
    arrays = tracker.store.layout(dim)
    rows = arrays.live()[0][::-1][:count]
    before = arrays.mode_x.copy(), arrays.mode_p.copy(), arrays.mode_prob.copy()
    for gap in (0.7, 12.0):
        dt = 5.0 + gap - arrays.t[rows]
        c, xs, ps = imm_jit.predicted(imm, arrays, rows, dt)
        c_ref, modes_ref = imm_jit.IMM.predicted(imm, arrays, rows, dt)
        assert close(c, c_ref, 1e-12)
        for j, (x_ref, p_ref) in enumerate(modes_ref):
            assert close(xs[:, j], x_ref, 1e-10) and close(ps[:, j], p_ref, 1e-9)
        fast, ref = imm_jit.gate_moments(imm, arrays, rows, dt), \
            imm_jit.IMM.gate_moments(imm, arrays, rows, dt)
        for a, b in zip(fast, ref, strict=True):  # mean, cross, narrow, c of the widest
            assert a.shape == b.shape and close(a, b, 1e-9)
    for now, was in zip((arrays.mode_x, arrays.mode_p, arrays.mode_prob), before, strict=True):
        assert np.array_equal(now, was)


def design_of(modes: str) -> tuple[imm_jit.CompiledIMM, Tracker]:
    """The IMM of `modes` and a tracker that runs it."""
    built = FilterSpec("imm", imm_turn=2.0 * (modes == "turns")).build()
    if modes == "turn-rate":
        built = dataclasses.replace(built, updater=ModeSet(manoeuvre=(
            *defaults.IMM_MANOEUVRE[:2], ("turn", 5.0), *defaults.IMM_MANOEUVRE[2:])).imm(
                imm_jit.CompiledIMM))
    tracker = Tracker.from_config(filter=built)
    return tracker.updater, tracker


WARMED_ONLY = """
import numpy as np
from zenoh_track.estimation import imm_kernel, jit, gate_kernel
from zenoh_track.tracking import frame_kernel
from zenoh_track.tracking.compiled import KERNELS
from zenoh_track.tracking.batches import Labelled, Unlabelled
from zenoh_track.tracking.tracker import Tracker
from zenoh_track.wire import Measurement

jit.load(KERNELS)
kernels = (imm_kernel.update_rows, imm_kernel.update_few, imm_kernel.predict_rows,
           imm_kernel.predict_few, imm_kernel.gate_moments, frame_kernel.draw,
           gate_kernel.at_points, gate_kernel.gate_pairs, gate_kernel.mixture)
warmed = [list(k.signatures) for k in kernels]
tracker, rng = Tracker.from_config(), np.random.default_rng(1)
for t in range(6):
    polar = [Measurement("r", f"p{i}", t, 3, True, (3e4 + 200.0 * t + i, 0.1 * i, 0.05),
                         (20.0, 0.002, 0.002), (0.0, 0.0, 0.0), None) for i in range(40)]
    flat = [Measurement("f", f"c{i}", t, 2, False, (1e3 * i + 150.0 * t, 5e3), (30.0,) * 2,
                        (0.0, 0.0, 0.0), None) for i in range(3)]
    tracker.step(Labelled.of(polar))
    tracker.step(Labelled.of(flat))
    tracker.step(Unlabelled.of("s", t + 0.5, [Measurement(
        "s", "", t + 0.5, 3, True, (2e4 + 200.0 * t, -0.3, 0.02), (20.0, 0.002, 0.002),
        (0.0, 0.0, 0.0), None)]))
    tracker.snapshot(t + 0.7)
print([len(w) == len(k.signatures) for w, k in zip(warmed, kernels)])
"""


def test_the_service_calls_only_the_warmed_kernels():
    """The kernels' first calls in a service take the types `warm` compiled: another type
    (a read-only array, say) would be compiled in the worker, tens of seconds on a
    machine's first start, while no frame goes out."""
    out = subprocess.run([sys.executable, "-c", WARMED_ONLY], capture_output=True, text=True,
                         check=True, timeout=300)
    assert out.stdout.split("\n")[-2] == str([True] * 9), out.stdout + out.stderr


@pytest.mark.parametrize("threads", [2, 3])
def test_a_pass_on_several_threads_is_the_same_bits(monkeypatch, threads):
    """The rows split over threads at multiples of BLOCK (`estimation.blocks`): every
    output and every store row written the same to the bit as on one thread."""
    monkeypatch.setattr(defaults, "PARALLEL_ROWS", imm_jit.BLOCK)
    rng, count = np.random.default_rng(11), 5 * imm_jit.BLOCK + 7
    tracker = Tracker.from_config()
    for t in range(3):
        track(tracker, measurements(count, float(t), 3, rng))
    arrays = tracker.store.layout(3)
    rows = arrays.live()[0][::-1]
    batch = MeasurementBatch.of(measurements(count, 3.5, 3, rng)[::-1], 3)
    dt = batch.t - arrays.t[rows]
    alone, split = copy.deepcopy(arrays), copy.deepcopy(arrays)
    one = imm_jit.step(tracker.updater, alone, rows, dt, batch, threads=1)
    many = imm_jit.step(tracker.updater, split, rows, dt, batch, threads=threads)
    assert len(blocks.parts(count, imm_jit.BLOCK, threads)) == threads
    for a, b in zip(one, many, strict=True):
        assert np.array_equal(a, b)
    for name in ("mode_x", "mode_p", "mode_prob"):
        assert np.array_equal(getattr(alone, name), getattr(split, name)), name
    assert one[3].all()


@pytest.mark.parametrize("k", [1, 39, 40, 41, 4096, 4099, 100_000])
@pytest.mark.parametrize("threads", [1, 2, 3, 8])
def test_the_parts_of_a_pass_cover_it_at_block_edges(k, threads):
    parts = blocks.parts(k, imm_jit.BLOCK, threads)
    assert parts[0][0] == 0 and parts[-1][1] == k
    assert all(hi == lo for (_, hi), (lo, _) in zip(parts, parts[1:], strict=False))
    assert all(lo % imm_jit.BLOCK == 0 for lo, _ in parts)
    assert len(parts) <= max(1, min(threads, k // defaults.PARALLEL_ROWS))
