"""Where each mode of the default IMM puts one aircraft of the `manoeuvres` scenario after
its track's last update (diagnosis of a scan not held, docs/accuracy.md "What is not
met, and why"): the track nearest the aircraft at `--after`, each mode's mixed prediction one and
two scans later, its predicted probability and its distance from the truth.

    python bench/coast.py --period 4 --seed 4 --aircraft 7g-s-0 --after 68
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import manoeuvres as bench  # noqa: E402  # bench/manoeuvres.py

from zenoh_track.clients.feeds.manoeuvres import Manoeuvres  # noqa: E402
from zenoh_track.tracking.batches import Unlabelled  # noqa: E402
from zenoh_track.tracking.plot_association import SensorModels  # noqa: E402
from zenoh_track.tracking.tracker import Tracker, TrackerConfig  # noqa: E402
from zenoh_track.wire import Measurement  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--period", type=float, default=4.0)
    p.add_argument("--seed", type=int, default=4)
    p.add_argument("--aircraft", default="7g-s-0")
    p.add_argument("--after", type=float, default=68.0, help="s: the scan of the last update")
    args = p.parse_args(argv)
    sc = Manoeuvres(args.period, 0.9, 10.0, 2, args.seed)
    tracker = Tracker.from_config(TrackerConfig(filter=bench.spec("default", args.period),
                                    sensors=SensorModels(pd=sc.pd)))
    imm, flight = tracker.updater, next(f for f in sc.flights if f.name == args.aircraft)
    scans = list(sc)
    seen = {round(s.t, 6): sc.flights.index(flight) in s.origin.tolist() for s in scans}
    for s in scans:
        tracker.step(Unlabelled.of(s.sensor, s.t, [
            Measurement(s.sensor, "", s.t, 3, True, tuple(d), (sc.sr, sc.sa, sc.sa),
                        s.sensor_pos, None) for d in s.dets.tolist()]))
        if abs(s.t - args.after) > 1e-9:
            continue
        snap, true = tracker.snapshot(s.t), flight.state(s.t)[0]
        track = snap.ids[int(np.argmin(np.linalg.norm(snap.pos - true, axis=1)))]
        arrays = tracker.store.layouts[3]
        rows = np.array([arrays.ids.index(track)])
        print(f"track {track} of {args.aircraft} (seed {args.seed}, {args.period:g} s scans), "
              f"last updated at {arrays.t[rows[0]]:g} s; detected at the next scans: "
              + ", ".join(f"{t:g} s {'yes' if seen.get(round(t, 6)) else 'no'}"
                          for t in (s.t + args.period, s.t + 2 * args.period)))
        for k in (1, 2):
            t = s.t + k * args.period
            dt = t - arrays.t[rows]
            c, x0, p0 = imm.mix(arrays.mode_x[rows], arrays.mode_p[rows],
                                arrays.mode_prob[rows], imm.transition(dt), 3)
            true = flight.state(t)[0]
            mix = np.zeros(3)
            for j, mode in enumerate(imm.modes):
                xp, _ = imm.predict_mode(j, dt, x0[:, j], p0[:, j], 3)
                mix += c[0, j] * xp[0, :3]
                print(f"  {t:6g} s  {mode[0]:<8} probability {c[0, j]:.3f}  "
                      f"{np.linalg.norm(xp[0, :3] - true):7.0f} m off")
            print(f"  {t:6g} s  mixture                    {np.linalg.norm(mix - true):7.0f} m off")
        return
    raise SystemExit(f"no scan at {args.after} s")


if __name__ == "__main__":
    main()
