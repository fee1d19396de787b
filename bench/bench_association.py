"""Data-association benchmark: our GNN and JPDA trackers against Stone Soup's, on the very
same unlabelled scans.

    python bench/bench_association.py [--runs R] [--scans S] [--targets N] [--clutter C]
                                      [--quick] [--scale] [--c 100]

Scenario (`zenoh_track.clients.feeds.plotgen.crossing`): N = 20 targets on straight lines (100-250
m/s)
crossing within 200 m of the origin around the middle scan, Pd 0.9, Poisson clutter of
mean 20 per scan uniform over the surveillance square (the smallest one holding every
trajectory; the true clutter density is printed), 2-D Cartesian detections with 25 m
noise per axis, 1 s scans, 100 scans. Run r uses seed r; every tracker gets the same
recorded scans.

- ours: `Tracker.from_config(TrackerConfig(filter=FilterSpec("cv", 1), associator="gnn" | "jpda",
  sensors=SensorModels(pd=0.9, clutter_density=<true density>)))`, fed scan by scan with
  `Tracker.step` (the `Measurement` records are built before the clock starts). Estimates:
  the confirmed and coasting tracks (not tentative), filtered states predicted to the scan.
- Stone Soup GNN: `MultiTargetTracker`, `GNNWith2DAssignment(DistanceHypothesiser(
  Mahalanobis, missed_distance = the 99.9 % chi-square gate, as ours))`, `KalmanPredictor`
  (two `ConstantVelocity` with the same continuous noise, q = 1 m/s^2, as ours, as
  in bench_filter.py), `KalmanUpdater(LinearGaussian(mapping (0, 2), 25^2 I))`,
  `MultiMeasurementInitiator` (min_points 3, its tentative tracks deleted after 2 scans
  without an update, prior velocity std 113 m/s as ours) and `UpdateTimeStepsDeleter(4)`
  (4 misses in a row, as ours).
- Stone Soup JPDA: `MultiTargetMixtureTracker` with `JPDAwithLBP(PDAHypothesiser(
  clutter_spatial_density = true density, prob_detect 0.9, prob_gate 0.999))`, same
  initiator and deleter; and Stone Soup's exact `JPDA` (all joint events of all tracks),
  which only finishes a small scenario: it runs on its own table (4 targets, 20 scans).

Per tracker: GOSPA (García-Fernández, Rahmathullah & Svensson, FUSION 2017; c printed,
p = 2, alpha = 2, `zenoh_track.clients.evaluation.gospa`) averaged over scans and runs with its
parts
(localisation, missed, false, in m^2 as Stone Soup's GOSPAMetric gives them), identity
switches, track breaks and false tracks (never within c of a truth) per run, mean time
to confirm a truth, confirmed tracks at the end, and the wall time per scan
(time.perf_counter around one tracker step) as mean and worst, with the ratio of Stone
Soup's GNN mean time to each. `--scale`: our GNN and JPDA on 1,000 targets + 1,000
clutter per scan (median ms per scan after 3 warm-up scans), and a scan of 10,000
detections; with `--scale-filter default`, the service's default IMM in place of CV.
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run from a checkout

from zenoh_track import defaults  # noqa: E402
from zenoh_track.clients.evaluation.gospa import Evaluation, evaluate  # noqa: E402
from zenoh_track.clients.evaluation.progress import bar  # noqa: E402
from zenoh_track.clients.feeds import plotgen  # noqa: E402
from zenoh_track.estimation.catalog import FilterSpec  # noqa: E402
from zenoh_track.tracking.batches import StepOutcome, Unlabelled  # noqa: E402
from zenoh_track.tracking.plot_association import SensorModels  # noqa: E402
from zenoh_track.tracking.tracker import Tracker, TrackerConfig  # noqa: E402
from zenoh_track.wire import Measurement  # noqa: E402

try:
    import stonesoup
    from peer_models import OurConstantVelocity
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.dataassociator.probability import JPDA, JPDAwithLBP
    from stonesoup.deleter.time import UpdateTimeStepsDeleter
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.measures import Mahalanobis
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.tracker.simple import MultiTargetMixtureTracker, MultiTargetTracker
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import KalmanUpdater
except ImportError:  # optional peer (pip install '.[bench]')
    stonesoup = None

Q = 1.0  # m/s^2: process noise of every tracker (the truths fly straight)
GATE = 0.999  # gate probability of every tracker
EPOCH = datetime.datetime(2025, 1, 1)
Estimates = tuple[float, dict, dict]  # (t, track id -> pos, truth id -> pos)


@dataclass
class Run:
    """What one tracker did on one run."""

    scans: list[Estimates] = field(default_factory=list)
    times: list[float] = field(default_factory=list)  # s per scan
    confirmed_end: int = 0


# ---------------------------------------------------------------- ours
def ours(kind: str, sc: plotgen.Scenario, scans: list[plotgen.Scan]) -> Run:
    tracker, run = our_tracker(kind, sc), Run()
    for s in scans:
        outcomes = records(s, sc.sigma)
        t0 = time.perf_counter()
        apply_scan(tracker, s, outcomes)
        run.times.append(time.perf_counter() - t0)
        run.scans.append((s.t, established(tracker, s.t), truth(s)))
    run.confirmed_end = len(run.scans[-1][1]) if run.scans else 0
    return run


def our_tracker(kind: str, sc: plotgen.Scenario, spec: FilterSpec | None = None) -> Tracker:
    """Our CV tracker (q = Q; or the filter `spec`) with the scan associator `kind` and
    the true Pd and clutter density."""
    return Tracker.from_config(TrackerConfig(filter=spec or FilterSpec("cv", Q), associator=kind,
                                 gate_probability=GATE,
                                 sensors=SensorModels(pd=sc.pd,
                                                      clutter_density=sc.clutter_density)))


def apply_scan(tracker: Tracker, s: plotgen.Scan, dets: list[Measurement]) -> StepOutcome:
    """One scan through the tracker's loop (`Tracker.step`)."""
    return tracker.step(Unlabelled.of(s.sensor, s.t, dets))


def records(s: plotgen.Scan, sigma: float) -> list[Measurement]:
    """The scan's detections as Cartesian `Measurement` records (tests/test_association)."""
    sig = (sigma, sigma)
    return [Measurement(s.sensor, "", s.t, 2, False, (x, y), sig, s.sensor_pos, None)
            for x, y in s.dets.tolist()]


def established(tracker: Tracker, t: float) -> dict[str, np.ndarray]:
    """Confirmed and coasting tracks (not tentative): filtered position predicted to t."""
    arrays = tracker.store.layouts.get(2)
    if arrays is None:
        return {}
    rows = arrays.rows()
    rows = rows[arrays.plot[rows] & arrays.confirmed[rows]]
    x = arrays.x[rows]
    pos = x[:, :2] + x[:, 2:4] * (t - arrays.t[rows])[:, None]
    return {arrays.ids[r]: pos[i] for i, r in enumerate(rows.tolist())}


def truth(s: plotgen.Scan) -> dict[str, np.ndarray]:
    return {k: p for k, (p, _) in s.truth.items()}


# ---------------------------------------------------------------- Stone Soup
def stone_soup(kind: str, sc: plotgen.Scenario, scans: list[plotgen.Scan]) -> Run:
    """One Stone Soup tracker ("gnn", "lbp" or "jpda") over the scans."""
    transition = CombinedLinearGaussianTransitionModel([OurConstantVelocity(Q**2)] * 2)
    predictor = KalmanPredictor(transition)
    model = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=np.eye(2) * sc.sigma**2)
    updater = KalmanUpdater(model)
    distance = DistanceHypothesiser(predictor, updater, Mahalanobis(),
                                    missed_distance=math.sqrt(chi2.ppf(GATE, 2)))
    v0 = defaults.MAX_SPEED / 3  # our new tracks' velocity std
    initiator = MultiMeasurementInitiator(
        prior_state=GaussianState(StateVector([0.0, 0.0, 0.0, 0.0]),
                                  CovarianceMatrix(np.diag([0.0, v0**2, 0.0, v0**2]))),
        deleter=UpdateTimeStepsDeleter(2), data_associator=GNNWith2DAssignment(distance),
        updater=updater, measurement_model=model, min_points=3)
    detections = [(EPOCH + datetime.timedelta(seconds=s.t),
                   {Detection(StateVector(p), timestamp=EPOCH + datetime.timedelta(seconds=s.t),
                              measurement_model=model) for p in s.dets.tolist()})
                  for s in scans]
    deleter = UpdateTimeStepsDeleter(4)
    if kind == "gnn":
        tracker = MultiTargetTracker(initiator=initiator, deleter=deleter, detector=detections,
                                     data_associator=GNNWith2DAssignment(distance),
                                     updater=updater)
    else:
        pda = PDAHypothesiser(predictor, updater, clutter_spatial_density=sc.clutter_density,
                              prob_detect=sc.pd, prob_gate=GATE)
        associator = JPDAwithLBP(pda) if kind == "lbp" else JPDA(pda)
        tracker = MultiTargetMixtureTracker(initiator=initiator, deleter=deleter,
                                            detector=detections, data_associator=associator,
                                            updater=updater)
    it, run = iter(tracker), Run()
    for s in scans:
        t0 = time.perf_counter()
        _, tracks = next(it)
        run.times.append(time.perf_counter() - t0)
        est = {tr.id: np.asarray(tr.state_vector, dtype=float)[[0, 2], 0] for tr in tracks}
        run.scans.append((s.t, est, truth(s)))
    run.confirmed_end = len(run.scans[-1][1]) if run.scans else 0
    return run


# ---------------------------------------------------------------- the table
TRACKERS: dict[str, tuple[str, Callable[..., Run]]] = {
    "ours GNN": ("gnn", ours), "ours JPDA": ("jpda", ours),
    "Stone Soup GNN": ("gnn", stone_soup), "Stone Soup JPDAwithLBP": ("lbp", stone_soup),
    "Stone Soup JPDA (exact)": ("jpda", stone_soup),
}


def bench(names: list[str], runs: int, c: float, **scenario) -> dict[str, list[tuple]]:
    """Each tracker on `runs` recorded runs of the crossing scenario: (Run, Evaluation)."""
    out: dict[str, list[tuple]] = {n: [] for n in names}
    progress = bar(total=runs * len(names), desc="tracker runs", unit=" run", leave=False)
    for r in range(runs):
        sc = plotgen.crossing(seed=r, **scenario)
        scans = list(sc)
        if r == 0:
            print(f"  region {2 * sc.half_width / 1e3:.1f} km square, clutter density "
                  f"{sc.clutter_density:.3g} /m^2, "
                  f"{np.mean([len(s.dets) for s in scans]):.1f} detections per scan")
        for name in names:
            kind, fn = TRACKERS[name]
            t0 = time.perf_counter()
            run = fn(kind, sc, scans)
            out[name].append((run, evaluate(run.scans, c=c)))
            progress.write(f"  run {r}: {name:<24} {time.perf_counter() - t0:6.1f} s")
            progress.update(1)
    progress.close()
    return out


def table(results: dict[str, list[tuple]], c: float) -> None:
    ref = results.get("Stone Soup GNN")
    ref_mean = float(np.mean([t for run, _ in ref for t in run.times])) if ref else math.nan
    print(f"GOSPA c = {c:g} m, p = 2, alpha = 2 (parts in m^2, as Stone Soup's GOSPAMetric); "
          "per run: switches, breaks, false tracks; ms per scan")
    head = (f"{'tracker':<24} {'GOSPA m':>8} {'loc':>7} {'missed':>7} {'false':>7} "
            f"{'switch':>6} {'break':>5} {'falseT':>6} {'conf s':>6} {'end':>5} "
            f"{'mean ms':>8} {'worst ms':>8} {'SSGNN/x':>7}")
    print(head)
    print("-" * len(head))
    for name, rows in results.items():
        evs: list[Evaluation] = [ev for _, ev in rows]
        runs = [run for run, _ in rows]
        parts = {k: float(np.mean([ev.mean()[k] for ev in evs]))
                 for k in ("total", "localisation", "missed", "false")}
        confirm = [v for ev in evs for v in ev.confirm_time.values() if v is not None]
        times = [t for run in runs for t in run.times]
        mean = float(np.mean(times))
        print(f"{name:<24} {parts['total']:8.1f} {parts['localisation']:7.0f} "
              f"{parts['missed']:7.0f} {parts['false']:7.0f} "
              f"{np.mean([ev.switches for ev in evs]):6.1f} "
              f"{np.mean([ev.breaks for ev in evs]):5.1f} "
              f"{np.mean([len(ev.false_tracks) for ev in evs]):6.1f} "
              f"{np.mean(confirm) if confirm else math.nan:6.2f} "
              f"{np.mean([run.confirmed_end for run in runs]):5.1f} "
              f"{1e3 * mean:8.2f} {1e3 * max(times):8.2f} {ref_mean / mean:7.2f}")
    print()


# ---------------------------------------------------------------- scale
def scale(kind: str, spec: FilterSpec | None = None) -> None:
    """Our tracker on 1,000 targets + 1,000 clutter per scan, then 10,000 detections."""
    sc = plotgen.swarm_plots(targets=1000, clutter=1000.0, scans=10, seed=1)
    tracker = our_tracker(kind, sc, spec)
    times, dets = [], []
    for s in sc:
        outcomes = records(s, sc.sigma)
        t0 = time.perf_counter()
        apply_scan(tracker, s, outcomes)
        times.append(time.perf_counter() - t0)
        dets.append(len(outcomes))
    est = established(tracker, sc.scans - 1.0)
    print(f"  {kind.upper():<4} 1,000 targets + 1,000 clutter: median "
          f"{1e3 * statistics.median(times[3:]):7.1f} ms per scan over scans 4-{len(times)} "
          f"(~{int(np.mean(dets))} detections; first scans {', '.join(f'{1e3 * t:.0f}' for t in times[:3])} ms), "  # noqa: E501
          f"{len(est)} confirmed tracks at the end, {len(tracker)} in all")
    big = plotgen.swarm_plots(targets=5000, clutter=6000.0, scans=3, seed=2)
    tracker = our_tracker(kind, big, spec)
    out = []
    for s in big:
        s = s._replace(dets=s.dets[:10_000])
        outcomes = records(s, big.sigma)
        t0 = time.perf_counter()
        apply_scan(tracker, s, outcomes)
        out.append(f"{len(outcomes)} dets {1e3 * (time.perf_counter() - t0):.0f} ms")
    print(f"  {kind.upper():<4} 10,000 detections per scan, 3 scans: {'; '.join(out)}; "
          f"{len(tracker)} tracks")


# ---------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="Monte Carlo runs (seeds 0..R-1)")
    ap.add_argument("--scans", type=int, default=100)
    ap.add_argument("--targets", type=int, default=20)
    ap.add_argument("--clutter", type=float, default=20.0, help="mean false detections per scan")
    ap.add_argument("--c", type=float, default=100.0, help="GOSPA cut-off, m")
    ap.add_argument("--quick", action="store_true", help="1 run of 30 scans; small table 10 scans")
    ap.add_argument("--scale", action="store_true", help="also the 1,000- and 10,000-plot scans")
    ap.add_argument("--no-stonesoup", action="store_true")
    ap.add_argument("--scale-filter", choices=("cv", "default"), default="cv",
                    help="--scale: our CV filter (default) or the service's default IMM")
    args = ap.parse_args(argv)
    runs, scans, small_scans = (1, 30, 10) if args.quick else (args.runs, args.scans, 20)
    peer = stonesoup is not None and not args.no_stonesoup
    print(f"bench_association  {datetime.datetime.now():%Y-%m-%d %H:%M}  "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} cpus, "
          f"Python {platform.python_version()}, NumPy {np.__version__}"
          + (f", Stone Soup {stonesoup.__version__}" if peer else " (Stone Soup not run)"))
    if stonesoup is None:
        print("Stone Soup is not installed (pip install -e '.[bench]'): ours only")
    warm = plotgen.crossing(targets=4, scans=6, seed=99)  # first calls: imports, caches
    for name in TRACKERS if peer else ["ours GNN", "ours JPDA"]:
        kind, fn = TRACKERS[name]
        fn(kind, warm, list(warm))

    names = ["ours GNN", "ours JPDA"] + (["Stone Soup GNN", "Stone Soup JPDAwithLBP"]
                                         if peer else [])
    print(f"\ncrossing: {args.targets} targets, Pd 0.9, {args.clutter:g} clutter per scan, "
          f"25 m, 1 s, {scans} scans, {runs} run(s)")
    results = bench(names, runs, args.c, targets=args.targets, clutter=args.clutter,
                    scans=scans)
    table(results, args.c)

    small = names + (["Stone Soup JPDA (exact)"] if peer else [])
    print(f"small crossing (for Stone Soup's exact JPDA): 4 targets, Pd 0.9, "
          f"{args.clutter:g} clutter per scan, {small_scans} scans, {runs} run(s)")
    results = bench(small, runs, args.c, targets=4, clutter=args.clutter, scans=small_scans)
    table(results, args.c)

    if args.scale:
        print("scale (ours):")
        spec = FilterSpec() if args.scale_filter == "default" else None
        for kind in ("gnn", "jpda"):
            scale(kind, spec)


if __name__ == "__main__":
    main()
