"""Filter-core benchmark: our batched CMKF step against FilterPy and Stone Soup.

    python bench/bench_filter.py [--sizes 100 1000 10000 100000] [--reps R] [--subset M]

One target-step is one prediction over T = 1 s and one converted-measurement update of
one target: 3-D nearly-constant-velocity state [x y z vx vy vz], continuous white
acceleration noise of density q^2 T, q = 1 m/s^2 per axis, polar radar measurements (range,
azimuth, elevation; sr = 20 m, saz = sel = 0.2 deg, the `swarm` scenario's sensor)
converted the way the track table does it (unbiased conversion, covariance averaged
over the predicted position: `convert.cmkf_soa`).

- ours: the filter core `filters.cmkf_step` (prediction, conversion, CMKF update) on the
  stacked arrays of all N targets and the columns of their measurements
  (`measurements.MeasurementBatch`), timed as one vectorised step; building those columns
  from the validated `Measurement` records is timed on its own ("decode"), and the parts
  through their own entry points (`models.predict`, `ucm.cmkf_arrays` on the
  columns, `kalman.update`). Also the whole table step `Tracker.step` (which adds
  decoding, the bookkeeping and the per-track `tracks/` message dicts) on the following
  scans.
- FilterPy: one `filterpy.kalman.KalmanFilter` per target, F and Q (Q from FilterPy's own
  `Q_continuous_white_noise`) equal to ours, fed our converted z and R; a loop of
  `predict(); update(z, R)`.
- Stone Soup: `KalmanPredictor` with a `CombinedLinearGaussianTransitionModel` of three
  `ConstantVelocity` models and `KalmanUpdater` (Joseph form, symmetrised, as ours) with
  one `LinearGaussian` measurement model per detection carrying our converted R. Stone
  Soup's `ConstantVelocity` is the continuous white-noise model (Q = q [[T^3/3, T^2/2],
  [T^2/2, T]]), ours too, with the density q^2 |T| (`peer_models`).

The peers get the converted measurements precomputed (their timings exclude the
conversion); the table reports their ratio both to our whole step and to our
predict + update. Peers loop in Python over targets, so above `--subset` targets they
are timed on the first `--subset` only and reported per target-step. All three are
checked (asserted) to give the same posterior states on a few targets. Timings: best
of R repetitions after a warm-up, `time.perf_counter`.
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import resource
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run from a checkout

from zenoh_track.clients.evaluation.progress import bar  # noqa: E402
from zenoh_track.estimation import filters, kalman, models  # noqa: E402
from zenoh_track.estimation.catalog import FilterSpec  # noqa: E402
from zenoh_track.estimation.measurements import MeasurementBatch  # noqa: E402
from zenoh_track.estimation.ucm import cmkf_arrays  # noqa: E402
from zenoh_track.tracking.batches import Labelled  # noqa: E402
from zenoh_track.tracking.tracker import Tracker, TrackerConfig  # noqa: E402
from zenoh_track.wire import Measurement  # noqa: E402

try:
    from filterpy.common import Q_continuous_white_noise
    from filterpy.kalman import KalmanFilter
except ImportError:  # optional peer (pip install '.[bench]')
    KalmanFilter = None

try:
    from peer_models import OurConstantVelocity
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import KalmanUpdater
except ImportError:  # optional peer (pip install '.[bench]')
    KalmanPredictor = None

DIM, ORDER, N_STATE = 3, 2, 6
T = 1.0  # s, scan period
Q = 1.0  # m/s^2, white acceleration std per axis
SR, SA = 20.0, math.radians(0.2)  # radar noise: range m, azimuth and elevation rad
PRIOR_SCANS = 3  # scans through Tracker.step before the timed step (initiate + 2)
CHECK = 5  # targets whose posteriors are compared across the three filters
RTOL = 1e-6
# ours [x y z vx vy vz] <-> Stone Soup [x vx y vy z vz]
SS_ORDER = np.array([0, 3, 1, 4, 2, 5])


# ---------------------------------------------------------------- data
def scans(n: int, count: int, seed: int = 0) -> list[list[Measurement]]:
    """`count` scans of n straight-flying targets seen by a 3-D radar at the origin,
    like `track-feed swarm`: one polar Measurement per target per scan, T apart."""
    rng = np.random.default_rng(seed)
    rho = rng.uniform(5_000, 80_000, n)
    bearing = rng.uniform(0, 2 * np.pi, n)
    p = np.stack([rho * np.sin(bearing), rho * np.cos(bearing), rng.uniform(500, 10_000, n)], 1)
    speed, heading = rng.uniform(50, 300, n), rng.uniform(0, 2 * np.pi, n)
    v = np.stack([speed * np.sin(heading), speed * np.cos(heading), np.zeros(n)], 1)
    names = [f"swarm-{i:06d}" for i in range(n)]
    out = []
    for k in range(count):
        q = p + v * k * T
        r = np.linalg.norm(q, axis=1) + SR * rng.standard_normal(n)
        az = np.arctan2(q[:, 0], q[:, 1]) + SA * rng.standard_normal(n)
        el = np.arctan2(q[:, 2], np.hypot(q[:, 0], q[:, 1])) + SA * rng.standard_normal(n)
        t, sig, origin = k * T, (SR, SA, SA), (0.0, 0.0, 0.0)
        out.append([Measurement("radar1", nm, t, 3, True, (ri, ai, ei), sig, origin, k)
                    for nm, ri, ai, ei in zip(names, r.tolist(), az.tolist(), el.tolist(),
                                              strict=True)])
    return out


# ---------------------------------------------------------------- timing
def best_of(fn: Callable[[], object], reps: int, setup: Callable[[], object] | None = None
            ) -> float:
    """Best wall time (s) of `reps` calls after one warm-up call; `setup` runs untimed
    before each call."""
    best = math.inf
    for i in range(reps + 1):
        if setup is not None:
            setup()
        t0 = time.perf_counter()
        fn()
        dt = time.perf_counter() - t0
        if i:
            best = min(best, dt)
    return best


def reference() -> float:
    """Best time (s) of one np.multiply of two 10,000-float arrays into a third: this
    machine's element-wise NumPy speed at the moment (on a shared virtual machine it
    varies by up to 2x from one minute to the next)."""
    a, b, c = np.ones(10_000), np.ones(10_000), np.empty(10_000)
    return best_of(lambda: np.multiply(a, b, out=c), 300)


def us(seconds: float, n: int) -> float:
    return seconds / n * 1e6


# ---------------------------------------------------------------- ours
def ours_step(x, p, batch):
    xn, pn, _, ok = filters.cmkf_step(x, p, np.full(len(x), T), ORDER, DIM, Q, batch)
    return xn, pn, ok


def ours_parts(x, p, batch):
    """The same step through the parts' own entry points (row-major arrays between them)."""
    xp, pp = models.predict(x, p, np.full(len(x), T), ORDER, DIM, Q)
    z, r = cmkf_arrays(batch, xp[:, :DIM], pp[:, :DIM, :DIM])
    xn, pn, _, ok = kalman.update(xp, pp, z, r)
    return xn, pn, ok


def bench_ours(n: int, reps: int, seed: int) -> dict:
    data = scans(n, PRIOR_SCANS + 1 + reps, seed)
    table = Tracker.from_config(TrackerConfig(filter=FilterSpec({2: "cv", 3: "ca"}[ORDER], Q)))
    for scan in data[:PRIOR_SCANS]:
        assert not table.step(Labelled.of(scan)).rejected
    x0, p0 = prior(table, data[PRIOR_SCANS])
    meas = data[PRIOR_SCANS]
    dt = np.full(n, T)

    res: dict = {"n": n}
    res["decode"] = best_of(lambda: MeasurementBatch.of(meas, DIM), reps)
    batch = MeasurementBatch.of(meas, DIM)
    res["predict"] = best_of(lambda: models.predict(x0, p0, dt, ORDER, DIM, Q), reps)
    xp, pp = models.predict(x0, p0, dt, ORDER, DIM, Q)
    pred, pred_cov = xp[:, :DIM], pp[:, :DIM, :DIM]
    res["convert"] = best_of(lambda: cmkf_arrays(batch, pred, pred_cov), reps)
    z, r = cmkf_arrays(batch, pred, pred_cov)
    res["update"] = best_of(lambda: kalman.update(xp, pp, z, r), reps)
    res["ref"] = reference()
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    res["step"] = best_of(lambda: ours_step(x0, p0, batch), reps)
    res["faults"] = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults) / (reps + 1)
    xn, pn, ok = ours_step(x0, p0, batch)
    assert ok.all()
    xs, ps, _ = ours_parts(x0, p0, batch)
    same_posterior("predict + cmkf_arrays + update", xs[:CHECK], ps[:CHECK],
                   xn[:CHECK], pn[:CHECK])

    # the whole table step: the table moves on, so the best of R *successive* scans,
    # after the timed step's own scan as warm-up (where it must give the same posterior)
    first, *later = data[PRIOR_SCANS:]
    table.step(Labelled.of(first))
    xa, pa = prior(table, first[:CHECK])
    same_posterior("Tracker.step", xa, pa, xn[:CHECK], pn[:CHECK])
    res["apply"] = min(_timed_apply(table, scan) for scan in later)
    res.update(x0=x0, p0=p0, z=z, r=r, xn=xn, pn=pn)
    return res


def prior(table: Tracker, meas: list[Measurement]) -> tuple[np.ndarray, np.ndarray]:
    """States and covariances of the measured targets, from the table's public
    `state` (the tracks/ message body)."""
    states = [table.state(m.target) for m in meas]
    return (np.array([s["x"] for s in states]),
            np.array([s["P"] for s in states]).reshape(len(meas), N_STATE, N_STATE))


def _timed_apply(table: Tracker, scan: list[Measurement]) -> float:
    t0 = time.perf_counter()
    out = table.step(Labelled.of(scan))
    dt = time.perf_counter() - t0
    assert not out.rejected
    return dt


# ---------------------------------------------------------------- FilterPy
def bench_filterpy(o: dict, m: int, reps: int) -> tuple[float, np.ndarray, np.ndarray]:
    f = models.transition(np.array([T]), ORDER, DIM)[0]
    q = Q_continuous_white_noise(2, dt=T, spectral_density=Q**2 * T, block_size=3,
                                 order_by_dim=False)
    assert np.allclose(q, models.process_noise(np.array([T]), ORDER, DIM, Q)[0], atol=1e-15)
    h = np.hstack([np.eye(DIM), np.zeros((DIM, DIM))])
    filters = []
    for _ in range(m):
        kf = KalmanFilter(dim_x=N_STATE, dim_z=DIM)
        kf.F, kf.Q, kf.H = f.copy(), q.copy(), h.copy()
        filters.append(kf)
    zs, rs = list(o["z"][:m]), list(o["r"][:m])
    x0, p0 = o["x0"], o["p0"]

    def reset() -> None:
        for i, kf in enumerate(filters):
            kf.x, kf.P = x0[i].copy(), p0[i].copy()

    def run() -> None:
        for kf, z, r in zip(filters, zs, rs, strict=True):
            kf.predict()
            kf.update(z, R=r)

    best = best_of(run, reps, reset)
    return best, np.array([kf.x for kf in filters[:CHECK]]), np.array(
        [kf.P for kf in filters[:CHECK]])


# ---------------------------------------------------------------- Stone Soup
def bench_stonesoup(o: dict, m: int, reps: int) -> tuple[float, np.ndarray, np.ndarray]:
    transition = CombinedLinearGaussianTransitionModel(
        [OurConstantVelocity(Q**2) for _ in range(DIM)])
    predictor = KalmanPredictor(transition)
    updater = KalmanUpdater(measurement_model=None, use_joseph_cov=True,
                            force_symmetric_covariance=True)
    t0 = datetime.datetime(2025, 1, 1)
    t1 = t0 + datetime.timedelta(seconds=T)
    perm = SS_ORDER
    x0, p0 = o["x0"][:m][:, perm], o["p0"][:m][:, perm][:, :, perm]
    dets = [Detection(StateVector(z), timestamp=t1, measurement_model=LinearGaussian(
        ndim_state=N_STATE, mapping=(0, 2, 4), noise_covar=CovarianceMatrix(r)))
        for z, r in zip(o["z"][:m], o["r"][:m], strict=True)]
    priors: list = []
    posts: list = []

    def fresh() -> None:  # new prior objects: the predictor's LRU cache must not hit
        priors[:] = [GaussianState(StateVector(x), CovarianceMatrix(p), timestamp=t0)
                     for x, p in zip(x0, p0, strict=True)]
        posts.clear()

    def run() -> None:
        for prior, det in zip(priors, dets, strict=True):
            pred = predictor.predict(prior, timestamp=t1)
            posts.append(updater.update(SingleHypothesis(pred, det)))

    best = best_of(run, reps, fresh)
    inv = np.argsort(perm)
    xs = np.array([np.asarray(s.state_vector, dtype=float).ravel()[inv] for s in posts[:CHECK]])
    ps = np.array([np.asarray(s.covar, dtype=float)[inv][:, inv] for s in posts[:CHECK]])
    return best, xs, ps


# ---------------------------------------------------------------- checks and report
def same_posterior(name: str, x: np.ndarray, p: np.ndarray, xr: np.ndarray, pr: np.ndarray
                   ) -> None:
    """Position and velocity blocks and P equal to RTOL (relative norm per target)."""
    for i in range(len(x)):
        for blk in (slice(0, DIM), slice(DIM, N_STATE)):
            err = np.linalg.norm(x[i, blk] - xr[i, blk]) / np.linalg.norm(xr[i, blk])
            assert err <= RTOL, f"{name}: target {i} state differs from ours by {err:.2e}"
        err = np.linalg.norm(p[i] - pr[i]) / np.linalg.norm(pr[i])
        assert err <= RTOL, f"{name}: target {i} covariance differs from ours by {err:.2e}"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10000, 100000])
    ap.add_argument("--reps", type=int, default=5, help="best of R timed repetitions")
    ap.add_argument("--subset", type=int, default=1000,
                    help="peers are timed on at most this many targets")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    print(f"# {platform.python_implementation()} {platform.python_version()}, "
          f"numpy {np.__version__}, {platform.machine()}, {os.cpu_count()} CPUs; "
          f"best of {args.reps} after warm-up; us = microseconds per target-step")
    print(f"# reference: np.multiply of two 10,000-float arrays into a third, "
          f"{reference() * 1e6:.1f} us (element-wise NumPy speed; also column ref)")
    peers = []
    if KalmanFilter is None:
        print("# FilterPy not installed: skipped (pip install filterpy)")
    else:
        import filterpy
        peers.append(("FilterPy", bench_filterpy))
        print(f"# FilterPy {filterpy.__version__}")
    if KalmanPredictor is None:
        print("# Stone Soup not installed: skipped (pip install stonesoup)")
    else:
        from importlib.metadata import version
        peers.append(("Stone Soup", bench_stonesoup))
        print(f"# Stone Soup {version('stonesoup')}")

    rows = []
    progress = bar(total=len(args.sizes), desc="sizes", unit=" N", leave=False)
    for n in args.sizes:
        o = bench_ours(n, args.reps, args.seed)
        m = min(n, max(args.subset, CHECK))
        peer_us = {}
        for name, fn in peers:
            best, x, p = fn(o, m, args.reps)
            same_posterior(name, x, p, o["xn"][:CHECK], o["pn"][:CHECK])
            peer_us[name] = us(best, m)
        rows.append((o, m, peer_us))
        timed = ", ".join(f"{k} timed on {m}" for k in peer_us) or "ours"
        progress.write(f"# N={n}: done ({timed})", file=sys.stdout)
        progress.update(1)
    progress.close()
    agree = ", ".join(["ours", "ours by parts", "Tracker.step", *(k for k, _ in peers)])
    print(f"# posteriors of the first {CHECK} targets agree to {RTOL:g} relative: {agree}")

    print("\nours, one vectorised step over N targets (us per target-step)")
    print(f"{'N':>8} {'decode':>8} {'step':>8} {'predict':>8} {'convert':>8} {'update':>8}"
          f" {'p+u':>8} {'apply':>8} {'faults':>8} {'ref':>6}")
    for o, _, _ in rows:
        n = o["n"]
        print(f"{n:>8} {us(o['decode'], n):>8.3f} {us(o['step'], n):>8.3f}"
              f" {us(o['predict'], n):>8.3f} {us(o['convert'], n):>8.3f}"
              f" {us(o['update'], n):>8.3f} {us(o['predict'] + o['update'], n):>8.3f}"
              f" {us(o['apply'], n):>8.3f} {o['faults']:>8.0f} {o['ref'] * 1e6:>6.1f}")
    print("  decode = the Measurement records to columns (MeasurementBatch.of), not in step;\n"
          "  step = filters.cmkf_step: predict + convert + update on arrays, in one pass;\n"
          "  predict, convert, update = the parts through their own entry points (each with\n"
          "  its own row-major input and output: they add up to more than step);\n"
          "  p+u = predict + update; apply = Tracker.step, the whole table step (decode,\n"
          "  bookkeeping, tracks/ message dicts); faults = minor page faults per step call;\n"
          "  ref = us of the reference np.multiply, timed just before step")

    if peers:
        names = [k for k, _ in peers]
        print("\npeers (us per target-step) and ratios peer / ours "
              "(/step: ours whole step; /p+u: ours predict + update, like for like)")
        head = f"{'N':>8} {'timed':>6} {'ours':>8}"
        for k in names:
            head += f" {k:>11} {'/step':>7} {'/p+u':>7}"
        print(head)
        for o, m, peer_us in rows:
            n = o["n"]
            step, core = us(o["step"], n), us(o["predict"] + o["update"], n)
            line = f"{n:>8} {m:>6} {step:>8.3f}"
            for k in names:
                line += f" {peer_us[k]:>11.2f} {peer_us[k] / step:>7.1f} {peer_us[k] / core:>7.1f}"
            print(line)


if __name__ == "__main__":
    main()
