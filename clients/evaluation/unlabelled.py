"""`track-eval crossing|multisensor`: multi-target accuracy on unlabelled scans, with GOSPA.

Each Monte Carlo run r (scenario seed `--seed` + r) starts a lockstep service with the
tracker's default flags (plus `--associator`, `--filter`, `--service-arg`), publishes the
scenario's scans with track-feed's code (clients/feeds/feed_plots.py) and collects the
`display/` messages at the scan instants: the service runs with `--rate` = scans per
second, so that its display instants are the scan instants (the display rate does not
touch the tracker), and `display/` carries each track's status. The estimates at a scan
are the tracks shown `confirmed` or `coasting` (not `tentative`), at their position at
the scan instant, after that scan's update (docs/protocol.md §6).

Against the scan's truth (clients/feeds/plotgen.py, same seed): GOSPA (c = `--c`, p = 2,
alpha = 2; clients/evaluation/gospa.py) and its parts, averaged over the scans; per run, identity
switches, track breaks, false confirmed tracks (never within c of a truth) and their
lifetimes, and confirmed/false tracks at the last scan; per target, the time from its
first detection to its first assignment to an established track, and the fraction of
targets confirmed within `--confirm-within` scans (N = 5, the N of the service's
default M-of-N rule 3/5: the scan of the first detection and the next four, any
radar's).
"""

from __future__ import annotations

import argparse
import json
import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from zenoh_track.clients.evaluation import gospa
from zenoh_track.clients.evaluation.collect import Shown, run_plots_through_service
from zenoh_track.clients.evaluation.progress import bar
from zenoh_track.clients.feeds import feed, feed_plots, plotgen

SCENARIOS = feed_plots.SCENARIOS
Rows = list[tuple[float, dict[str, np.ndarray], dict[str, np.ndarray]]]


def add_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("unlabelled scans (crossing, multisensor; default --runs 10)")
    g.add_argument("--associator", action="append", default=[], choices=("gnn", "jpda"),
                   help="service associator(s) to compare (repeatable; default: the "
                        "service's default)")
    g.add_argument("--targets", type=int, default=20)
    g.add_argument("--pd", type=float, default=0.9,
                   help="the scenario's detection probability (stated to the service too)")
    g.add_argument("--clutter", type=float, default=20.0, help="false detections per scan")
    g.add_argument("--sigma", type=float, default=25.0,
                   help="m: Cartesian noise per axis (multisensor: range noise)")
    g.add_argument("--scans", type=int, default=100, help="scans per radar")
    g.add_argument("--radars", type=int, choices=(2, 3), default=3, help="multisensor")
    g.add_argument("--c", type=float, default=100.0, help="GOSPA cut-off, m")
    g.add_argument("--confirm-within", type=int, default=5, metavar="N",
                   help="count targets confirmed within N scans of their first detection "
                        "(default %(default)s: the N of the service's M-of-N rule)")


@dataclass
class Run:
    """One run: its GOSPA evaluation, the estimates and truths per scan, and per
    detected target (delay s, scans from the first detection, 1 = that scan) or None."""

    seed: int
    ev: gospa.Evaluation
    rows: Rows
    confirm: dict[str, tuple[float, int] | None]


def feed_argv(args: argparse.Namespace, seed: int) -> list[str]:
    argv = [args.scenario, "--targets", str(args.targets), "--pd", str(args.pd),
            "--clutter", str(args.clutter), "--sigma", str(args.sigma),
            "--scans", str(args.scans), "--seed", str(seed)]
    return argv + (["--radars", str(args.radars)] if args.scenario == "multisensor" else [])


def configs(args: argparse.Namespace) -> list[tuple[str, list[str]]]:
    """(label, service options) of each service configuration to compare."""
    out = []
    for f in args.filter or [None]:
        for a in args.associator or [None]:
            opts = (["--filter", f] if f else []) + (["--associator", a] if a else [])
            out.append(("/".join(x for x in (a, f) if x) or "default", opts))
    return out


def score(sc: plotgen.Scenario, shown: dict[float, Shown], c: float, seed: int) -> Run:
    """Evaluate one run's displayed tracks against the scenario's truth."""
    rows: Rows = []
    first_seen: dict[str, int] = {}
    for i, (s, origin) in enumerate(sc.labelled()):
        for j in np.unique(origin[origin >= 0]).tolist():
            first_seen.setdefault(sc.flyers.ids[j], i)
        est = {k: np.asarray(p, float) for k, (p, status) in shown[round(s.t, 6)].items()
               if status != "tentative"}
        rows.append((s.t, est, {k: p for k, (p, _) in s.truth.items()}))
    ev = gospa.evaluate(rows, c=c)
    confirm: dict[str, tuple[float, int] | None] = {}
    for target, k0 in first_seen.items():  # every truth is in every scan: index = scan
        k = next((i for i, tr in enumerate(ev.assigned[target][k0:], k0) if tr is not None),
                 None)
        confirm[target] = None if k is None else (rows[k][0] - rows[k0][0], k - k0 + 1)
    return Run(seed, ev, rows, confirm)


def summary(runs: list[Run], within: int) -> dict[str, Any]:
    """Means over the runs (GOSPA parts: over scans, then runs) and the per-run counts."""
    parts = {k: float(np.mean([r.ev.mean()[k] for r in runs]))
             for k in ("total", "localisation", "missed", "false", "n_missed", "n_false")}
    life = [v for r in runs for v in r.ev.false_tracks.values()]
    conf = [v for r in runs for v in r.confirm.values()]
    delays = [v[0] for v in conf if v is not None]
    per_run = [{"seed": r.seed, "gospa": r.ev.mean()["total"], "switches": r.ev.switches,
                "breaks": r.ev.breaks, "false_tracks": len(r.ev.false_tracks),
                "end_tracks": len(r.rows[-1][1]), "end_false": r.ev.scans[-1].n_false,
                "never_confirmed": sum(v is None for v in r.confirm.values())} for r in runs]
    return {
        "gospa": parts,
        "switches": float(np.mean([r.ev.switches for r in runs])),
        "breaks": float(np.mean([r.ev.breaks for r in runs])),
        "false_tracks": float(np.mean([len(r.ev.false_tracks) for r in runs])),
        "false_life_mean": float(np.mean(life)) if life else 0.0,
        "false_life_max": float(max(life)) if life else 0.0,
        "confirm_mean_s": float(np.mean(delays)) if delays else math.nan,
        "confirmed_within": sum(v is not None and v[1] <= within for v in conf)
        / max(len(conf), 1),
        "never_confirmed": int(sum(v is None for v in conf)),
        "end_false": float(np.mean([r.ev.scans[-1].n_false for r in runs])),
        "end_tracks": float(np.mean([len(r.rows[-1][1]) for r in runs])),
        "per_run": per_run,
        "per_scan": {"t": [t for t, _, _ in runs[0].rows],
                     "gospa": np.mean([[g.total for g in r.ev.scans] for r in runs],
                                      axis=0).tolist()},
    }


def title(args: argparse.Namespace, n_runs: int, no_tracks: float) -> str:
    """The table's header: the scenario and the columns."""
    sc = feed_plots.scenario(feed.parser().parse_args(feed_argv(args, args.seed)))
    noise = (f"sr {sc.sr:g} m, saz {sc.saz:g} rad" if sc.radars[0].polar
             else f"sigma {sc.sigma:g} m")
    radars = f", {args.radars} radars" if args.scenario == "multisensor" else ""
    service = f"; service {' '.join(args.service_arg)}" if args.service_arg else ""
    return (f"{args.scenario}: {args.targets} targets{radars}, Pd {args.pd:g}, "
            f"{args.clutter:g} clutter per scan ({sc.clutter_density:.3g} /m^2 for seed "
            f"{args.seed}), {noise}, {args.scans} scans, {n_runs} runs (seeds {args.seed}-"
            f"{args.seed + n_runs - 1}){service}\n"
            f"GOSPA c = {args.c:g} m, p = 2, mean over scans (parts in m^2); no tracks at "
            f"all: {no_tracks:.1f} m.\nPer run: switches, breaks, false confirmed tracks "
            "(their mean and max lifetime, s); from first detection: mean time to confirm "
            f"(s), fraction confirmed within {args.confirm_within} scans, never confirmed "
            "(all runs); at the last scan: tracks, false tracks")


def table(header: str, sums: dict[str, dict[str, Any]], within: int) -> str:
    head = (f"{'service':<12}{'GOSPA m':>8}{'loc':>7}{'missed':>7}{'false':>7}{'switch':>7}"
            f"{'break':>6}{'falseT':>7}{'life s':>7}{'max s':>6}{'conf s':>7}"
            f"{f'<={within}':>6}{'never':>6}{'end':>6}{'endF':>5}")
    lines = [header, head, "-" * len(head)]
    for label, s in sums.items():
        g = s["gospa"]
        lines.append(
            f"{label:<12}{g['total']:8.1f}{g['localisation']:7.0f}{g['missed']:7.0f}"
            f"{g['false']:7.0f}{s['switches']:7.2f}{s['breaks']:6.2f}{s['false_tracks']:7.2f}"
            f"{s['false_life_mean']:7.1f}{s['false_life_max']:6.0f}{s['confirm_mean_s']:7.2f}"
            f"{s['confirmed_within']:6.2f}{s['never_confirmed']:6d}{s['end_tracks']:6.1f}"
            f"{s['end_false']:5.1f}")
    return "\n".join(lines)


def plot(scenario: str, sums: dict[str, dict[str, Any]], first: Run, label: str,
         outdir: str) -> None:
    """`<scenario>_gospa.png`: mean GOSPA per scan and configuration; `<scenario>_tracks.png`:
    the first run's established tracks against the truth (false tracks in red)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(outdir, exist_ok=True)
    fig, ax = plt.subplots(figsize=(8, 4))
    for name, s in sums.items():
        ax.plot(s["per_scan"]["t"], s["per_scan"]["gospa"], label=name)
    ax.set_xlabel("t, s")
    ax.set_ylabel("GOSPA, m (mean over runs)")
    ax.legend()
    fig.suptitle(f"{scenario}: GOSPA per scan, {len(next(iter(sums.values()))['per_run'])} runs")
    fig.savefig(os.path.join(outdir, f"{scenario}_gospa.png"), dpi=120)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 7))
    truth = np.array([[p for p in tru.values()] for _, _, tru in first.rows])  # (K, N, 2)
    for i in range(truth.shape[1]):
        ax.plot(truth[:, i, 0], truth[:, i, 1], color="0.6", lw=3, zorder=1,
                label="truth" if i == 0 else None)
    tracks: dict[str, list[np.ndarray]] = {}
    for _, est, _ in first.rows:
        for k, p in est.items():
            tracks.setdefault(k, []).append(p)
    for k, ps in tracks.items():
        xy = np.array(ps)
        false = k in first.ev.false_tracks
        ax.plot(xy[:, 0], xy[:, 1], "x" if false else ".", ms=3, zorder=2,
                color="red" if false else None)
    ax.set_aspect("equal")
    ax.set_xlabel("East, m")
    ax.set_ylabel("North, m")
    ax.legend()
    fig.suptitle(f"{scenario} seed {first.seed}, {label}: established tracks against truth")
    fig.savefig(os.path.join(outdir, f"{scenario}_tracks.png"), dpi=120)
    plt.close(fig)


def run(args: argparse.Namespace) -> None:
    """`track-eval crossing|multisensor` with the parsed options of
    clients/evaluation/evaluate.py."""
    if args.connect or args.intercept or args.display_variants:
        raise SystemExit("track-eval: -e, --intercept and --display-variants are for the "
                         "labelled scenarios")
    n_runs = 10 if args.runs is None else args.runs
    results: dict[str, list[Run]] = {}
    progress = bar(total=n_runs * len(configs(args)), desc="service runs", unit=" run",
                   quiet=getattr(args, "quiet", False))
    for label, opts in configs(args):
        results[label] = []
        for r in range(n_runs):
            argv = feed_argv(args, args.seed + r)
            sc = feed_plots.scenario(feed.parser().parse_args(argv))
            rate = len(sc.radars) / sc.dt  # multisensor: radar k scans at k dt / radars
            # the radars' Pd stated to the service, as its operator would
            shown = run_plots_through_service(argv, ["--rate", f"{rate:g}", "--pd",
                                                     f"{args.pd:g}", *opts,
                                                     *args.service_arg])
            results[label].append(score(sc, shown, args.c, args.seed + r))
            progress.update(1)
    progress.close()
    sums = {k: summary(v, args.confirm_within) for k, v in results.items()}
    no_tracks = math.sqrt(args.targets * args.c**2 / gospa.ALPHA)
    if args.json:
        print(json.dumps({"scenario": args.scenario, "runs": n_runs, "seed": args.seed,
                          "c": args.c, "no_tracks_gospa": no_tracks,
                          "configs": {k: {kk: vv for kk, vv in v.items() if kk != "per_scan"}
                                      for k, v in sums.items()}}, indent=1))
    else:
        print(table(title(args, n_runs, no_tracks), sums, args.confirm_within))
    if args.plot:
        label = next(iter(results))
        plot(args.scenario, sums, results[label][0], label, args.plot)
