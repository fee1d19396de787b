"""CPU time of our scan step on the crossing benchmark, this checkout against another.

`python bench/step_cpu.py --base DIR` times `Tracker.step` (GNN or JPDA, the CV filter,
the scans of `bench_association.py`'s crossing scenario, seeds 0-2, 100 scans each) with
`time.thread_time` (the CPU of the stepping thread alone: on a shared machine wall time
measures the neighbours too) in fresh processes, alternately for this checkout and for
the one in DIR (e.g. `git worktree add /tmp/base <commit>`), `--rounds` times each, and
prints each process's ms per scan (the fastest of its `--reps` passes), the medians and
their ratio. Each process also prints a digest of every track's id, state, covariance,
time, NIS, score and life after every scan: equal digests mean the two checkouts
computed the same bits.
"""

from __future__ import annotations

import argparse
import hashlib
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent


def measure(root: Path, kind: str, reps: int) -> tuple[float, str]:
    """(ms per scan, the fastest pass; digest of the first pass) of the code in `root`."""
    sys.path[:0] = [str(root), str(root / "bench")]
    import bench_association as ba  # of that checkout
    import numpy as np

    from zenoh_track.clients.feeds import plotgen

    # a checkout before Tracker.step took typed batches stepped a list of Outcome records
    apply = getattr(ba, "apply_scan", None) or (
        lambda tracker, s, records: tracker.step(records, s.t, tracker.scan_associator))
    scenarios = [plotgen.crossing(seed=r) for r in range(3)]
    scans = [list(sc) for sc in scenarios]
    best, digest = float("inf"), ""
    for rep in range(reps):
        h, cpu, count = hashlib.sha256(), 0.0, 0
        for sc, ss in zip(scenarios, scans, strict=True):
            tracker = ba.our_tracker(kind, sc)
            for s, outcomes in [(s, ba.records(s, sc.sigma)) for s in ss]:
                t0 = time.thread_time()
                apply(tracker, s, outcomes)
                cpu += time.thread_time() - t0
                count += 1
                if rep == 0:
                    _digest(h, tracker, np)
        best = min(best, 1e3 * cpu / count)
        digest = digest or h.hexdigest()[:16]
    return best, digest


def _digest(h, tracker, np) -> None:  # noqa: ANN001
    a = tracker.store.layouts.get(2)
    if a is not None:
        rows = a.rows()
        for col in (rows, a.x[rows], a.p[rows], a.t[rows], a.nis[rows], a.score[rows],
                    a.hits[rows], a.misses[rows], a.confirmed[rows]):
            h.update(np.ascontiguousarray(col).tobytes())
        h.update(",".join(a.ids[r] for r in rows.tolist()).encode())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", type=Path, help="another checkout to compare against")
    ap.add_argument("--kind", default="gnn", choices=["gnn", "jpda"])
    ap.add_argument("--rounds", type=int, default=6, help="processes per checkout")
    ap.add_argument("--reps", type=int, default=4, help="passes over the scans per process")
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        ms, digest = measure(args.child, args.kind, args.reps)
        print(f"{ms:.4f} {digest}")
        return
    sides = {"this": HERE} | ({"base": args.base.resolve()} if args.base else {})
    times: dict[str, list[float]] = {k: [] for k in sides}
    for r in range(args.rounds):
        for name, root in sides.items():
            out = subprocess.run([sys.executable, __file__, "--child", str(root), "--kind",
                                  args.kind, "--reps", str(args.reps)], cwd=root,
                                 capture_output=True, text=True, check=True).stdout.split()
            times[name].append(float(out[0]))
            print(f"round {r}: {name:<4} {float(out[0]):6.3f} ms per scan  digest {out[1]}",
                  flush=True)
    med = {k: statistics.median(v) for k, v in times.items()}
    print("median ms per scan (CPU of Tracker.step): " +
          ", ".join(f"{k} {v:.3f}" for k, v in med.items()))
    if "base" in med:
        print(f"this / base: {med['this'] / med['base']:.3f} "
              f"({100 * (1 - med['this'] / med['base']):.1f} % less CPU)")


if __name__ == "__main__":
    main()
