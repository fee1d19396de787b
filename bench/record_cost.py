"""CPU per measurement of batched scans on the record path, for comparing commits.

    python bench/record_cost.py [--targets 10000]

Measures the checkout in the current directory (it puts the current directory first on
the import path), with only interfaces that older commits have too, so the same file
measures an earlier commit from a worktree:

    git worktree add /tmp/base 4bdd515 && (cd /tmp/base && python <this file>)

A swarm of N targets in one scan a second (`zenoh_track.clients.feeds.scenarios.swarm`, --sectors
1), each
scan as a `scan/<sensor>` payload checked into records (`parse_scan`), made columns again
and applied by `Tracker.step` with the default filter; turns 0-1 warm up, turn 2 is
measured. Beside it, the filter core (`filters.cmkf_step`, CV) on as many rows in the
same process: the ratio does not depend on how busy the machine is.
`bench_capacity.py --scan-cost` measures the one-pass path of the current code the same
way.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.getcwd())

from zenoh_track import defaults  # noqa: E402
from zenoh_track.clients.feeds import scenarios  # noqa: E402
from zenoh_track.estimation.filters import cmkf_step  # noqa: E402
from zenoh_track.estimation.measurements import MeasurementBatch  # noqa: E402
from zenoh_track.tracking.batches import Labelled  # noqa: E402
from zenoh_track.tracking.tracker import Tracker  # noqa: E402
from zenoh_track.wire import pack, parse_scan  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--targets", type=int, default=10_000)
    n = p.parse_args().targets
    turns = []
    for _, meas, _ in scenarios.swarm(n, 0, 2.0, sectors=1):
        col = {k: np.array([m[k] for _, m in meas]).tobytes() for k in ("t", "r", "az", "el")}
        first = meas[0][1]
        turns.append(pack({"ids": [k for k, _ in meas], **col, "sr": first["sr"],
                           "saz": first["saz"], "sel": first["sel"]}))
    clock, tracker, spent = time.process_time, Tracker.from_config(), 0.0
    for k, payload in enumerate(turns[:3]):
        t0 = clock()
        tracker.step(Labelled.of(parse_scan("radar1", payload, defaults.NOISE).measurements))
        if k == 2:
            spent = clock() - t0
    arrays = tracker.store.layout(3)
    live = arrays.live()[0]
    batch = MeasurementBatch.of(parse_scan("radar1", turns[2], defaults.NOISE).measurements, 3)
    x, pc = np.ascontiguousarray(arrays.x[live][:, :6]), np.ascontiguousarray(
        arrays.p[live][:, :6, :6])
    core = float("inf")
    for _ in range(5):
        t0 = clock()
        cmkf_step(x, pc, np.full(len(batch), 0.5), 2, 3, 1.0, batch)
        core = min(core, clock() - t0)
    per, core_per = spent / n * 1e6, core / len(batch) * 1e6
    print(f"{os.getcwd()}: {n} targets, records (parse_scan, columns again, Tracker.step) "
          f"{per:.2f} us of CPU per measurement; filter core {core_per:.2f} us per row; "
          f"ratio {per / core_per:.1f}; load average "
          f"{' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
