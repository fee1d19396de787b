"""CPU per row of the default IMM's update: the compiled kernel (`estimation.imm_jit`, what
the service runs) against `IMM.update`'s own textbook code (its reference, NumPy on
row-major arrays), one pass of k rows at N tracks, in this process.

    python bench/imm_cost.py [--tracks 10000] [--sizes 1 64 312 1024 10000]
    python bench/imm_cost.py --before     # also the three modes before the manoeuvre modes
    python bench/imm_cost.py --before --turn-estimated 5   # and with the turn at its own rate
    python bench/imm_cost.py --shares     # a realtime part on two threads, pieces or halves

Tracks: a swarm of polar 3-D measurements, three updates each, then passes of k of them
(best of 5 per size, thread CPU time). The first line gives how long the kernel took to
compile or to load from Numba's cache.
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
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
    p.add_argument("--shares", action="store_true",
                   help="instead: the wall time of a realtime part (PART rows a thread) on "
                        "two threads, cut in `blocks.SHARES` pieces a thread or in halves, "
                        "alone and beside a process keeping one core busy")
    args = p.parse_args()
    if args.shares:
        shares(args.tracks)
        return
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

def shares(tracks: int, passes: int = 400) -> None:
    """Wall time of passes of 2 x PART rows on two threads, the default pieces (each
    taken by whichever thread is free) against fixed halves (the helper's half waited
    for), in turn, without and then with a busy process beside them."""
    import subprocess

    from zenoh_track.estimation import blocks
    from zenoh_track.tracking.tracker import PART

    imm_jit.warm()
    imm, rng = ModeSet().imm(CompiledIMM), np.random.default_rng(0)
    tracker = Tracker.from_config(filter=Filter(imm, defaults.Q_CV, CMKFConversion, "imm"))
    for t in (0.0, 1.0, 2.0):
        tracker.step(Labelled.of(swarm(tracks, t, rng)))
    arrays, k = tracker.store.layout(3), 2 * PART
    rows = arrays.live()[0][:k]
    batch = MeasurementBatch.of(swarm(tracks, 3.0, rng)[:k], 3)
    dt = batch.t - arrays.t[rows]
    shared, pool = blocks.over_rows, ThreadPoolExecutor(1)

    def halves(k: int, block: int, work: Callable[[int, int], None],
               threads: int | None = None) -> None:
        (lo, mid), (_, hi) = blocks.parts(k, block, 2)
        helper = pool.submit(work, mid, hi)
        work(lo, mid)
        helper.result()

    print(f"# a part of {k} rows on 2 threads, wall ms over {passes} passes each "
          f"(pieces: {blocks.SHARES} a thread; halves: one fixed half a thread)")
    print(f"{'beside':>10} {'cut':>7} {'mean':>7} {'p50':>7} {'p90':>7} {'p99':>7}")
    for beside in ("nothing", "a busy core"):
        busy = (subprocess.Popen([sys.executable, "-c", "while True: pass"])
                if beside != "nothing" else None)
        times: dict[str, list[float]] = {"pieces": [], "halves": []}
        try:
            for _ in range(passes):
                for cut, over_rows in (("pieces", shared), ("halves", halves)):
                    blocks.over_rows = over_rows
                    w0 = time.perf_counter()
                    imm_jit.step(imm, arrays, rows, dt, batch, threads=2)
                    times[cut].append(time.perf_counter() - w0)
        finally:
            blocks.over_rows = shared
            if busy is not None:
                busy.kill()
                busy.wait()
        for cut, w in times.items():
            a = np.array(w) * 1e3
            print(f"{beside:>10} {cut:>7} {a.mean():>7.2f} {np.median(a):>7.2f} "
                  f"{np.percentile(a, 90):>7.2f} {np.percentile(a, 99):>7.2f}")


if __name__ == "__main__":
    main()
