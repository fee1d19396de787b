"""Positions whose time is not quite theirs (docs/timing.md): the held-out measure in
process (the service's tracker without Zenoh; `track-eval heldout --feed stamped`
measures the service itself).

    python bench/timing.py               # 50 aircraft, 300 s, seed 0
    python bench/timing.py --aircraft 100 --seed 1
    python bench/timing.py --seeds 20    # seeds 0-19: each variant's mean and worst ratio
    python bench/timing.py --gaussian    # the time noise one Gaussian, not the mixture
    python bench/timing.py --accelerating  # legs straight or changing speed (+-2 m/s^2)

The feed of `zenoh_track.clients.feeds.stamped` (80-300 m/s, straight and turning, time
stamps off by 0.1-0.2 s RMS, heavy-tailed, with repeats and quantisation), every other
position sent with sigma 0, the frame 1 s later scored against the position held out:
RMS and its ratio to linear extrapolation's from the last two positions sent, in all,
in turns and straight, for three variants in the same run: the time noise not modelled
(the noise check's position noise only), learned by the noise check (the service as it
runs), and stated by the feed (`sigma_t`, each aircraft's own RMS). Also the noise
check's report of the sensor.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from zenoh_track import defaults  # noqa: E402
from zenoh_track.clients.evaluation import heldout as held  # noqa: E402
from zenoh_track.clients.feeds import stamped  # noqa: E402
from zenoh_track.estimation import timing  # noqa: E402
from zenoh_track.tracking import noise_check  # noqa: E402
from zenoh_track.tracking.batches import Labelled  # noqa: E402
from zenoh_track.tracking.tracker import Tracker, TrackerConfig  # noqa: E402
from zenoh_track.wire import Measurement  # noqa: E402

TIMING = noise_check.NoiseCheck._timing


def run(f: stamped.StampedFeed, sigma_t: np.ndarray | None) -> tuple[np.ndarray, Tracker]:
    """The frames at the held-out instants (N, K, 3) of a tracker fed the even ones."""
    tr = Tracker.from_config(TrackerConfig())
    n = len(f.pos)
    pred = np.full_like(f.pos, np.nan)
    for k in range(0, len(f.ts), 2):
        tr.step(Labelled.of([Measurement(
            "feed", f"t{i}", float(f.ts[k]), 3, False, tuple(f.pos[i, k]), (0.0,) * 3,
            (0.0,) * 3, None, None if sigma_t is None else float(sigma_t[i]))
            for i in range(n)]))
        if k + 1 < len(f.ts):
            snap = tr.snapshot(f.ts[k + 1], detail=False)
            order = {name: j for j, name in enumerate(snap.ids)}
            pred[:, k + 1] = snap.pos[[order[f"t{i}"] for i in range(n)]]
    return pred, tr


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--aircraft", type=int, default=50)
    p.add_argument("--duration", type=float, default=300.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--seeds", type=int, default=1,
                   help="seeds from --seed on: each variant's mean and worst ratio")
    p.add_argument("--gaussian", action="store_true",
                   help="the time noise one Gaussian of variance sigma_t^2 (not the "
                        "mixture of defaults.TIME_MIXTURE)")
    p.add_argument("--accelerating", action="store_true",
                   help="legs straight or changing speed only, half each")
    args = p.parse_args()
    if args.accelerating:
        stamped.LEGS = (0.5, 0.0, 0.0, 0.5)
    # the keyword's default, read at each call: the mixture of this run
    timing.mixture_update.__defaults__ = (((1.0, 1.0),) if args.gaussian
                                          else defaults.TIME_MIXTURE,)
    parts = ("all", "turns", "straight")
    labels = ("time noise not modelled", "learned (the service)", "stated sigma_t")
    ratios = {label: [] for label in labels}
    for seed in range(args.seed, args.seed + args.seeds):
        got = one(args, seed, parts, labels, verbose=args.seeds == 1)
        for label in labels:
            ratios[label].append(got[label])
    if args.seeds > 1:
        print(f"{args.aircraft} aircraft, {args.duration:g} s, seeds {args.seed}-"
              f"{args.seed + args.seeds - 1}{', one Gaussian' if args.gaussian else ''}: "
              "1-s-ahead RMS against the held-out positions / linear extrapolation's, "
              "mean and worst over the seeds")
        print(f"{'variant':<30}" + "".join(f"{k:>16}" for k in parts))
        for label in labels:
            a = np.array(ratios[label])
            print(f"{label:<30}" + "".join(f"{m:>8.3f}{w:>8.3f}"
                                           for m, w in zip(a.mean(0), a.max(0), strict=True)))


def one(args: argparse.Namespace, seed: int, parts: tuple[str, ...],
        labels: tuple[str, ...], verbose: bool) -> dict[str, list[float]]:
    """One seed's three variants: their ratios to linear extrapolation's RMS per part,
    printed as a table with the noise check's reports when `verbose`."""
    f = stamped.generate(args.aircraft, 1, seed, args.duration)
    first = np.zeros(len(f.pos))
    lin = held.linear(f.ts, f.pos)
    where = {"all": None, "turns": f.turning, "straight": ~f.turning}
    base = {k: held.score(lin, f.pos, f.ts, first, where[k])["rms"] for k in parts}
    if verbose:
        print(f"{args.aircraft} aircraft, {args.duration:g} s, seed {seed}"
              f"{', one Gaussian' if args.gaussian else ''}: time error RMS "
              f"{np.sqrt(np.mean(f.sigma_t ** 2)):.3f} s; 1-s-ahead RMS against the "
              "held-out positions, m, and / linear extrapolation's")
        print(f"{'variant':<30}" + "".join(f"{k:>18}" for k in parts) + f"{'CPU, s':>8}")
        print(f"{'linear extrapolation':<30}" + "".join(f"{v:>10.2f}{1.0:>8.3f}"
                                                       for v in base.values()))
    reports, out = {}, {}
    for label, st, learn in zip(labels, (None, None, f.sigma_t), (False, True, True),
                                strict=True):
        noise_check.NoiseCheck._timing = TIMING if learn else (lambda *a: None)
        t0 = time.process_time()
        pred, tr = run(f, st)
        cpu = time.process_time() - t0
        got = {k: held.score(pred, f.pos, f.ts, first, where[k])["rms"] for k in parts}
        out[label] = [got[k] / base[k] for k in parts]
        if verbose:
            print(f"{label:<30}" + "".join(f"{got[k]:>10.2f}{got[k] / base[k]:>8.3f}"
                                           for k in parts) + f"{cpu:>8.1f}")
        reports[label] = tr.noise.status().get("feed")
    noise_check.NoiseCheck._timing = TIMING
    if verbose:
        for label, rep in reports.items():
            print(f"noise check, {label}: {rep}")
    return out


if __name__ == "__main__":
    main()
