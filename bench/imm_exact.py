"""C's straight legs: is the default IMM conservative on scenario C because of the
IMM (its mixing, R, initiation), or because of the model it approximates? In-process (the
service's tracker without Zenoh, as `bench/imm_design.py`), 20 runs of C unless told.

    python bench/imm_exact.py leak     # C's first straight leg per 40-s window: the quiet
                                       # mode alone, inside an IMM, without switching; what
                                       # mixing pours into the quiet mode, by source
    python bench/imm_exact.py exact    # each phase of C: the IMM against the exact posterior
                                       # of its own model (a particle filter), the VDF
    python bench/imm_exact.py sweep    # the exact posterior's straight leg against its slow
                                       # turn, over how often the model lets a quiet target
                                       # start to manoeuvre
    python bench/imm_exact.py exact --particles 5000 --particle-seed 2

The exact posterior of an IMM's model (its Markov chain over the modes, each mode's linear
motion and process noise exactly as the IMM predicts them, a CV mode's acceleration zero,
the tracker's one-point initiation) is computed by a Rao-Blackwellised particle filter
over the mode sequences: a Kalman filter per particle, so only the sequence is sampled
(Doucet, Gordon & Krishnamurthy, IEEE TSP 49(3), 2001, for jump Markov linear systems).
Switches are proposed more often than the chain makes them (`EPS`) and importance-weighted
back, so rare switches are represented; systematic resampling below half the particles.
Its estimate and covariance are the moments of the whole mixture, as the IMM reports.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from imm_consistency import nees  # noqa: E402
from imm_design import measurement, tracker  # noqa: E402

from zenoh_track import defaults  # noqa: E402
from zenoh_track.clients.evaluation import metrics  # noqa: E402
from zenoh_track.clients.feeds import scenarios  # noqa: E402
from zenoh_track.estimation import models  # noqa: E402
from zenoh_track.estimation.catalog import FilterSpec  # noqa: E402
from zenoh_track.estimation.imm import IMM, ModeSet  # noqa: E402
from zenoh_track.tracking.batches import Labelled  # noqa: E402

C = scenarios.ManeuverC
EPS = 0.2  # share of the proposal spread evenly over the modes
QUIET = ("quiet", "cv", defaults.IMM_QUIET_Q, 0.0)
CA = ("ca", "ca", defaults.IMM_CA_Q, 0.0)
NO_NOMINAL = IMM((QUIET, CA), (3000.0, 10.0), initial=(0.7, 0.3))  # imm_design's no-nominal


def exact(imm: IMM, runs: int, seed: int, particles: int, pseed: int = 1,
          until: float = C.duration) -> dict[str, np.ndarray]:
    """The exact posterior of `imm`'s model on C (`runs`, `seed`): per scan, its mean NEES
    of the 4-D state, squared position error, velocity variance and squared error per
    axis, first mode's probability and effective sample size (means over runs)."""
    rng = np.random.default_rng(pseed)
    m, dt, var = len(imm.modes), np.full(1, C.period), C.sigma ** 2
    f = np.stack([models.motion(kind, dt, 3, 1, q)[0][0] for _, kind, q, _ in imm.modes])
    qm = np.stack([models.motion(kind, dt, 3, 1, q)[1][0] for _, kind, q, _ in imm.modes])
    pi = imm.transition(dt)[0]
    prop = (1 - EPS) * pi + EPS / m
    with np.errstate(divide="ignore"):  # a forbidden switch: weight -inf, never kept
        log_ratio = np.log(pi) - np.log(prop)
    init = np.asarray(imm.initial, float) / sum(imm.initial)
    out: dict[str, list] = {k: [] for k in ("t", "nees", "pos_sq", "vvar", "vsq", "mu0",
                                            "ess")}
    for k, (t, meas, truth) in enumerate(scenarios.maneuver(runs=runs, seed=seed)):
        if t > until:
            break
        z = np.array([mm["pos"] for _, mm in meas])[:, None, :]  # (runs, 1, axis)
        if k == 0:  # the tracker's one-point initiation, per axis (pos, vel, acc)
            x = np.zeros((runs, particles, 2, 3))
            x[..., 0] = z
            p = np.zeros((runs, particles, 2, 3, 3))
            p[..., 0, 0], p[..., 1, 1] = var, defaults.INIT_SPEED ** 2
            p[..., 2, 2] = defaults.INIT_ACCEL ** 2
            mode = rng.choice(m, (runs, particles), p=init)
            logw = np.zeros((runs, particles))
        else:
            new = (rng.random((runs, particles, 1)) > np.cumsum(prop[mode], -1)).sum(-1)
            new = np.minimum(new, m - 1)
            logw += log_ratio[mode, new]
            mode = new
            fm = f[mode][:, :, None]  # (runs, particles, 1, 3, 3): both axes alike
            x = np.einsum("rpaij,rpaj->rpai", fm, x)
            p = fm @ p @ np.swapaxes(fm, -1, -2) + qm[mode][:, :, None]
            s = p[..., 0, 0] + var
            nu = z - x[..., 0]
            logw += (-0.5 * (nu ** 2 / s + np.log(2 * np.pi * s))).sum(-1)
            gain = p[..., :, 0] / s[..., None]
            x = x + gain * nu[..., None]
            p = p - gain[..., :, None] * p[..., 0, None, :]
        w = np.exp(logw - logw.max(1, keepdims=True))
        w /= w.sum(1, keepdims=True)
        xs = np.concatenate([x[..., 0], x[..., 1]], -1)  # (runs, particles, 4): pos, vel
        ps = np.zeros(xs.shape + (4,))
        for a in range(2):  # axis a, derivatives i, j -> entry (i * 2 + a, j * 2 + a)
            ps[..., a::2, a::2] = p[..., a, :2, :2]
        mean = np.einsum("rp,rpi->ri", w, xs)
        d = xs - mean[:, None]
        cov = np.einsum("rp,rpij->rij", w, ps + d[..., :, None] * d[..., None, :])
        e = mean - np.array([s["pos"][:2] + s["vel"][:2] for _, s in truth])
        ess = 1.0 / (w ** 2).sum(1)
        for key, v in (("t", t), ("nees", nees(e, cov).mean()),
                       ("pos_sq", (e[:, :2] ** 2).sum(1).mean()),
                       ("vvar", cov[:, 2, 2].mean()), ("vsq", (e[:, 2] ** 2).mean()),
                       ("mu0", (w * (mode == 0)).sum(1).mean()), ("ess", ess.mean())):
            out[key].append(v)
        for r in np.flatnonzero(ess < particles / 2):  # systematic resampling
            idx = np.searchsorted(np.cumsum(w[r]), (rng.random() + np.arange(particles))
                                  / particles)
            idx = np.minimum(idx, particles - 1)
            x[r], p[r], mode[r], logw[r] = x[r, idx], p[r, idx], mode[r, idx], 0.0
    return {k: np.array(v) for k, v in out.items()}


def filtered(tr: object, runs: int, seed: int, until: float = C.duration
             ) -> dict[str, np.ndarray]:
    """The same figures for the service's tracker `tr`, with each IMM mode's NEES,
    velocity variance and probability, and what the next mixing pours into the first
    (quiet) mode's velocity variance from every mode: w_i0 P_i and w_i0 (v_i - v_0)^2,
    per axis (w_i0 = pi_i0 mu_i / c_0, Bar-Shalom, Li & Kirubarajan 2001, sec. 11.6.6)."""
    out: dict[str, list] = {k: [] for k in ("t", "nees", "pos_sq", "vvar", "vsq", "mode_nees",
                                            "mode_vvar", "mu", "in_cov", "in_spread")}
    for t, meas, truth in scenarios.maneuver(runs=runs, seed=seed):
        if t > until:
            break
        tr.step(Labelled.of([measurement(t, n, mm) for n, mm in meas]))
        a = tr.store.layout(2)
        rows = np.array([tr.store.where[n][1] for n, _ in meas])
        x = np.array([s["pos"][:2] + s["vel"][:2] for _, s in truth])
        e, p = a.x[rows, :4] - x, a.p[rows, :4, :4]
        for key, v in (("t", t), ("nees", nees(e, p).mean()),
                       ("pos_sq", (e[:, :2] ** 2).sum(1).mean()),
                       ("vvar", p[:, 2, 2].mean()), ("vsq", (e[:, 2] ** 2).mean())):
            out[key].append(v)
        if hasattr(a, "mode_x"):
            mx, mp, mu = a.mode_x[rows], a.mode_p[rows], a.mode_prob[rows]
            out["mode_nees"].append(nees(mx[:, :, :4] - x[:, None], mp[:, :, :4, :4]).mean(0))
            out["mode_vvar"].append(mp[:, :, 2, 2].mean(0))
            out["mu"].append(mu.mean(0))
            pi = tr.updater.transition(np.full(len(rows), C.period))
            w = pi[:, :, 0] * mu / (pi[:, :, 0] * mu).sum(1, keepdims=True)  # w_i0
            out["in_cov"].append((w * mp[:, :, 2, 2]).mean(0))
            out["in_spread"].append((w * (mx[:, :, 2] - mx[:, :1, 2]) ** 2).mean(0))
    return {k: np.array(v) for k, v in out.items()}


def window(c: dict[str, np.ndarray], key: str, lo: float, hi: float) -> np.ndarray:
    sel = (c["t"] >= lo) & (c["t"] < hi)
    return c[key][sel].mean(0)


def leak(runs: int, seed: int) -> None:
    """Hypotheses 1-4 of C's straight leg, per 40-s window of C's first leg."""
    edges = np.arange(20.0, 381.0, 40.0)
    never = IMM((QUIET, CA), (1e12, 1e12), initial=(0.7, 0.3))
    rows: list[tuple[str, IMM | None, Callable[[], dict[str, np.ndarray]]]] = [
        ("cv q=0.003 alone", None, lambda: filtered(
            tracker(None, FilterSpec("cv", defaults.IMM_QUIET_Q)), runs, seed, 380.0)),
        ("quiet as a 1-mode IMM", None, lambda: filtered(
            tracker(IMM((QUIET,), (600.0,), initial=(1.0,))), runs, seed, 380.0)),
        ("exact posterior, never switching", None,  # the particle filter's own check
         lambda: exact(never, runs, seed, 50, until=380.0)),
        ("vdf", None, lambda: filtered(tracker(None, FilterSpec("vdf")), runs, seed, 380.0)),
        ("no-nominal IMM", NO_NOMINAL, lambda: filtered(tracker(NO_NOMINAL), runs, seed, 380.0)),
        ("no-nominal, never switching", never, lambda: filtered(tracker(never), runs, seed,
                                                                380.0)),
        ("default IMM", ModeSet().imm(), lambda: filtered(tracker(ModeSet().imm()), runs, seed,
                                                          380.0))]
    print(f"scenario C, {runs} runs, seed {seed}: the first straight leg per window of 40 s "
          f"(from {edges[0]:g} s); velocity variance P_vx and squared error e_vx^2 in m^2/s^2")
    spans = list(zip(edges[:-1], edges[1:], strict=True))
    print(f"{'':<34}" + "".join(f"{f'{a:g}-{b:g}':>9}" for a, b in spans))
    for name, imm, run in rows:
        c = run()
        lines = [("NEES", "nees", None), ("P_vx", "vvar", None), ("e_vx^2", "vsq", None)]
        if imm is not None:
            lines += [("quiet mode's NEES", "mode_nees", 0), ("quiet mode's P_vx", "mode_vvar", 0)]
        print(name)
        for label, key, j in lines:
            vals = [window(c, key, a, b) for a, b in spans]
            vals = [v if j is None else v[j] for v in vals]
            nd = 2 if "NEES" in label else 4
            print(f"  {label:<32}" + "".join(f"{v:>9.{nd}f}" if v < 10 else f"{v:>9.2f}"
                                             for v in vals))
        if imm is not None:
            names = [md[0] for md in imm.modes]
            mu, cov, spread, vv = (window(c, k, 200.0, 380.0)
                                   for k in ("mu", "in_cov", "in_spread", "mode_vvar"))
            print("  t 200-380 s: " + ", ".join(
                f"{n} mu {u:.4f} P_vx {v:.3g}" for n, u, v in zip(names, mu, vv, strict=True)))
            print("  the next mixing gives the quiet mode, per axis and scan: " + ", ".join(
                f"from {n} {a:.2e} (its P) + {b:.2e} (spread)"
                for n, a, b in zip(names[1:], cov[1:], spread[1:], strict=True))
                  + f"; its own process noise adds "
                    f"{models.process_noise(np.full(1, C.period), 2, 1, QUIET[2])[0, 1, 1]:.1e}")


def phase_row(name: str, c: dict[str, np.ndarray]) -> str:
    vals = []
    for _, a, b in C.phases:
        sel = (c["t"] >= max(a, 20)) & (c["t"] < b)
        vals.append(f"{np.sqrt(c['pos_sq'][sel].mean()):>7.1f} {c['nees'][sel].mean():>7.2f}")
    return f"{name:<34}" + "".join(f"{v:>17}" for v in vals)


def compare(runs: int, seed: int, particles: int, pseed: int) -> None:
    """Each phase of C: the IMM and the exact posterior of its model, and the VDF."""
    lo, hi = metrics.chi2_interval(4, runs)
    print(f"scenario C, {runs} runs, seed {seed}; exact: {particles} particles, seed {pseed}; "
          f"position RMSE (m) and NEES (95 % interval [{lo:.2f}, {hi:.2f}]) per phase")
    print(f"{'filter':<34}" + "".join(f"{name:>17}" for name, *_ in C.phases))
    for label, imm in (("default IMM", ModeSet().imm()), ("no-nominal IMM", NO_NOMINAL)):
        t0 = time.monotonic()
        print(phase_row(label, filtered(tracker(imm), runs, seed)), flush=True)
        c = exact(imm, runs, seed, particles, pseed)
        print(phase_row("  exact posterior of its model", c)
              + f"  (ESS {c['ess'].mean():.0f}, {time.monotonic() - t0:.0f} s)", flush=True)
    print(phase_row("vdf", filtered(tracker(None, FilterSpec("vdf")), runs, seed)))


def sweep(runs: int, seed: int, particles: int, pseed: int) -> None:
    """The exact posterior of the default's model with the quiet mode left less often."""
    lo, hi = metrics.chi2_interval(4, runs)
    print(f"scenario C, {runs} runs, seed {seed}: the exact posterior of the default model "
          f"with the quiet mode's sojourn changed ({particles} particles); NEES interval "
          f"[{lo:.2f}, {hi:.2f}]")
    print(f"{'quiet sojourn, s':<18}{'straight':>9}{'slow turn':>11}{'fast turn':>11}"
          f"{'straight-2':>11}{'IMM straight':>14}{'IMM slow':>10}")
    base = ModeSet().imm()
    for tau in (600.0, 3000.0, 20000.0, 1e6):
        imm = IMM(base.modes, (tau, *base.sojourn[1:]), base.leave, base.initial)
        c, f = exact(imm, runs, seed, particles, pseed), filtered(tracker(imm), runs, seed)
        ph = [[cc["nees"][(cc["t"] >= max(a, 20)) & (cc["t"] < b)].mean()
               for _, a, b in C.phases] for cc in (c, f)]
        print(f"{tau:<18g}" + "".join(f"{v:>{11 if i else 9}.2f}" for i, v in
                                      enumerate(ph[0])) + f"{ph[1][0]:>14.2f}{ph[1][1]:>10.2f}",
              flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("leak", "exact", "sweep"))
    p.add_argument("--runs", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--particles", type=int, default=2000)
    p.add_argument("--particle-seed", type=int, default=1)
    args = p.parse_args()
    if args.what == "leak":
        leak(args.runs, args.seed)
    elif args.what == "exact":
        compare(args.runs, args.seed, args.particles, args.particle_seed)
    else:
        sweep(args.runs, args.seed, args.particles, args.particle_seed)


if __name__ == "__main__":
    main()
