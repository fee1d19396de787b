"""Starts of track-service stopped by a signal at a random moment, as a supervisor does.

    python bench/bench_stop.py [--starts 200] [--clock realtime ...] [--seed 1]

Half first starts (an empty kernel cache), half with `--state` and a realtime feed
giving it tracks; SIGTERM or SIGINT, to the service or to its process group, at a uniform
moment from the spawn to 2 s after the banner (tests/stop_runs.py). Prints, per kind of
start, how long every process of the group took to be gone after the signal, and whether
each state file loads with every track published before the signal.
"""

from __future__ import annotations

import argparse
import random
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from stop_runs import GONE_WITHIN, Outcome, plan, run_all  # noqa: E402


def kind(o: Outcome) -> str:
    s = o.start
    return (f"{s.clock:<8} {'first' if s.first else 'warm':<5} "
            f"{'--state' if s.state else '':<7}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--starts", type=int, default=200)
    p.add_argument("--clock", action="append", default=[], choices=("realtime", "lockstep"))
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    rng = random.Random(args.seed)
    starts = plan(args.starts, rng, tuple(args.clock) or ("realtime",))
    done: list[Outcome] = []

    def report(o: Outcome) -> None:
        done.append(o)
        mark = "ok" if o.ok else "FAIL " + "; ".join(o.problems)
        when = f"banner {o.banner:5.2f} s" if o.banner is not None else "before the banner"
        print(f"{len(done):4d}/{len(starts)} {kind(o)} {o.start.sig.name:<7} "
              f"{'group' if o.start.group else 'pid':<5} at {o.delay:5.2f} s ({when}): "
              f"gone in {o.gone:.2f} s, tracks {o.tracks_seen} seen / "
              f"{o.tracks_loaded if o.tracks_loaded is not None else '-'} in the file  {mark}",
              flush=True)

    with tempfile.TemporaryDirectory() as tmp:
        outcomes = run_all(starts, Path(tmp), rng, report)
    print(f"\n{'kind':<23}{'starts':>7}{'before banner':>14}{'gone p50':>10}{'max':>7}"
          f"{'state kept':>12}{'failed':>8}")
    for k in sorted({kind(o) for o in outcomes}):
        group = [o for o in outcomes if kind(o) == k]
        gone = np.array([o.gone for o in group])
        kept = [o for o in group if o.tracks_loaded is not None]
        print(f"{k:<23}{len(group):>7}{sum(o.banner is None for o in group):>14}"
              f"{np.median(gone):>9.2f}s{gone.max():>6.2f}s"
              f"{f'{len(kept)}/{sum(o.tracks_seen > 0 for o in group)}':>12}"
              f"{sum(not o.ok for o in group):>8}")
    failed = [o for o in outcomes if not o.ok]
    gone = np.array([o.gone for o in outcomes])
    print(f"\nall {len(outcomes)} starts: gone within {gone.max():.2f} s of the signal "
          f"(target {GONE_WITHIN:g} s), p50 {np.median(gone):.2f} s; "
          f"{len(failed)} failed")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
