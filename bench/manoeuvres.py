"""The `manoeuvres` scenario in-process (the service's tracker without Zenoh, the same
scans and scoring as `track-eval manoeuvres`), for designing the default filter, with
Stone Soup's GNN and a CV EKF (continuous white-noise acceleration q 300 m^2/s^3) as the
peer on the same scans.

    python bench/manoeuvres.py                      # default, ncv-blair, stonesoup; 1, 2, 4, 5 s
    python bench/manoeuvres.py default --period 2 --runs 4
    python bench/manoeuvres.py default --labelled
    python bench/manoeuvres.py --classes straight,orbit,helicopter,glider   # slow, tight
    python bench/manoeuvres.py before default   # the default before the manoeuvre modes
    python bench/manoeuvres.py default ncv-blair --period 1 --onset   # NEES by scans since onset

`before` is the default IMM before the manoeuvre modes (quiet, nominal, CA with jerk 0.1), gated by
the combined state and the nominal noise, deleted after 4 misses; `default:k=v;k=v` a
variant of `imm.ModeSet` (e.g. `default:onset=600.0`).
"""

from __future__ import annotations

import argparse
import datetime
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from zenoh_track import defaults  # noqa: E402
from zenoh_track.clients.evaluation import manoeuvre_score as ms  # noqa: E402
from zenoh_track.clients.feeds import feed_plots  # noqa: E402
from zenoh_track.clients.feeds.manoeuvres import CLASSES, Manoeuvres  # noqa: E402
from zenoh_track.estimation.catalog import FilterSpec  # noqa: E402
from zenoh_track.estimation.imm import ModeSet  # noqa: E402
from zenoh_track.estimation.imm_jit import CompiledIMM  # noqa: E402
from zenoh_track.tracking.batches import Labelled, Unlabelled  # noqa: E402
from zenoh_track.tracking.plot_association import SensorModels  # noqa: E402
from zenoh_track.tracking.reach import Reach  # noqa: E402
from zenoh_track.tracking.tracker import (  # noqa: E402
    SCAN_ASSOCIATORS,
    Tracker,
    TrackerConfig,
    stages,
)
from zenoh_track.wire import Measurement  # noqa: E402

A_MAX = 7 * 9.80665
SIGMA = 1.5e-3 * 36_000.0  # m: the radar's cross-range noise at the aircraft's distance
EPOCH = datetime.datetime(2026, 1, 1)


def spec(name: str, period: float) -> FilterSpec:
    if name == "ncv-blair":
        return FilterSpec("cv", ms.blair_q(A_MAX, period, SIGMA))
    if name.startswith("default") or name == "before":
        return FilterSpec()
    raise ValueError(name)


def ours(name: str, sc: Manoeuvres, labelled: bool, associator: str = "gnn",
         second_look: float = defaults.SECOND_LOOK, stitch_reach: float = defaults.MAX_ACCEL,
         delete_misses: int = defaults.DELETE_MISSES) -> tuple[ms.Shown, ms.States, float]:
    """Our tracker over the scenario: what a lockstep service would show at each scan."""
    config = TrackerConfig(filter=spec(name, sc.period), associator=associator,
                           sensors=SensorModels(pd=sc.pd),  # the radar's, as stated
                           second_look=second_look, stitch_reach=stitch_reach,
                           delete_misses=4 if name == "before" else delete_misses)
    built, parts = config.filter.build(), {}
    if name == "before":  # the default before the manoeuvre modes, gated by the store's state
        built = replace(built, updater=ModeSet(manoeuvre=(), ca_q=0.1,
                                               initial=(0.1, 0.6, 0.3)).imm(CompiledIMM))
        parts["scan_associator"] = SCAN_ASSOCIATORS[associator](
            built.q, config.sensors, config.gate_probability, predict=None,
            stages=stages(associator, Reach(), second_look))
    if ":" in name:  # a variant of the default mode set: default:key=value,key=value
        changes = {k: eval(v) for k, v in (kv.split("=") for kv in name.split(":")[1].split(";"))}
        built = replace(built, updater=ModeSet(**changes).imm(CompiledIMM))
    tr = Tracker.from_config(config, filter=built, **parts)
    shown, states, spent = {}, {}, 0.0
    names = [f.name for f in sc.flights]
    for s in sc:
        t0 = time.perf_counter()
        if labelled:
            tr.step(Labelled.of([Measurement(s.sensor, names[o], s.t, 3, True, tuple(d),
                                  (sc.sr, sc.sa, sc.sa), s.sensor_pos, None)
                      for d, o in zip(s.dets.tolist(), s.origin.tolist(), strict=True)
                      if o >= 0]))
        else:
            tr.step(Unlabelled.of(s.sensor, s.t, [
                Measurement(s.sensor, "", s.t, 3, True, tuple(d), (sc.sr, sc.sa, sc.sa),
                            s.sensor_pos, None) for d in s.dets.tolist()]))
        spent += time.perf_counter() - t0
        snap = tr.snapshot(s.t)
        t = round(s.t, 6)
        shown[t] = {k: snap.pos[i].copy() for i, k in enumerate(snap.ids)
                    if snap.status[i] != "tentative"}
        arrays = tr.store.layouts.get(3)
        states[t] = {}
        if arrays is not None:
            rows = arrays.rows()
            rows = rows[np.abs(arrays.t[rows] - s.t) < 1e-9]
            states[t] = {arrays.ids[r]: (arrays.x[r].copy(), arrays.p[r].copy())
                         for r in rows.tolist()}
    return shown, states, spent


def stone_soup(sc: Manoeuvres) -> tuple[ms.Shown, ms.States, float]:
    """Stone Soup's GNN (2-D assignment, Mahalanobis gate at the 0.999 chi-square point)
    with a CV EKF (q 300) on the polar detections, 3-of-3 initiation, deleted after 4
    scans without an update."""
    from scipy.stats import chi2
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.deleter.time import UpdateTimeStepsDeleter
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.measures import Mahalanobis
    from stonesoup.models.measurement.nonlinear import CartesianToElevationBearingRange
    from stonesoup.models.transition.linear import (
        CombinedLinearGaussianTransitionModel,
        ConstantVelocity,
    )
    from stonesoup.predictor.kalman import ExtendedKalmanPredictor
    from stonesoup.tracker.simple import MultiTargetTracker
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import ExtendedKalmanUpdater

    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(300.0)] * 3)
    predictor = ExtendedKalmanPredictor(transition)
    model = CartesianToElevationBearingRange(
        ndim_state=6, mapping=(0, 2, 4), noise_covar=np.diag([sc.sa**2, sc.sa**2, sc.sr**2]))
    updater = ExtendedKalmanUpdater(model)
    hyp = DistanceHypothesiser(predictor, updater, Mahalanobis(),
                               missed_distance=math.sqrt(chi2.ppf(0.999, 3)))
    v0 = 340.0 / 3
    initiator = MultiMeasurementInitiator(
        prior_state=GaussianState(StateVector([0.0] * 6),
                                  CovarianceMatrix(np.diag([0.0, v0**2] * 3))),
        deleter=UpdateTimeStepsDeleter(2), data_associator=GNNWith2DAssignment(hyp),
        updater=updater, measurement_model=model, min_points=3)
    scans = list(sc)
    detections = []
    for s in scans:
        when = EPOCH + datetime.timedelta(seconds=s.t)
        # Stone Soup's bearing: counter-clockwise from x (East); ours from North, clockwise
        detections.append((when, {Detection(StateVector([el, math.pi / 2 - az, r]),
                                            timestamp=when, measurement_model=model)
                                  for r, az, el in s.dets.tolist()}))
    tracker = MultiTargetTracker(initiator=initiator, deleter=UpdateTimeStepsDeleter(4),
                                 detector=detections, data_associator=GNNWith2DAssignment(hyp),
                                 updater=updater)
    shown, states, spent = {}, {}, 0.0
    it = iter(tracker)
    for s in scans:
        t0 = time.perf_counter()
        _, tracks = next(it)
        spent += time.perf_counter() - t0
        t = round(s.t, 6)
        shown[t], states[t] = {}, {}
        for track in tracks:
            st = track.state
            x = np.asarray(st.state_vector, float)[[0, 2, 4, 1, 3, 5], 0]
            dt = s.t - (st.timestamp - EPOCH).total_seconds()
            shown[t][str(track.id)] = x[:3] + x[3:] * dt
            if abs(dt) < 1e-9:
                idx = [0, 2, 4, 1, 3, 5]
                states[t][str(track.id)] = (x, np.asarray(st.covar, float)[np.ix_(idx, idx)])
    return shown, states, spent


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("names", nargs="*", default=["default", "ncv-blair", "stonesoup"])
    p.add_argument("--period", type=float, action="append", default=[])
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--per-class", type=int, default=2)
    p.add_argument("--classes", type=feed_plots.classes, default=CLASSES,
                   help="classes, comma-separated (the scenario's; also orbit, helicopter, "
                        "glider)")
    p.add_argument("--pd", type=float, default=0.9)
    p.add_argument("--clutter", type=float, default=10.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--labelled", action="store_true")
    p.add_argument("--onset", action="store_true",
                   help="also RMSE and NEES while manoeuvring by scans since the onset")
    p.add_argument("--associator", choices=("gnn", "jpda"), default="gnn", help="ours")
    p.add_argument("--second-look", type=float, default=defaults.SECOND_LOOK,
                   help="ours: the service's --second-look (0: off)")
    p.add_argument("--stitch-reach", type=float, default=defaults.MAX_ACCEL,
                   help="ours: the service's --stitch-reach (0: off)")
    p.add_argument("--delete-misses", type=int, default=defaults.DELETE_MISSES,
                   help="ours: the service's --delete-misses")
    args = p.parse_args()
    for period in args.period or [1.0, 2.0, 4.0, 5.0]:
        for name in args.names:
            got: list[ms.Aircraft] = []
            spent, wall = 0.0, time.monotonic()
            for r in range(args.runs):
                sc = Manoeuvres(period, args.pd, args.clutter, args.per_class, args.seed + r,
                                classes=args.classes)
                if name == "stonesoup":
                    shown, states, s = stone_soup(sc)
                else:
                    shown, states, s = ours(name, sc, args.labelled, args.associator,
                                            args.second_look, args.stitch_reach,
                                            args.delete_misses)
                spent += s
                got += ms.score(sc, shown, states, args.labelled)
            form = "labelled" if args.labelled else f"Pd {args.pd:g}, {args.clutter:g} clutter"
            print(ms.table(f"{name}: period {period:g} s, {form}, {args.runs} runs x "
                           f"{args.per_class} a class ({spent:.1f} s tracking, "
                           f"{time.monotonic() - wall:.0f} s)", ms.summary(got)), flush=True)
            if args.onset:
                print(ms.onset_table([a for a in got if a.kind != "straight"], period),
                      flush=True)


if __name__ == "__main__":
    main()
