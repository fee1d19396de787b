"""The cost of `--state`: a checkpoint of N tracks, its size, the copy the worker makes
(`checkpoint.capture`, every --state-period s), the encoding the writer thread does
(`checkpoint.encode`) and the restore at start (`checkpoint.load`), best of --repeat.

    python bench/bench_checkpoint.py --tracks 1000 10000 --filters imm cv
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from zenoh_track.estimation.catalog import FilterSpec  # noqa: E402
from zenoh_track.tracking import checkpoint  # noqa: E402
from zenoh_track.tracking.batches import Labelled  # noqa: E402
from zenoh_track.tracking.tracker import Tracker, TrackerConfig  # noqa: E402
from zenoh_track.wire import Measurement  # noqa: E402


def tracker(name: str, n: int) -> Tracker:
    tr = Tracker.from_config(TrackerConfig(filter=FilterSpec(name)))
    for k in range(3):
        tr.step(Labelled.of([Measurement("r", f"t{i}", float(k), 3, True,
                              (5000.0 + i + 10 * k, 0.0005 * i, 0.1), (10.0, 0.01, 0.01),
                              (0.0, 0.0, 0.0), None) for i in range(n)]))
    return tr


def best(fn, repeat: int) -> tuple[float, object]:
    out, times = None, []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tracks", type=int, nargs="+", default=[1000, 10000])
    p.add_argument("--filters", nargs="+", default=["imm", "cv"])
    p.add_argument("--repeat", type=int, default=5)
    a = p.parse_args()
    print(f"{'filter':<7}{'tracks':>7}{'MB':>7}{'capture ms':>12}{'encode ms':>11}"
          f"{'load ms':>9}")
    for name in a.filters:
        for n in a.tracks:
            tr = tracker(name, n)
            t_cap, cap = best(lambda tr=tr: checkpoint.capture(tr), a.repeat)
            t_enc, data = best(lambda cap=cap: checkpoint.encode(cap), a.repeat)
            t_load, _ = best(lambda name=name, data=data: checkpoint.load(
                Tracker.from_config(TrackerConfig(filter=FilterSpec(name))), data), a.repeat)
            print(f"{name:<7}{n:>7}{len(data) / 1e6:>7.1f}{t_cap * 1e3:>12.1f}"
                  f"{t_enc * 1e3:>11.1f}{t_load * 1e3:>9.1f}", flush=True)


if __name__ == "__main__":
    main()
