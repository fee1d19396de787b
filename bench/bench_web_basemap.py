"""What the basemap costs `track-web`'s draw: frames drawn per second in headless chromium
with the basemap on and off, at the same number of tracks, in the same run.

    python bench/bench_web_basemap.py                  # 10,000 tracks, 3 rounds of 10 s
    python bench/bench_web_basemap.py --sizes 1000 10000 --rounds 2

One `track-web --origin 50.95,1.85,0` (the Strait of Dover: coastlines and borders of
England, France and Belgium in view) fed by bench_web's publisher (N tracks over
300 km, 30 Hz, from a Zenoh peer on loopback); one page with the basemap
(`/#...`) and one without (`/?basemap=off`), 1280 x 800, following the tracks (so the
view, and with it the basemap's layer, changes every 2 s). The two pages are measured
in turns, `--rounds` times each, so that a change of the machine's load falls on both;
each figure is bench_web's: frames drawn in the last second (median over the window),
milliseconds per draw; the ratios on / off of the medians and means over the rounds.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_web import (  # noqa: E402
    CHROMIUM,
    CHROMIUM_ARGS,
    PY,
    RATE,
    FramePublisher,
    measure,
    wait_http,
)

from zenoh_track.clients.lib.process import stop  # noqa: E402
from zenoh_track.wire import free_port  # noqa: E402

ORIGIN = "50.95,1.85,0"


def run(n: int, args: argparse.Namespace, playwright) -> dict[str, list[dict]]:
    endpoint, port = f"tcp/127.0.0.1:{free_port()}", free_port()
    publisher = FramePublisher(endpoint, n)
    web = subprocess.Popen([PY, "-m", "zenoh_track.clients.web.web", "-e", endpoint, "--port",
                            str(port), "--origin", ORIGIN], stderr=subprocess.DEVNULL)
    out: dict[str, list[dict]] = {"on": [], "off": []}
    try:
        wait_http(f"http://127.0.0.1:{port}/api/health")
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            for _ in range(args.rounds):
                for variant, path in (("off", "/?basemap=off"), ("on", "/")):
                    page = browser.new_page(viewport={"width": 1280, "height": 800})
                    page.goto(f"http://127.0.0.1:{port}{path}")
                    out[variant].append(measure(page, port, n, args.seconds, args.warmup))
                    page.close()
        finally:
            browser.close()
    finally:
        stop(web, timeout=10)
        publisher.close()
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[10000])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--warmup", type=float, default=3.0)
    args = p.parse_args()
    from playwright.sync_api import sync_playwright

    print(f"headless chromium, 1280 x 800, {os.cpu_count()} cores, frames offered at "
          f"{RATE:g} Hz; basemap at {ORIGIN}")
    with sync_playwright() as pw:
        for n in args.sizes:
            r = run(n, args, pw)
            fps = {v: statistics.median(x["fps_median"] for x in r[v]) for v in r}
            ms = {v: statistics.median(x["draw_ms"] for x in r[v]) for v in r}
            load = statistics.mean(x["load"] for v in r for x in r[v])
            mean = {v: statistics.mean(x["fps_median"] for x in r[v]) for v in r}
            print(f"{n:>6} tracks: basemap off {fps['off']:.1f} frames/s ({ms['off']:.1f} ms a "
                  f"draw), on {fps['on']:.1f} frames/s ({ms['on']:.1f} ms); on/off "
                  f"{fps['on'] / fps['off']:.2f} (means {mean['on'] / mean['off']:.2f}; "
                  f"ms a draw {ms['on'] / ms['off']:.2f}) (rounds off "
                  f"{[x['fps_median'] for x in r['off']]}, on "
                  f"{[x['fps_median'] for x in r['on']]}), load {load:.1f}", flush=True)


if __name__ == "__main__":
    main()
