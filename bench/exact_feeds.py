"""Positions stated exact (docs/accuracy.md, "Exact positions"): variants in-process (the
service's tracker without Zenoh; `track-eval heldout` measures the service itself).

    python bench/exact_feeds.py heldout   # the held-out measure: the noise check's parts
    python bench/exact_feeds.py a         # scenario A: the default IMM's CA noise and sojourn
    python bench/exact_feeds.py a-trace   # scenario A per scan: mode probabilities, frame RMS

`heldout`: 50 aircraft (`zenoh_track.clients.evaluation.heldout.generate`, seed 0, 120
s), every other
position sent with sigma 0 or 1 m, the frame 1 s later against the position held out,
RMS as a multiple of linear extrapolation's; with the noise check as in the service,
without using the measured noise, and without the one-time covariance inflation.
`a`: scenario A's frame RMS (as `bench/imm_design.py`) for the default IMM and for
variants of its CA mode's noise and of a new track's start, beside the plain CA filter.
`a-trace`: per scan of A, the mode probabilities after the update and the RMS of the 30
frames that follow it, for the default and for the mode set before (CA 0.1, start 0.3).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from zenoh_track.clients.evaluation import heldout as held  # noqa: E402
from zenoh_track.clients.feeds import scenarios  # noqa: E402
from zenoh_track.estimation.catalog import FilterSpec  # noqa: E402
from zenoh_track.estimation.imm import ModeSet  # noqa: E402
from zenoh_track.tracking import noise_check  # noqa: E402
from zenoh_track.tracking.batches import Labelled  # noqa: E402
from zenoh_track.tracking.tracker import Tracker, TrackerConfig  # noqa: E402
from zenoh_track.wire import Measurement  # noqa: E402

ADJUST = noise_check.NoiseCheck.adjust


def no_use(self, sensors, batch, *args):  # noqa: ANN001, ANN002, ANN202
    """The noise check reports, the filter uses the stated noise."""
    return batch, np.zeros(0, int), np.zeros((0, 0, 0))


def no_inflation(self, sensors, batch, *args):  # noqa: ANN001, ANN002, ANN202
    """The measured noise used, the tracks' covariances left as they are."""
    out = ADJUST(self, sensors, batch, *args)
    return out[0], np.zeros(0, int), np.zeros((0, 0, 0))


def heldout(spec: FilterSpec, sigma: float, ts: np.ndarray, pos: np.ndarray) -> float:
    tr = Tracker.from_config(TrackerConfig(filter=spec))
    n = len(pos)
    pred = np.full_like(pos, np.nan)
    for k in range(0, len(ts), 2):
        tr.step(Labelled.of([Measurement("feed", f"t{i}", float(ts[k]), 3, False, tuple(pos[i, k]),
                              (sigma,) * 3, (0.0, 0.0, 0.0), None) for i in range(n)]))
        if k + 1 < len(ts):
            snap = tr.snapshot(ts[k + 1], detail=False)
            order = {name: j for j, name in enumerate(snap.ids)}
            pred[:, k + 1] = snap.pos[[order[f"t{i}"] for i in range(n)]]
    first = np.zeros(n)
    return (held.score(pred, pos, ts, first)["rms"]
            / held.score(held.linear(ts, pos), pos, ts, first)["rms"])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("heldout", "a", "a-trace"))
    args = p.parse_args()
    if args.what == "heldout":
        ts, pos, _ = held.generate(50, 1, 0, 120.0)
        print("RMS / linear extrapolation's, 50 aircraft, 120 s, seed 0")
        print(f"{'variant':<34}{'filter':<8}{'sigma 0':>9}{'sigma 1':>9}")
        for label, adjust in (("noise check (the service)", ADJUST),
                              ("measured noise not used", no_use),
                              ("no covariance inflation", no_inflation)):
            noise_check.NoiseCheck.adjust = adjust
            for name in ("imm", "cv", "ca"):
                r = [heldout(FilterSpec(name), s, ts, pos) for s in (0.0, 1.0)]
                print(f"{label:<34}{name:<8}{r[0]:>9.3f}{r[1]:>9.3f}", flush=True)
        noise_check.NoiseCheck.adjust = ADJUST
        return
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import imm_design  # noqa: PLC0415

    if args.what == "a-trace":
        trace(imm_design)
        return

    def a_rms(tr: Tracker) -> float:
        return imm_design.run("display", 1, tr)["frame RMS"]

    print(f"ca (plain CA filter): {a_rms(imm_design.tracker(None, FilterSpec('ca'))):.4f} m")
    tr = imm_design.tracker(None)
    rms, sensor = a_rms(tr), tr.noise.sensors["s"]
    print(f"default IMM as the service builds it: {rms:.4f} m; the noise check: reported "
          f"{tr.noise.status() or 'nothing'}, jitter "
          f"{np.sqrt(np.median(list(sensor.res)) / noise_check.CHI2_1_MEDIAN):.1e} m, "
          f"mean NIS per axis {np.mean(list(sensor.nis)):.2f}")
    before = (0.1, 0.6, 0.3, 0.0)  # a new track's start before the CA mode's 0.6
    for kw in ({}, {"ca_q": 0.1, "initial": before}, {"ca_q": 0.1}, {"initial": before},
               {"ca_q": 0.15}, {"ca_q": 0.3}, {"ca_q": 0.5}, {"initial": (0.1, 0.45, 0.45, 0.0)},
               {"initial": (0.0, 0.0, 1.0, 0.0)}, {"manoeuvre_sojourn": 30.0}):
        print(f"default IMM {kw or ''}: {a_rms(imm_design.tracker(ModeSet(**kw).imm())):.4f} m",
              flush=True)


def trace(imm_design) -> None:  # noqa: ANN001
    """Scenario A scan by scan: mode probabilities and the following second's frame RMS."""
    sets = {"default": ModeSet(), "before": ModeSet(ca_q=0.1, initial=(0.1, 0.6, 0.3, 0.0))}
    trackers = {k: imm_design.tracker(m.imm()) for k, m in sets.items()}
    names = [m[0] for m in sets["default"].imm().modes]
    print(f"{'t':>4}  " + "  ".join(f"{k}: {' '.join(f'{n:>5}' for n in names)}  frames"
                                    for k in sets))
    flight = scenarios.FlightA()
    for t, meas, _ in scenarios.display():
        cols = []
        for tr in trackers.values():
            tr.step(Labelled.of([imm_design.measurement(t, n, m) for n, m in meas]))
            mu = tr.store.layout(3).mode_prob[tr.store.where[meas[0][0]][1]]
            tf = t + np.arange(30) / 30
            e = np.array([tr.snapshot(x, detail=False).pos[0] for x in tf]) - flight.state(tf)[0]
            cols.append(" " * 9 + " ".join(f"{p:5.3f}" for p in mu)
                        + f"  {np.sqrt(np.mean((e ** 2).sum(1))):6.3f}")
        print(f"{t:4.0f}  " + "  ".join(cols), flush=True)


if __name__ == "__main__":
    main()
