"""Why the default IMM is conservative on scenario C's straight legs (docs/accuracy.md,
"The default filter"): three measurements in-process (the service's tracker without Zenoh,
as `bench/imm_design.py`), 20 runs of C unless told.

    python bench/imm_consistency.py phases     # C per phase: the mixture's and each mode's
                                               # NEES, the mode probabilities
    python bench/imm_consistency.py self       # targets drawn from the IMM's own model:
                                               # NEES overall and by the true regime
    python bench/imm_consistency.py tradeoff   # C's straight-leg NEES against the slow
                                               # turn's, over single CVs, the VDF and IMMs
    python bench/imm_consistency.py phases --seed 1
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from imm_design import measurement, tracker, variant  # noqa: E402

from zenoh_track.clients.feeds import scenarios  # noqa: E402
from zenoh_track.estimation import models  # noqa: E402
from zenoh_track.estimation.catalog import FilterSpec  # noqa: E402
from zenoh_track.estimation.imm import IMM, ModeSet  # noqa: E402
from zenoh_track.estimation.imm_jit import CompiledIMM  # noqa: E402
from zenoh_track.tracking.batches import Labelled  # noqa: E402
from zenoh_track.tracking.tracker import Tracker  # noqa: E402

PHASES = scenarios.ManeuverC.phases
ONSET = 378.0  # s: the last scan of C's first straight leg, before the slow turn


def nees(e: np.ndarray, p: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...ij,...j->...", e, np.linalg.inv(p), e)


def collect(tr: Tracker, runs: int, seed: int) -> dict[str, np.ndarray]:
    """Scenario C through `tr`: per scan, the mean over runs of the combined NEES, of each
    IMM mode's own NEES and probability, and the velocity std and error (per axis)."""
    out: dict[str, list] = {"t": [], "nees": [], "mode_nees": [], "mu": [], "vsig": [],
                            "verr": [], "inflow": []}
    for t, meas, truth in scenarios.maneuver(runs=runs, seed=seed):
        tr.step(Labelled.of([measurement(t, n, m) for n, m in meas]))
        a = tr.store.layout(2)
        rows = np.array([tr.store.where[n][1] for n, _ in meas])
        x = np.array([s["pos"][:2] + s["vel"][:2] for _, s in truth])
        e, p = a.x[rows, :4] - x, a.p[rows, :4, :4]
        out["t"].append(t)
        out["nees"].append(nees(e, p).mean())
        out["vsig"].append(np.sqrt(p[:, 2:, 2:].trace(axis1=1, axis2=2).mean() / 2))
        out["verr"].append(np.sqrt((e[:, 2:] ** 2).mean()))
        if hasattr(a, "mode_x"):
            em = a.mode_x[rows, :, :4] - x[:, None]
            out["mode_nees"].append(nees(em, a.mode_p[rows, :, :4, :4]).mean(0))
            out["mu"].append(a.mode_prob[rows].mean(0))
            # velocity variance the next mixing (2 s on) adds to the first (quiet) mode
            imm = tr.updater
            p0 = imm.mix(a.mode_x[rows], a.mode_p[rows], a.mode_prob[rows],
                         imm.transition(np.full(len(rows), 2.0)), 2)[2]
            dv = [p0[:, 0, i, i] - a.mode_p[rows, 0, i, i] for i in (2, 3)]
            out["inflow"].append(np.mean(dv))
    return {k: np.array(v) for k, v in out.items()}


def phase_means(c: dict[str, np.ndarray], key: str) -> list:
    return [c[key][(c["t"] >= max(a, 20)) & (c["t"] < b)].mean(0) for _, a, b in PHASES]


def phases(runs: int, seed: int) -> None:
    """The default IMM per phase of C, beside the same modes that never switch."""
    for label, imm in (("default", ModeSet().imm(CompiledIMM)),
                       ("no switching", variant(sojourn=(1e12, 1e12, 1e12)))):
        c = collect(tracker(imm), runs, seed)
        names = [m[0] for m in imm.modes]
        print(f"{label}: scenario C, {runs} runs, seed {seed}")
        print(f"{'phase':<12}{'NEES':>7}" + "".join(f"{'NEES ' + n:>11}" for n in names)
              + "".join(f"{'mu ' + n:>10}" for n in names) + f"{'vel std':>9}{'vel err':>9}")
        for (name, *_), n, mn, mu, vs, ve in zip(
                PHASES, *(phase_means(c, k) for k in ("nees", "mode_nees", "mu", "vsig",
                                                      "verr")), strict=True):
            print(f"{name:<12}{n:>7.2f}" + "".join(f"{v:>11.2f}" for v in mn)
                  + "".join(f"{v:>10.4f}" for v in mu) + f"{vs:>9.3f}{ve:>9.3f}")
        late = (c["t"] >= 200) & (c["t"] < 380)
        print(f"straight leg, t 200-380 s: NEES {c['nees'][late].mean():.2f}, of the quiet "
              f"mode alone {c['mode_nees'][late, 0].mean():.2f}, mean probabilities "
              + ", ".join(f"{n} {v:.4f}" for n, v in zip(names, c["mu"][late].mean(0),
                                                         strict=True))
              + f";\n  mixing adds {c['inflow'][late].mean():.2e} m^2/s^2 per axis and scan to the "
              f"quiet mode's velocity variance; its own process noise adds "
              f"{models.motion('cv', np.full(1, 2.0), 3, 2, imm.modes[0][2])[1][0, 2, 2]:.1e}\n")


def own_model_targets(imm: IMM, runs: int, seed: int, scans: int = 400, period: float = 2.0,
                      sigma: float = 100.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Targets drawn from the IMM's own model (its Markov chain over 2 s, its modes'
    motion and process noise exactly), positions measured like C (sigma per axis, every
    `period` s). Returns per scan and run: the NEES, the true mode and the time in it."""
    rng = np.random.default_rng(seed)
    dt = np.full(1, period)
    pi = imm.transition(dt)[0]
    moves = [models.motion(kind, dt, 3, 2, q, w) for _, kind, q, w in imm.modes]
    mode = rng.choice(len(imm.modes), runs, p=np.asarray(imm.initial) / sum(imm.initial))
    x = np.zeros((runs, 6))
    x[:, :2], x[:, 2] = 4000.0, -18.0
    since = np.zeros(runs)
    tr, names = tracker(imm), [f"own-{i:03d}" for i in range(runs)]
    out = []
    for k in range(scans + 1):
        if k:
            new = np.minimum((rng.random((runs, 1)) > np.cumsum(pi[mode], 1)).sum(1), len(pi) - 1)
            since = np.where(new == mode, since + period, 0.0)
            mode = new
            for j, (f, q) in enumerate(moves):
                sel = mode == j
                chol = np.linalg.cholesky(q[0] + 1e-12 * np.eye(6))
                x[sel] = x[sel] @ f[0].T + rng.standard_normal((sel.sum(), 6)) @ chol.T
        z = x[:, :2] + sigma * rng.standard_normal((runs, 2))
        tr.step(Labelled.of([measurement(k * period, n, {"pos": z[i].tolist(), "sigma": sigma})
                  for i, n in enumerate(names)]))
        a = tr.store.layout(2)
        rows = np.array([tr.store.where[n][1] for n in names])
        out.append((nees(a.x[rows, :4] - x[:, :4], a.p[rows, :4, :4]), mode, since))
    return tuple(np.array(v)[10:] for v in zip(*out, strict=True))  # from 20 s


def self_consistency(runs: int, seed: int) -> None:
    imm = ModeSet().imm(CompiledIMM)
    n, mode, since = own_model_targets(imm, runs, seed)
    print(f"default IMM on {runs} targets drawn from its own model (2 s, 100 m, 400 scans), "
          f"seed {seed}, t >= 20 s: average NEES {n.mean():.2f} (4-D state: 4 if consistent)")
    for j, (name, *_) in enumerate(imm.modes):
        for lo, hi in ((0, 20), (20, 100), (100, np.inf)):
            sel = (mode == j) & (since >= lo) & (since < hi)
            if sel.sum() >= 100:
                print(f"  truth in mode {name:<6} for {lo:>3}-{hi:<4g} s: NEES {n[sel].mean():6.2f}"
                      f"  ({100 * sel.mean():4.1f} % of the scans)")


def tradeoff(runs: int, seed: int) -> None:
    """C's straight-leg NEES against the slow turn's, with the velocity std (per axis) at
    the slow turn's onset, for filters from the most to the least trusting."""
    rows: list[tuple[str, Callable[[], Tracker]]] = [
        *[(f"cv q={q:g}", lambda q=q: tracker(None, FilterSpec("cv", q)))
          for q in (0.003, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5)],
        ("vdf", lambda: tracker(None, FilterSpec("vdf"))),
        ("imm default (quiet->nominal 600 s)", lambda: tracker(ModeSet().imm(CompiledIMM))),
        *[(f"imm quiet->nominal {s:g} s", lambda s=s: tracker(variant(sojourn=(s, 600.0, 10.0))))
          for s in (300.0, 1200.0, 3000.0, 20000.0)],
        *[(f"imm start quiet {s:g}", lambda s=s: tracker(variant(initial=(s, 1 - s, 0.0))))
          for s in (0.5, 1.0)],
    ]
    print(f"scenario C, {runs} runs, seed {seed}; NEES 95 % interval [2.86, 5.33]; vel std and "
          f"error per axis at t = {ONSET:g} s")
    print(f"{'filter':<36}{'straight':>9}{'slow turn':>11}{'fast turn':>11}{'straight-2':>11}"
          f"{'vel std':>9}{'vel err':>9}")
    for name, make in rows:
        c = collect(make(), runs, seed)
        k = int(np.searchsorted(c["t"], ONSET))
        print(f"{name:<36}" + "".join(f"{v:>{11 if i else 9}.{2 if v < 1e3 else 0}f}"
                                      for i, v in enumerate(phase_means(c, "nees")))
              + f"{c['vsig'][k]:>9.3f}{c['verr'][k]:>9.3f}", flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("phases", "self", "tradeoff"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--runs", type=int, help="20 (C) or 200 (self)")
    args = p.parse_args()
    if args.what == "self":
        self_consistency(args.runs or 200, args.seed)
    else:
        {"phases": phases, "tradeoff": tradeoff}[args.what](args.runs or 20, args.seed)


if __name__ == "__main__":
    main()
