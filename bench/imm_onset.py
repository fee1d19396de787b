"""The conflict between the bars of scenarios A, B and C and the manoeuvre targets
(docs/accuracy.md, "Manoeuvres"): variants of the default IMM (`imm.ModeSet` options),
in-process, on A (1 run), B (100 runs) and C (20 runs) as bench/imm_design.py runs them,
and on the manoeuvres scenario as bench/manoeuvres.py runs it (scans at each period,
labelled measurements at 1 s); per class breaks (b), the smallest fraction held (h),
RMSE while manoeuvring / on straight legs (m) and NEES while manoeuvring (N).

    python bench/imm_onset.py --runs 3 --period 1 --period 4 onset=60.0 onset=3000.0 default
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import imm_design as design  # noqa: E402
import manoeuvres as bench  # noqa: E402

from zenoh_track.clients.evaluation import manoeuvre_score as ms  # noqa: E402
from zenoh_track.clients.feeds.manoeuvres import Manoeuvres  # noqa: E402
from zenoh_track.estimation.catalog import FilterSpec  # noqa: E402
from zenoh_track.estimation.imm import ModeSet  # noqa: E402
from zenoh_track.estimation.imm_jit import CompiledIMM  # noqa: E402

RUNS = {"display": 1, "radar3d": 100, "maneuver": 20}


def manoeuvres(name: str, runs: int, period: float, labelled: bool) -> str:
    got = []
    for r in range(runs):
        sc = Manoeuvres(period, 0.9, 10.0, 2, r)
        shown, states, _ = bench.ours(name, sc, labelled)
        got += ms.score(sc, shown, states, labelled)
    return " | ".join(f"{k} b{r['breaks']:.0f} h{r['held_min']:.2f} m{r['rmse_man']:.0f}/"
                      f"{r['rmse_str']:.0f} N{r['nees_man']:.0f}"
                      for k, r in ms.summary(got).items() if k != "straight")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("variants", nargs="+", help="k=v;k=v (ModeSet options) or default")
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--period", type=float, action="append", default=[])
    args = p.parse_args()
    best = {sc: design.run(sc, n, design.tracker(None, FilterSpec(design.BEST[sc])))
            for sc, n in RUNS.items()}
    print(f"bars: A <= {1.2 * best['display']['frame RMS']:.4f} m, B ratio <= 1.05 and NEES "
          f"in [5.34, 6.70], C straight <= {1.25 * best['maneuver']['straight RMSE']:.1f} m")
    for v in args.variants:
        changes = {} if v == "default" else {
            k: eval(x) for k, x in (kv.split("=") for kv in v.split(";"))}  # noqa: S307
        a, b, c = (design.run(sc, n, design.tracker(ModeSet(**changes).imm(CompiledIMM)))
                   for sc, n in RUNS.items())
        print(f"{v}: A {a['frame RMS']:.4f} B {b['RMSE/CRB']:.4f} NEES {b['NEES']:.2f} "
              f"(window {b['max window NEES']:.2f}) C {c['straight RMSE']:.1f} "
              f"{c['slow turn RMSE']:.1f} {c['fast turn RMSE']:.1f}", flush=True)
        name = "default" if v == "default" else f"default:{v}"
        for period in args.period or [1.0, 4.0]:
            print(f"  {period:g} s: {manoeuvres(name, args.runs, period, False)}", flush=True)
        print(f"  labelled 1 s: {manoeuvres(name, args.runs, 1.0, True)}", flush=True)


if __name__ == "__main__":
    main()
