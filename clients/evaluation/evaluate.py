"""`track-eval SCENARIO`: measure the service's accuracy and consistency over Zenoh.

Runs a reference scenario through a real service on loopback (lockstep clock; each
Monte Carlo run is a separate target, so all runs go through at once), collects
`tracks/*` and `frame` against the scenario's truth, and prints position and velocity
RMSE per window or phase, the posterior Cramér-Rao bound and the ratio to it, average
NEES and NIS with their 95 % chi-square intervals, and for display frames the RMS and
maximum error and the largest visual jump. The unlabelled-scan scenarios `crossing` and
`multisensor` are evaluated with GOSPA by clients/evaluation/unlabelled.py.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
from typing import Any

import numpy as np

from zenoh_track.clients.evaluation import (
    heldout,
    manoeuvres,
    metrics,
    reference,
    unlabelled,
)
from zenoh_track.clients.evaluation.collect import Collected, run_through_service
from zenoh_track.clients.evaluation.progress import add_quiet_arg, bar
from zenoh_track.clients.feeds import scenarios
from zenoh_track.clients.intercept.intercept_report import summary_line
from zenoh_track.wire import add_version, need, on_signals

START = {"display": 3.0, "radar3d": 20.0, "maneuver": 20.0}  # s: after initiation
# service options per scenario: scenario C's target has no process noise, only two
# turns, so the filters' white-noise level is set low (CV/CT acceleration, CA jerk)
SERVICE_ARGS = {"display": [], "radar3d": [], "maneuver": ["--q", "0.003"]}


# ---------------------------------------------------------------- truth
def truth_arrays(scenario: str, runs: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Scan times (K,) and true [pos(3), vel(3)] (runs, K, 6)."""
    ts, states = [], []
    for t, _, truth in scenarios.SCENARIOS[scenario](runs=runs, seed=seed):
        ts.append(t)
        states.append([(tr["pos"] + [0.0] * (3 - len(tr["pos"])))
                       + (tr["vel"] + [0.0] * (3 - len(tr["vel"]))) for _, tr in truth])
    return np.array(ts), np.array(states).transpose(1, 0, 2)


@functools.cache
def flight_a() -> scenarios.FlightA:
    return scenarios.FlightA()


def truth_at(scenario: str, ts: np.ndarray, states: np.ndarray, t: float) -> np.ndarray:
    """True positions (runs, 3) at any instant: scenario A from its flight model, B and C
    exactly by their piecewise-constant accelerations between scans."""
    if scenario == "display":
        return np.repeat(flight_a().state(t)[0], states.shape[0], axis=0)
    pos, vel = states[..., :3].swapaxes(0, 1), states[..., 3:].swapaxes(0, 1)  # (K, runs, 3)
    acc = np.zeros_like(vel)
    acc[:-1] = np.diff(vel, axis=0) / np.diff(ts)[:, None, None]
    return scenarios.interpolate(ts, pos, vel, acc, t)[0][0]


# ---------------------------------------------------------------- evaluation
def windows(scenario: str, ts: np.ndarray) -> list[tuple[str, float, float]]:
    """Report windows (name, t0, t1): 20-scan windows for B, the phases for A and C."""
    if scenario == "radar3d":
        return [(f"{a}-{a + 19}", ts[a], ts[a + 19] + 1e-9) for a in range(20, len(ts), 20)]
    phases = scenarios.FlightA.phases if scenario == "display" else scenarios.ManeuverC.phases
    return [(n, max(a, START[scenario]), b) for n, a, b in phases]


def evaluate(scenario: str, runs: int, seed: int, got: Collected) -> dict[str, Any]:
    ts, truth = truth_arrays(scenario, runs, seed)
    dim = 2 if scenario == "maneuver" else 3
    n = 2 * dim
    ids = sorted({tid for tid, _ in got.tracks})
    est = np.full((runs, len(ts), n), np.nan)
    cov = np.full((runs, len(ts), n, n), np.nan)
    nis = np.full((runs, len(ts)), np.nan)
    manoeuvre = np.full((runs, len(ts)), np.nan)  # 1 - P(cv), or 1 when a VDF is in CA
    for i, tid in enumerate(ids):
        for k, t in enumerate(ts):
            m = got.tracks.get((tid, round(float(t), 6)))
            if m is None:
                continue
            size = len(m["x"])
            est[i, k] = m["x"][:n]
            cov[i, k] = np.reshape(m["P"], (size, size))[:n, :n]
            nis[i, k] = m["nis"]
            model = m["model"]
            manoeuvre[i, k] = (1.0 - model.get("cv", 0.0)) if isinstance(model, dict) \
                else float(model != "cv")
    tru = np.concatenate([truth[..., :dim], truth[..., 3:3 + dim]], -1)
    err = est - tru
    sq_pos, sq_vel = (err[..., :dim] ** 2).sum(-1), (err[..., dim:] ** 2).sum(-1)
    ok = np.isfinite(cov).all((2, 3))
    nees = np.full((runs, len(ts)), np.nan)
    # pseudo-inverse: exact measurements (scenario A) leave P singular in position
    nees[ok] = np.einsum("ni,nij,nj->n", err[ok], np.linalg.pinv(cov[ok], hermitian=True),
                         err[ok])
    bound_p = bound_v = None
    if scenario == "radar3d":
        bound_p, bound_v = metrics.scenario_b_bound(runs, seed)
    lo, hi = metrics.chi2_interval(n, runs)
    nis_lo, nis_hi = metrics.chi2_interval(dim, runs)

    def row(name: str, t0: float, t1: float) -> dict[str, Any]:
        sel = (ts >= t0) & (ts < t1)
        r = {"window": name, "t0": float(t0), "t1": float(t1),
             "pos_rmse": float(np.sqrt(np.nanmean(sq_pos[:, sel]))),
             "vel_rmse": float(np.sqrt(np.nanmean(sq_vel[:, sel]))),
             "pos_peak": float(np.nanmax(np.sqrt(np.nanmean(sq_pos[:, sel], axis=0)))),
             "nees": float(np.nanmean(nees[:, sel])),
             "nees_max_scan": float(np.nanmax(np.nanmean(nees[:, sel], axis=0))),
             "nis": float(np.nanmean(nis[:, sel])),
             "manoeuvre": float(np.nanmean(manoeuvre[:, sel])),
             "manoeuvre_detected": float(np.mean(np.nanmax(manoeuvre[:, sel], axis=1) > 0.5))}
        if bound_p is not None:
            r["pos_bound"] = float(np.sqrt(np.mean(bound_p[sel] ** 2)))
            r["vel_bound"] = float(np.sqrt(np.mean(bound_v[sel] ** 2)))
            r["pos_ratio"] = r["pos_rmse"] / r["pos_bound"]
            r["vel_ratio"] = r["vel_rmse"] / r["vel_bound"]
        return r

    start = START[scenario]
    report = {
        "scenario": scenario, "runs": runs, "seed": seed, "state_dim": n,
        "tracks_missing": int(runs * len(ts) - len(got.tracks)),
        "nees_interval": [lo, hi], "nis_interval": [nis_lo, nis_hi],
        "overall": row(f"t {start:g}-{ts[-1]:g}", start, ts[-1] + 1e-9),
        "windows": [row(*w) for w in windows(scenario, ts)],
        "per_scan": {"t": ts.tolist(),
                     "pos_rmse": np.sqrt(np.nanmean(sq_pos, axis=0)).tolist(),
                     "nees": np.nanmean(nees, axis=0).tolist(),
                     "manoeuvre": np.nanmean(manoeuvre, axis=0).tolist(),
                     "pos_bound": None if bound_p is None else bound_p.tolist()},
        "display": display_quality(scenario, ts, truth, got, start, windows(scenario, ts)),
    }
    # per window, each run's mean squared position error (Monte Carlo intervals)
    report["per_run"] = {r["window"]: np.nanmean(
        sq_pos[:, (ts >= r["t0"]) & (ts < r["t1"])], axis=1).tolist()
        for r in [*report["windows"], report["overall"]]}
    return report


def display_quality(scenario: str, ts: np.ndarray, truth: np.ndarray, got: Collected,
                    start: float, wins: list[tuple[str, float, float]]) -> dict[str, Any]:
    """Per-frame error against truth at the frame instant, and the visual jump: the
    frame-to-frame displacement beyond the true displacement. Overall and per window."""
    frames = sorted((f for f in got.frames if f[0] >= start), key=lambda f: f[0])
    t_f, err, jump = [], [], []
    prev: tuple[np.ndarray, dict] | None = None
    for t, tracks in frames:
        true = truth_at(scenario, ts, truth, t)
        shown = {int(tr["id"].rsplit("-", 1)[1]): np.array(tr["pos"]) for tr in tracks}
        e = [np.linalg.norm(p - true[i]) for i, p in shown.items()]
        j = [np.linalg.norm((p - prev[1][i]) - (true[i] - prev[0][i]))
             for i, p in shown.items() if prev is not None and i in prev[1]]
        t_f.append(t)
        err.append(e)
        jump.append(j)
        prev = (true, shown)

    def summary(t0: float, t1: float) -> dict[str, Any]:
        sel = [i for i, t in enumerate(t_f) if t0 <= t < t1]
        e = np.concatenate([np.asarray(err[i], float) for i in sel]) if sel else np.zeros(0)
        j = np.concatenate([np.asarray(jump[i], float) for i in sel]) if sel else np.zeros(0)
        return {"frames": len(sel), "rms": float(np.sqrt(np.mean(e**2))) if e.size else None,
                "max": float(e.max()) if e.size else None,
                "max_jump": float(j.max()) if j.size else None}

    out = summary(start, ts[-1] + 1e-9)  # frames after the last scan have no truth for A
    out["windows"] = [{"window": n, **summary(a, b)} for n, a, b in wins]
    out["per_frame"] = {"t": t_f, "rms": [float(np.sqrt(np.mean(np.square(e)))) if e else None
                                          for e in err]}
    return out


# ---------------------------------------------------------------- output
def comparison(reports: dict[str, dict[str, Any]]) -> str:
    """Position RMSE (and the peak of the per-scan RMSE) per window, filters side by side."""
    names = list(reports)
    lines = ["position RMSE / peak per-scan RMSE, m",
             f"{'window':<16}" + "".join(f"{n:>20}" for n in names)]
    first = reports[names[0]]
    for i, w in enumerate([*first["windows"], first["overall"]]):
        cells = []
        for n in names:
            r = [*reports[n]["windows"], reports[n]["overall"]][i]
            cells.append(f"{r['pos_rmse']:>11.1f} / {r['pos_peak']:<6.1f}")
        lines.append(f"{w['window']:<16}" + "".join(f"{c:>20}" for c in cells))
    return "\n".join(lines)


def table(report: dict[str, Any], label: str) -> str:
    lo, hi = report["nees_interval"]
    has_bound = "pos_bound" in report["overall"]
    head = f"{'window':<16}{'pos RMSE':>10}{'vel RMSE':>10}"
    if has_bound:
        head += f"{'pos CRB':>9}{'ratio':>7}{'vel CRB':>9}{'ratio':>7}"
    head += f"{'NEES':>8}{'max/scan':>10}{'NIS':>7}"
    lines = [f"{report['scenario']} / {label}: {report['runs']} runs, seed {report['seed']}; "
             f"NEES of the {report['state_dim']}-D state, 95 % interval [{lo:.2f}, {hi:.2f}]"
             + (f"; {report['tracks_missing']} tracks/ messages MISSING"
                if report["tracks_missing"] else ""),
             head]
    for r in [*report["windows"], report["overall"]]:
        s = f"{r['window']:<16}{r['pos_rmse']:>10.2f}{r['vel_rmse']:>10.3f}"
        if has_bound:
            s += (f"{r['pos_bound']:>9.2f}{r['pos_ratio']:>7.3f}{r['vel_bound']:>9.3f}"
                  f"{r['vel_ratio']:>7.3f}")
        s += f"{r['nees']:>8.2f}{r['nees_max_scan']:>10.2f}{r['nis']:>7.2f}"
        lines.append(s)
    d = report["display"]
    if d["rms"] is not None:
        lines.append(f"display frames ({d['frames']} instants): error RMS / max, largest "
                     "jump beyond the true motion, m")
        for w in [*d["windows"], {"window": "all", **d}]:
            if w["rms"] is not None:
                lines.append(f"  {w['window']:<14}{w['rms']:>9.3f}{w['max']:>9.3f}"
                             f"{w['max_jump'] or 0.0:>9.3f}")
    return "\n".join(lines)


def plot(reports: dict[str, dict[str, Any]], got: dict[str, Collected], outdir: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(outdir, exist_ok=True)
    first = next(iter(reports.values()))
    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for label, rep in reports.items():
        ps = rep["per_scan"]
        ax[0].plot(ps["t"], ps["pos_rmse"], label=f"{label} RMSE")
        ax[1].plot(ps["t"], ps["nees"], label=label)
    if first["per_scan"]["pos_bound"] is not None:
        ax[0].plot(first["per_scan"]["t"], first["per_scan"]["pos_bound"], "k--", label="PCRB")
    lo, hi = first["nees_interval"]
    ax[1].axhspan(lo, hi, color="0.85", label="95 % interval")
    ax[0].set_ylabel("position RMSE, m")
    ax[1].set_ylabel("average NEES")
    ax[1].set_yscale("log")
    ax[1].set_xlabel("t, s")
    ax[0].legend()
    ax[1].legend()
    fig.suptitle(f"{first['scenario']}: {first['runs']} runs")
    fig.savefig(os.path.join(outdir, f"{first['scenario']}_errors.png"), dpi=120)
    plt.close(fig)
    label, col = next(iter(got.items()))
    sc = first["scenario"]
    ts, truth = truth_arrays(sc, first["runs"], first["seed"])
    run0 = sorted({tid for tid, _ in col.tracks})[0]
    fr = [(t, next((x for x in trs if x["id"] == run0), None)) for t, trs in col.frames]
    fr = [(t, x) for t, x in fr if x is not None]
    fig, ax = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for i, name in enumerate(("East", "North", "Up")):
        ax[i].plot([t for t, _ in fr], [x["pos"][i] for _, x in fr], label=f"{label} 30 Hz")
        ax[i].plot(ts, truth[0, :, i], "k.", ms=2, label="truth at scans")
        ax[i].set_ylabel(f"{name}, m")
    ax[0].legend()
    ax[2].set_xlabel("t, s")
    fig.suptitle(f"{sc}: track {run0} against truth")
    fig.savefig(os.path.join(outdir, f"{sc}_track.png"), dpi=120)
    plt.close(fig)


def plot_display(collected: dict[str, Collected], outdir: str,
                 spans: tuple[tuple[float, float], ...] = ((4.5, 8.5), (17.5, 33.5))) -> None:
    """Scenario A: drawn position minus truth (East, North, Up) around the end of the first
    acceleration and through the turn, one curve per display variant."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(outdir, exist_ok=True)
    flight = flight_a()
    fig, ax = plt.subplots(3, len(spans), figsize=(10, 7), sharex="col")
    for label, col in collected.items():
        fr = sorted((t, trs[0]["pos"]) for t, trs in col.frames if trs)
        t = np.array([f[0] for f in fr])
        err = np.array([f[1] for f in fr]) - flight.state(t)[0]
        for j, (a, b) in enumerate(spans):
            sel = (t >= a) & (t <= b)
            for i in range(3):
                ax[i, j].plot(t[sel], err[sel, i], ".-", ms=2, lw=0.8, label=label)
    for i, name in enumerate(("East", "North", "Up")):
        ax[i, 0].set_ylabel(f"{name} error, m")
    for j in range(len(spans)):
        ax[2, j].set_xlabel("t, s")
    ax[0, 0].legend()
    fig.suptitle("scenario A: 30 Hz frames minus truth (scans every 1 s)")
    fig.savefig(os.path.join(outdir, "display_frames.png"), dpi=100)
    plt.close(fig)


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-eval", description=__doc__)
    p.add_argument("scenario", choices=[*sorted(scenarios.SCENARIOS), *unlabelled.SCENARIOS,
                                        "defaults", "heldout", "manoeuvres"],
                   help="crossing, multisensor: unlabelled scans and GOSPA "
                        "(clients/evaluation/unlabelled.py); defaults: A, B and C with the "
                        "service's defaults beside the best filter of each "
                        "(clients/evaluation/reference.py); heldout: every other "
                        "position of a "
                        "1 Hz feed sent, the frame scored at the others "
                        "(clients/evaluation/heldout.py); manoeuvres: track breaks, "
                        "held and RMSE/NEES per class of manoeuvre (its own options: "
                        "track-eval manoeuvres -h)")
    p.add_argument("--runs", type=int, default=None,
                   help="Monte Carlo runs (default 100; crossing, multisensor: 10)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--runs-c", type=int, default=20,
                   help="defaults: Monte Carlo runs of scenario C (--runs: of B, default 100)")
    p.add_argument("--filter", action="append", default=[],
                   help="service filter(s) to compare (repeatable; default cv, ca for display, "
                        "the service's for crossing and multisensor)")
    p.add_argument("--service-arg", action="append", default=[],
                   help="extra argument passed to every service (repeatable)")
    p.add_argument("-e", "--connect", default=None,
                   help="use a running lockstep service at this endpoint instead")
    p.add_argument("--ns", default=None, help="namespace of that running service")
    p.add_argument("--intercept", action="append", default=[],
                   choices=("pure", "pn", "intercept"),
                   help="also fly interceptors with this guidance (repeatable; scenario C)")
    p.add_argument("--display-variants", action="store_true",
                   help="scenario A: compare plain prediction, --blend 0.35, --blend-speed "
                        "2.4 and --lag 1 (with the first --filter) and plot the frames "
                        "around corrections")
    p.add_argument("--json", action="store_true", help="print the reports as JSON")
    p.add_argument("--plot", metavar="DIR", help="write PNG figures here")
    unlabelled.add_args(p)
    heldout.add_args(p)
    add_quiet_arg(p)
    add_version(p)
    return p


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["manoeuvres"]:  # its own options (clients/evaluation/manoeuvres.py)
        manoeuvres.main(argv[1:])
        return
    args = parser().parse_args(argv)
    on_signals(interrupt=True)
    if args.plot:
        need("matplotlib", "plot", "track-eval --plot")
    if args.scenario in unlabelled.SCENARIOS:
        return unlabelled.run(args)
    if args.scenario == "defaults":
        return reference.run(args)
    if args.scenario == "heldout":
        heldout.run(args)
        return None
    args.runs = 100 if args.runs is None else args.runs
    filters = args.filter or (["ca"] if args.scenario == "display" else ["cv"])
    reports, collected = {}, {}
    progress = bar(total=4 * args.display_variants + (not args.display_variants) * len(filters),
                   desc="service runs", unit=" run", quiet=args.quiet)
    if args.display_variants:
        variants = {"prediction": [], "blend 0.35 s": ["--blend", "0.35"],
                    "blend 2.4 m/s": ["--blend-speed", "2.4"], "lag 1 s": ["--lag", "1"]}
        for label, extra in variants.items():
            collected[label] = run_through_service(
                args.scenario, args.runs, args.seed,
                ["--filter", filters[0], "--no-display-keys", *extra], args.connect, args.ns)
            reports[label] = evaluate(args.scenario, args.runs, args.seed, collected[label])
            reports[label]["interception"] = {}
            progress.update(1)
        filters = []
        if args.plot:
            plot_display(collected, args.plot)
    for name in filters:
        display_keys = [] if args.intercept else ["--no-display-keys"]
        got = run_through_service(args.scenario, args.runs, args.seed,
                                  ["--filter", name, *display_keys,
                                   *SERVICE_ARGS[args.scenario], *args.service_arg],
                                  args.connect, args.ns, args.intercept)
        collected[name] = got
        reports[name] = evaluate(args.scenario, args.runs, args.seed, got)
        reports[name]["interception"] = got.interception
        progress.update(1)
    progress.close()
    if args.json:
        print(json.dumps({k: {kk: vv for kk, vv in v.items() if kk not in ("per_scan", "per_run")}
                          for k, v in reports.items()}, indent=1))
    else:
        print("\n\n".join(table(r, k) for k, r in reports.items()))
        if len(reports) > 1:
            print("\n" + comparison(reports))
        for name, r in reports.items():
            for g, summ in r["interception"].items():
                print(f"interception, filter {name}, guidance {g}: {summary_line(summ)}")
    if args.plot and not args.display_variants:
        plot(reports, collected, args.plot)


if __name__ == "__main__":
    main()
