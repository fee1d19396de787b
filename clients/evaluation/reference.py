"""`track-eval defaults`: the service as a new user runs it, without options, on the three
reference scenarios, beside the best filter chosen for each (A: `ca`, the paper's
predictor; B: `cv`, the CMKF whose model is the truth's; C: `vdf`, the paper's filter),
all through a lockstep service over Zenoh, with the targets of issue 14 and 95 %
Monte Carlo intervals (bootstrap over the runs, paired where two filters share them).
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np

from zenoh_track.clients.evaluation import evaluate
from zenoh_track.clients.evaluation.collect import run_through_service

BEST = {"display": "ca", "radar3d": "cv", "maneuver": "vdf"}
# evaluation plumbing only (what the service publishes), not an estimation option
PLUMBING = ["--no-display-keys"]
BOOT = 2000  # bootstrap resamples


def reports(scenario: str, runs: int, seed: int) -> dict[str, dict[str, Any]]:
    """The default service's report and the best filter's, same runs."""
    out = {}
    for label, args in (("default", []), (BEST[scenario], ["--filter", BEST[scenario],
                                                         *evaluate.SERVICE_ARGS[scenario]])):
        got = run_through_service(scenario, runs, seed, [*PLUMBING, *args])
        out[label] = evaluate.evaluate(scenario, runs, seed, got)
    return out


def interval(samples: np.ndarray) -> tuple[float, float]:
    return float(np.percentile(samples, 2.5)), float(np.percentile(samples, 97.5))


def boot_rmse_ratio(mse_a: np.ndarray, mse_b: np.ndarray | float, seed: int
                    ) -> tuple[float, float]:
    """95 % bootstrap interval of sqrt(mean mse_a) / sqrt(mean mse_b) over runs resampled
    together (mse_b may be a fixed number, such as a bound)."""
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(mse_a), (BOOT, len(mse_a)))
    num = np.sqrt(np.nanmean(mse_a[idx], 1))
    den = np.sqrt(np.nanmean(np.asarray(mse_b)[idx], 1)) if np.ndim(mse_b) else np.sqrt(mse_b)
    return interval(num / den)


def window(report: dict[str, Any], name: str) -> dict[str, Any]:
    return next(w for w in [*report["windows"], report["overall"]] if w["window"] == name)


def rows_a(rep: dict[str, dict]) -> list[dict[str, Any]]:
    d, b = rep["default"]["display"], rep["ca"]["display"]
    return [{"what": "A frame RMS, m (1 run: deterministic)", "default": d["rms"],
             "best": b["rms"], "ratio": d["rms"] / b["rms"], "ci": None,
             "target": "ratio <= 1.2", "ok": d["rms"] <= 1.2 * b["rms"]}]


def rows_b(rep: dict[str, dict], seed: int) -> list[dict[str, Any]]:
    d, b = rep["default"], rep["cv"]
    od, ob = d["overall"], b["overall"]
    lo, hi = d["nees_interval"]
    mse = np.array(d["per_run"][od["window"]])
    wins = [w["nees"] for w in d["windows"]]
    return [
        {"what": f"B pos RMSE / PCRB, scans {od['window'][2:]}", "default": od["pos_rmse"],
         "best": ob["pos_rmse"], "ratio": od["pos_ratio"], "best_ratio": ob["pos_ratio"],
         "ci": boot_rmse_ratio(mse, od["pos_bound"] ** 2, seed), "target": "ratio <= 1.05",
         "ok": od["pos_ratio"] <= 1.05},
        {"what": "B average NEES", "default": od["nees"], "best": ob["nees"], "ratio": None,
         "ci": (lo, hi), "target": "inside the interval", "ok": lo <= od["nees"] <= hi},
        {"what": "B largest 20-scan window NEES", "default": max(wins),
         "best": max(w["nees"] for w in b["windows"]), "ratio": None, "ci": None,
         "target": "< 9", "ok": max(wins) < 9},
    ]


def rows_c(rep: dict[str, dict], seed: int) -> list[dict[str, Any]]:
    d, v = rep["default"], rep["vdf"]
    lo, hi = d["nees_interval"]
    out = []
    for name, limit in (("straight", 1.25), ("slow turn", 1.0), ("fast turn", 1.0)):
        wd, wv = window(d, name), window(v, name)
        ratio = wd["pos_rmse"] / wv["pos_rmse"]
        ok = ratio <= limit if limit > 1 else ratio < limit
        out.append({"what": f"C {name} pos RMSE, m", "default": wd["pos_rmse"],
                    "best": wv["pos_rmse"], "ratio": ratio,
                    "ci": boot_rmse_ratio(np.array(d["per_run"][name]),
                                          np.array(v["per_run"][name]), seed),
                    "target": f"ratio {'<=' if limit > 1 else '<'} {limit:g}", "ok": ok})
    for w in d["windows"]:
        out.append({"what": f"C {w['window']} NEES", "default": w["nees"],
                    "best": window(v, w["window"])["nees"], "ratio": None, "ci": (lo, hi),
                    "target": "inside the interval", "ok": lo <= w["nees"] <= hi})
    return out


def fmt(v: float | None, digits: int = 3) -> str:
    return "" if v is None else f"{v:.{digits}f}" if abs(v) < 1e4 else f"{v:.3g}"


def print_table(rows: list[dict[str, Any]], header: str) -> None:
    print(header)
    print(f"{'measure':<40}{'default':>10}{'best':>10}{'ratio':>8}  {'95 % interval':<18}"
          f"{'target':<22}")
    for r in rows:
        ci = "" if r["ci"] is None else f"[{r['ci'][0]:.3f}, {r['ci'][1]:.3f}]"
        print(f"{r['what']:<40}{fmt(r['default']):>10}{fmt(r['best']):>10}"
              f"{fmt(r['ratio']):>8}  {ci:<18}{r['target']:<22}{'ok' if r['ok'] else 'MISSED'}")


def run(args: argparse.Namespace) -> None:
    runs_b = 100 if args.runs is None else args.runs
    runs_c = args.runs_c
    started = time.monotonic()
    rep_a = reports("display", 1, args.seed)
    rep_b = reports("radar3d", runs_b, args.seed)
    rep_c = reports("maneuver", runs_c, args.seed)
    rows = rows_a(rep_a) + rows_b(rep_b, args.seed) + rows_c(rep_c, args.seed)
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print_table(rows, f"track-eval defaults: the service without options (default) against "
                      f"the best filter per scenario (A: ca, B: cv, C: vdf), seed {args.seed}; "
                      f"B {runs_b} runs, C {runs_c} runs")
    missed = [r["what"] for r in rows if not r["ok"]]
    print(f"{len(rows) - len(missed)} of {len(rows)} targets met"
          + (f"; missed: {', '.join(missed)}" if missed else "")
          + f" ({time.monotonic() - started:.0f} s)")
