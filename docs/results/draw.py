"""Draw the results pages' figures from the benchmarks' own output.

    python docs/results/draw.py [--out docs/figures]

Reads the files of docs/results/data/ (each the printed output of the command named on its
first line, or a table of it) and writes docs/figures/results_*.png. Rerun a benchmark,
save its output over the data file, and run this to redraw its figure.
"""

from __future__ import annotations

import argparse
import csv
import re
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

DATA = Path(__file__).resolve().parent / "data"
OUT = Path(__file__).resolve().parents[1] / "figures"


def rows(name: str) -> list[dict[str, str]]:
    """A data file's CSV rows (its comment lines skipped)."""
    with open(DATA / name) as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def table(lines: list[str], header: str) -> list[list[str]]:
    """The whitespace-separated rows under the line starting with `header`, to a blank line."""
    start = next(i for i, line in enumerate(lines) if line.strip().startswith(header))
    out = []
    for line in lines[start + 1:]:
        if not line.strip() or not re.match(r"\s*[\dt]", line):
            break
        out.append(line.split())
    return out


def radar3d(out: Path) -> Path:
    """Scenario B: each filter's position RMSE against the PCRB, and its NEES, per window."""
    text = (DATA / "radar3d.txt").read_text().split("\n\n")
    blocks = {re.search(r"radar3d / (\w+):", b).group(1): b.splitlines()
              for b in text if re.search(r"radar3d / (\w+):", b)}
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for name, lines in blocks.items():
        rows_ = [r for r in table(lines, "window") if "-" in r[0]]
        mid = [sum(map(int, r[0].split("-"))) / 2 for r in rows_]
        a.plot(mid, [float(r[1]) for r in rows_], "o-", label=f"{name} RMSE")
        b.plot(mid, [float(r[7]) for r in rows_], "o-", label=f"{name} mean NEES")
        b.plot(mid, [float(r[8]) for r in rows_], ":", label=f"{name} largest scan NEES")
    bound = [r for r in table(next(iter(blocks.values())), "window") if "-" in r[0]]
    a.plot([sum(map(int, r[0].split("-"))) / 2 for r in bound], [float(r[3]) for r in bound],
           "k--", label="PCRB")
    a.set(xlabel="scan (window centre)", ylabel="position error, m",
          title="B: position RMSE against the bound")
    b.axhspan(5.34, 6.70, color="0.9", label="95 % interval of the mean")
    b.set(xlabel="scan (window centre)", ylabel="NEES (6-D)", yscale="log",
          title="B: consistency (6 expected)")
    a.legend(), b.legend(fontsize=8)
    return save(fig, out / "results_radar3d.png")


def display(out: Path) -> Path:
    """Scenario A: frame RMS and largest jump of each display mode, all phases."""
    data = [r for r in rows("display_variants.csv") if r["phase"] == "all"]
    names = [r["variant"] for r in data]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    x = range(len(names))
    ax.bar([i - 0.2 for i in x], [float(r["frame_rms_m"]) for r in data], 0.4,
           label="frame error RMS")
    ax.bar([i + 0.2 for i in x], [float(r["largest_jump_m"]) for r in data], 0.4,
           label="largest jump beyond the true motion")
    ax.set_xticks(list(x), names)
    ax.set(ylabel="m", yscale="log", title="A: 30 Hz frames of a 1 Hz target, CA filter")
    ax.legend()
    return save(fig, out / "results_display.png")


def manoeuvres(out: Path) -> Path:
    """RMSE while manoeuvring per class, one panel per scan period, the default and peers."""
    data = rows("manoeuvres.csv")
    periods = sorted({r["period_s"] for r in data}, key=float)
    peers = {"default": "rmse_manoeuvring_default_m", "ncv-blair":
             "rmse_manoeuvring_ncv_blair_m", "Stone Soup": "rmse_manoeuvring_stonesoup_m"}
    fig, axes = plt.subplots(1, len(periods), figsize=(13, 3.8), sharey=True)
    for ax, period in zip(axes, periods, strict=True):
        sub = [r for r in data if r["period_s"] == period]
        for k, (label, col) in enumerate(peers.items()):
            ax.bar([i + (k - 1) * 0.27 for i in range(len(sub))], [float(r[col]) for r in sub],
                   0.27, label=label)
        ax.set_xticks(range(len(sub)), [r["class"] for r in sub], rotation=30)
        ax.set(title=f"scans every {period} s", yscale="log")
    axes[0].set_ylabel("RMSE while manoeuvring, m")
    axes[0].legend(fontsize=8)
    return save(fig, out / "results_manoeuvres.png")


def periods(out: Path) -> Path:
    """The default's breaks and RMSE while turning against the scan period."""
    data = rows("beyond5s.csv")
    p = [float(r["period_s"]) for r in data]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    for col, label in (("rmse_standard_rate_m", "standard-rate"), ("rmse_4g_m", "4 g"),
                       ("rmse_7g_m", "7 g S-turns"), ("rmse_climbing_m", "climbing")):
        a.plot(p, [float(r[col]) for r in data], "o-", label=label)
    a.set(xlabel="scan period, s", ylabel="RMSE while manoeuvring, m",
          title="the default, per class")
    a.legend(fontsize=8)
    b.bar(p, [int(r["breaks"]) for r in data], width=0.8, label="breaks in 200 aircraft")
    b2 = b.twinx()
    b2.plot(p, [float(r["held_smallest"]) for r in data], "k.-", label="smallest held")
    b.set(xlabel="scan period, s", ylabel="track breaks", title="breaks and holding")
    b2.set(ylabel="smallest fraction of scans held", ylim=(0, 1.05))
    return save(fig, out / "results_periods.png")


def filter_core(out: Path) -> Path:
    """Microseconds a target-step against N: ours, FilterPy, Stone Soup."""
    lines = (DATA / "bench_filter.txt").read_text().splitlines()
    peers = table(lines, "N  timed")
    n = [int(r[0]) for r in peers]
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for col, label in ((2, "ours (one vectorised step)"), (3, "FilterPy (object per target)"),
                       (6, "Stone Soup (object per target)")):
        ax.plot(n, [float(r[col]) for r in peers], "o-", label=label)
    ax.set(xscale="log", yscale="log", xlabel="targets", ylabel="us per target-step",
           title="Predict, convert and update one radar measurement")
    ax.legend()
    return save(fig, out / "results_filter_core.png")


def capacity(out: Path) -> Path:
    """The realtime service's CPU and p99 latency against the number of targets."""
    lines = (DATA / "capacity.txt").read_text().splitlines()
    runs = [r for r in table(lines, "N    mode") if r[1] == "frame"]
    head = next(line for line in lines if line.strip().startswith("N    mode")).split()
    col = {name: i for i, name in enumerate(head)}
    n = [int(r[0]) for r in runs]
    fig, a = plt.subplots(figsize=(6.5, 4))
    a.plot(n, [float(r[col["cpu%"]]) for r in runs], "o-", label="service CPU, % of a core")
    a.plot(n, [float(r[col["wrk%"]]) for r in runs], "s-", label="worker thread, %")
    a.set(xlabel="targets, each measured once a second", ylabel="% of one core",
          title="The realtime service, no flags")
    b = a.twinx()
    b.plot(n, [float(r[col["lat99"]]) for r in runs], "k^:", label="p99 latency, ms")
    b.set(ylabel="p99 measurement to tracks/ latency, ms", yscale="log")
    a.legend(loc="upper left", fontsize=8), b.legend(loc="lower right", fontsize=8)
    return save(fig, out / "results_capacity.png")


def save(fig: plt.Figure, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


DRAWINGS = (radar3d, display, manoeuvres, periods, filter_core, capacity)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=OUT, help="where the PNG files go")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for draw in DRAWINGS:
        print(draw(args.out))


if __name__ == "__main__":
    main()
