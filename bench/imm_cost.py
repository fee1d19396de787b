"""CPU per row of the default IMM's update: the compiled kernel (`estimation.imm_jit`, what
the service runs) against `IMM.update`'s own textbook code (its reference, NumPy on
row-major arrays), one pass of k rows at N tracks, in this process.

    python bench/imm_cost.py [--tracks 10000] [--sizes 1 64 312 1024 10000]
    python bench/imm_cost.py --before     # also the three modes before the manoeuvre modes
    python bench/imm_cost.py --before --turn-estimated 5   # and with the turn at its own rate

Tracks: a swarm of polar 3-D measurements, three updates each, then passes of k of them
(best of 5 per size, thread CPU time). The first line gives how long the kernel took to
compile or to load from Numba's cache.
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from zenoh_track import defaults  # noqa: E402
from zenoh_track.estimation import imm_jit  # noqa: E402
from zenoh_track.estimation.catalog import Filter  # noqa: E402
from zenoh_track.estimation.imm import IMM, ModeSet  # noqa: E402
from zenoh_track.estimation.imm_jit import CompiledIMM  # noqa: E402
from zenoh_track.estimation.measurements import MeasurementBatch  # noqa: E402
from zenoh_track.estimation.ucm import CMKFConversion  # noqa: E402
from zenoh_track.tracking.batches import Labelled  # noqa: E402
from zenoh_track.tracking.tracker import Tracker  # noqa: E402
from zenoh_track.wire import Measurement  # noqa: E402


def swarm(n: int, t: float, rng: np.random.Generator) -> list[Measurement]:
    r, az = rng.uniform(5e3, 8e4, n) + 150.0 * t, rng.uniform(-3, 3, n)
    return [Measurement("radar1", f"swarm-{i:06d}", t, 3, True, (float(r[i]), float(az[i]), 0.1),
                        (20.0, 0.003, 0.003), (0.0, 0.0, 0.0), None) for i in range(n)]


def best(fn, args: tuple, reps: int = 5) -> float:
    out = np.inf
    for _ in range(reps):
        c0 = time.thread_time()
        fn(*args)
        out = min(out, time.thread_time() - c0)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--tracks", type=int, default=10_000)
    p.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 312, 1024, 10_000])
    p.add_argument("--before", action="store_true",
                   help="also the default's three modes before the manoeuvre modes (quiet, "
                        "nominal, CA), in the same run, and the ratio per row")
    p.add_argument("--turn-estimated", type=float, default=0.0, metavar="JERK",
                   help="also the default with the service's --imm-turn-estimated JERK")
    args = p.parse_args()
    t0 = time.perf_counter()
    imm_jit.warm()
    print(f"# kernel compiled or loaded in {time.perf_counter() - t0:.2f} s; "
          f"{args.tracks} tracks, CPU per pass (best of 5)")
    sets = {"default": ModeSet().imm(CompiledIMM)}
    if args.turn_estimated > 0:
        sets["with the turn"] = ModeSet(manoeuvre=(*defaults.IMM_MANOEUVRE,
                                                   ("turn", args.turn_estimated))).imm(CompiledIMM)
    if args.before:
        sets["three modes"] = ModeSet(manoeuvre=(), initial=(0.1, 0.6, 0.3)).imm(CompiledIMM)
    per_row: dict[str, dict[int, float]] = {}
    for label, imm in sets.items():
        print(f"{label}: {len(imm.modes)} modes ({', '.join(m[0] for m in imm.modes)})")
        per_row[label] = run(imm, args.tracks, args.sizes)
    for label in sets:
        if args.before and label != "three modes":
            print(f"compiled us/row, {label} / three modes: " + ", ".join(
                f"k={k} {per_row[label][k] / per_row['three modes'][k]:.2f}"
                for k in args.sizes))


def run(imm: IMM, tracks: int, sizes: list[int]) -> dict[int, float]:
    """The table of one mode set; returns the compiled CPU per row at each size."""
    rng = np.random.default_rng(0)
    tracker = Tracker.from_config(filter=Filter(imm, defaults.Q_CV, CMKFConversion, "imm"))
    for t in (0.0, 1.0, 2.0):
        tracker.step(Labelled.of(swarm(tracks, t, rng)))
    arrays = tracker.store.layout(3)
    live = arrays.live()[0]
    print(f"{'k':>7} {'compiled ms':>12} {'us/row':>8} {'textbook ms':>12} {'us/row':>8} "
          f"{'ratio':>6}")
    out = {}
    for k in sizes:
        rows = live[:k]
        batch = MeasurementBatch.of(swarm(tracks, 3.0, rng)[:k], 3)
        dt = batch.t - arrays.t[rows]
        conv = CMKFConversion(batch)
        fast = best(imm_jit.step, (imm, arrays, rows, dt, batch))  # the modes in place
        textbook = conv.__call__  # not a CMKFConversion: IMM.update's own code
        slow = best(imm.update, (copy.deepcopy(arrays), rows, dt, textbook), 3)
        print(f"{k:>7} {fast * 1e3:>12.3f} {fast / k * 1e6:>8.2f} {slow * 1e3:>12.3f} "
              f"{slow / k * 1e6:>8.2f} {slow / fast:>6.1f}")
        out[k] = fast / k
    return out

if __name__ == "__main__":
    main()
