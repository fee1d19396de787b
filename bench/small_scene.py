"""A small unlabelled scene: what the service's worker spends on each scan, beside Stone
Soup's GNN on the same scans, and (with `--against REV`) beside the service as it was at
another revision, measured in the same run.

    python bench/small_scene.py                      # ours and Stone Soup's GNN
    python bench/small_scene.py --against 812c5d6    # and the tracker of that revision

The scene: 24 aircraft of the manoeuvre classes (`clients/feeds/manoeuvres.py`: straight,
standard-rate turns, 4 g and 7 g turns, climbs) seen by two 3-D radars 29 km apart, each
turning once a second (the second half a second after the first), Pd 0.9, 30 m and
1.5 mrad of noise, Poisson clutter of mean 3 a scan over the scene's box: about 25
detections a scan, 400 scans. Every tracker gets the very same scans, recorded first.

Ours is the worker's work for one `plots/<sensor>` message: the payload checked
(`parse_plots`), the tracker's step with the default configuration (association,
updates, initiation, deletion, every updated track's state) and the `states` bodies
encoded; CPU time of the process (its kernels' threads included) over the 400 scans
after a first pass that loads the compiled kernels, median of `--repeat` runs, the
trackers taking turns. The other revision runs the same code in a child process with
that revision's `service/` as the `zenoh_track` package (`git archive`). Stone Soup
(`pip install -e '.[bench]'`): its `MultiTargetTracker` with `GNNWith2DAssignment`, a
nearly-constant-velocity Kalman filter (q = 5 m/s^2) on the detections converted to
Cartesian with their own covariance (each detection its own `LinearGaussian`),
`MultiMeasurementInitiator` (3 points) and `UpdateTimeStepsDeleter(4)`, timed the same
way.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

RADARS = {"radar1": (0.0, 0.0, 0.0), "radar2": (25_000.0, 15_000.0, 0.0)}
SR, SA = 30.0, 1.5e-3  # m, rad
PD, CLUTTER, AIRCRAFT, SECONDS = 0.9, 3.0, 24, 200.0


def scene(seed: int) -> list[dict[str, Any]]:
    """The scans, in time order: {sensor, t, payload (the plots/ message), z (K, 3)
    converted points, r (K, 3, 3) their covariances}."""
    from zenoh_track.clients.feeds import manoeuvres
    from zenoh_track.wire import pack

    rng = np.random.default_rng(seed)
    flights = manoeuvres.flights(seed, per_class=5)[:AIRCRAFT]
    pts = np.array([f.state(t)[0] for f in flights for t in np.linspace(0, SECONDS, 41)])
    lo, hi = pts.min(0) - 2000.0, pts.max(0) + 2000.0
    lo[2] = max(lo[2], 0.0)
    out = []
    for t in np.arange(0.0, SECONDS, 0.5).tolist():
        sensor = "radar1" if round(2 * t) % 2 == 0 else "radar2"
        origin = np.array(RADARS[sensor])
        pos = np.array([f.state(t)[0] for f in flights])
        seen = pos[rng.random(len(pos)) < PD]
        false = rng.uniform(lo, hi, (rng.poisson(CLUTTER), 3))
        rel = np.vstack([seen, false]) - origin
        r = np.linalg.norm(rel, axis=1) + rng.normal(0, SR, len(rel))
        az = np.arctan2(rel[:, 0], rel[:, 1]) + rng.normal(0, SA, len(rel))
        el = np.arcsin(rel[:, 2] / np.linalg.norm(rel, axis=1)) + rng.normal(0, SA, len(rel))
        order = rng.permutation(len(r))
        r, az, el = r[order], az[order], el[order]
        payload = pack({"t": t, "sensor_pos": list(RADARS[sensor]), "sr": SR, "saz": SA,
                        "sel": SA, "r": r.tobytes(), "az": az.tobytes(), "el": el.tobytes()})
        z, cov = converted(r, az, el, origin)
        out.append({"sensor": sensor, "t": t, "payload": payload, "z": z, "r": cov})
    return out


def converted(r: np.ndarray, az: np.ndarray, el: np.ndarray, origin: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Polar detections (azimuth from North, clockwise) as Cartesian points and their
    first-order covariances J diag(sr^2, sa^2, sa^2) J' (Stone Soup's input)."""
    ce, se, ca, sa = np.cos(el), np.sin(el), np.cos(az), np.sin(az)
    z = origin + np.column_stack([r * ce * sa, r * ce * ca, r * se])
    jac = np.zeros((len(r), 3, 3))  # d(x, y, z) / d(r, az, el)
    jac[:, :, 0] = np.column_stack([ce * sa, ce * ca, se])
    jac[:, :, 1] = np.column_stack([r * ce * ca, -r * ce * sa, np.zeros(len(r))])
    jac[:, :, 2] = np.column_stack([-r * se * sa, -r * se * ca, r * ce])
    return z, jac @ np.diag([SR**2, SA**2, SA**2]) @ jac.transpose(0, 2, 1)


def ours(payloads: list[tuple[str, bytes]], repeat: int) -> list[float]:
    """CPU ms per scan of the worker's work, `repeat` times (a fresh tracker each)."""
    from zenoh_track import defaults
    from zenoh_track.adapter.encode import pack_states
    from zenoh_track.estimation import jit
    from zenoh_track.tracking.batches import Unlabelled
    from zenoh_track.tracking.tracker import Tracker
    from zenoh_track.wire import parse_plots

    try:
        from zenoh_track.tracking.compiled import KERNELS
    except ImportError:  # another revision's tracker (--against)
        from zenoh_track.estimation import imm_jit
        from zenoh_track.tracking import frame
        KERNELS = (imm_jit, frame)
    jit.load(KERNELS)

    def run() -> float:
        tracker = Tracker.from_config()
        t0 = time.process_time()
        for sensor, payload in payloads:
            scan = parse_plots(sensor, payload, defaults.NOISE)
            outcome = tracker.step(Unlabelled.of(scan.sensor, scan.t, scan.detections),
                                   want=lambda ids: None)
            for block in outcome.states:
                pack_states(block)
        return (time.process_time() - t0) / len(payloads) * 1e3

    run()  # the kernels' first calls
    return [run() for _ in range(repeat)]


def stone_soup(scans: list[dict[str, Any]], repeat: int) -> list[float] | None:
    """CPU ms per scan of Stone Soup's GNN on the same scans (None: not installed)."""
    try:
        from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
        from stonesoup.deleter.time import UpdateTimeStepsDeleter
        from stonesoup.hypothesiser.distance import DistanceHypothesiser
        from stonesoup.initiator.simple import MultiMeasurementInitiator
        from stonesoup.measures import Mahalanobis
        from stonesoup.models.measurement.linear import LinearGaussian
        from stonesoup.models.transition.linear import (
            CombinedLinearGaussianTransitionModel,
            ConstantVelocity,
        )
        from stonesoup.predictor.kalman import KalmanPredictor
        from stonesoup.tracker.simple import MultiTargetTracker
        from stonesoup.types.array import CovarianceMatrix, StateVector
        from stonesoup.types.detection import Detection
        from stonesoup.types.state import GaussianState
        from stonesoup.updater.kalman import KalmanUpdater
    except ImportError:
        return None
    from scipy.stats import chi2

    epoch = datetime.datetime(2026, 1, 1)
    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(25.0)] * 3)
    base = LinearGaussian(ndim_state=6, mapping=(0, 2, 4), noise_covar=np.eye(3) * SR**2)
    predictor, updater = KalmanPredictor(transition), KalmanUpdater(base)
    times = []
    for _ in range(repeat):
        detections = []
        for s in scans:
            when = epoch + datetime.timedelta(seconds=s["t"])
            detections.append((when, {Detection(StateVector(z), timestamp=when,
                                                measurement_model=LinearGaussian(
                                                    ndim_state=6, mapping=(0, 2, 4),
                                                    noise_covar=CovarianceMatrix(r)))
                                      for z, r in zip(s["z"].tolist(), s["r"], strict=True)}))
        distance = DistanceHypothesiser(predictor, updater, Mahalanobis(),
                                        missed_distance=math.sqrt(chi2.ppf(0.999, 3)))
        v0 = 100.0
        initiator = MultiMeasurementInitiator(
            prior_state=GaussianState(StateVector([0.0] * 6), CovarianceMatrix(
                np.diag([0.0, v0**2, 0.0, v0**2, 0.0, v0**2]))),
            deleter=UpdateTimeStepsDeleter(2), data_associator=GNNWith2DAssignment(distance),
            updater=updater, measurement_model=base, min_points=3)
        tracker = MultiTargetTracker(initiator=initiator, deleter=UpdateTimeStepsDeleter(4),
                                     detector=detections,
                                     data_associator=GNNWith2DAssignment(distance),
                                     updater=updater)
        it = iter(tracker)
        t0 = time.process_time()
        for _ in scans:
            next(it)
        times.append((time.process_time() - t0) / len(scans) * 1e3)
    return times


def against(rev: str, payloads: list[tuple[str, bytes]], repeat: int) -> list[float]:
    """`ours` with revision `rev`'s service, in a child process."""
    with tempfile.TemporaryDirectory() as tmp:
        tree = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "service"],
                              capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=tree, check=True)
        os.rename(f"{tmp}/service", f"{tmp}/zenoh_track")
        with open(f"{tmp}/scans.msgpack", "wb") as f:
            f.write(msgpack.packb([list(p) for p in payloads]))
        env = {**os.environ, "PYTHONPATH": tmp}
        out = subprocess.run([sys.executable, __file__, "--child", f"{tmp}/scans.msgpack",
                              "--repeat", str(repeat)], env=env, capture_output=True,
                             text=True, check=True, timeout=1800)
        return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--against", metavar="REV", nargs="*", default=[],
                    help="also the tracker of these git revisions")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-stone-soup", action="store_true",
                    help="leave Stone Soup out (its runs take most of the time)")
    ap.add_argument("--child", metavar="FILE", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        with open(args.child, "rb") as f:
            print(json.dumps(ours([tuple(p) for p in msgpack.unpackb(f.read())], args.repeat)))
        return
    scans = scene(args.seed)
    payloads = [(s["sensor"], s["payload"]) for s in scans]
    dets = np.mean([len(s["z"]) for s in scans])
    print(f"# {time.strftime('%Y-%m-%dT%H:%M:%S')}; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"small scene: {AIRCRAFT} aircraft, 2 radars, {len(scans)} scans, {dets:.1f} "
          f"detections a scan; CPU ms per scan, median of {args.repeat} runs")
    # the trackers in turn, one run each at a time, so that the machine's moments fall
    # on all of them alike
    mine: list[float] = []
    theirs: dict[str, list[float]] = {rev: [] for rev in args.against}
    for _ in range(args.repeat):
        mine += ours(payloads, 1)
        for rev in args.against:
            theirs[rev] += against(rev, payloads, 1)
    rows = [("ours", mine)] + [(f"ours at {rev}", t) for rev, t in theirs.items()]
    peer = None if args.no_stone_soup else stone_soup(scans, args.repeat)
    if peer is not None:
        rows.append(("Stone Soup GNN", peer))
    first = float(np.median(rows[0][1]))
    print(f"{'tracker':<24} {'ms a scan':>10} {'runs':>24} {'x ours':>8}")
    for name, times in rows:
        med = float(np.median(times))
        print(f"{name:<24} {med:>10.3f} {' '.join(f'{x:.3f}' for x in times):>24} "
              f"{med / first:>8.2f}")


if __name__ == "__main__":
    main()
