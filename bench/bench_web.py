"""Browser benchmark of `track-web`: frames drawn per second in headless chromium.

    python bench/bench_web.py                          # 1,000 and 10,000 tracks, both sources
    python bench/bench_web.py --sizes 10000 --source frames --seconds 20
    python bench/bench_web.py --source service --sizes 20 --warmup 60 \
        --feed "multisensor --radars 3 --realtime" --service "--filter imm" \
        --screenshot docs/figures/track_web.png

For each N and source this starts `track-web` (a separate process, loopback, free ports),
opens its page in Debian's chromium driven by Playwright (never a browser download:
`apt-get install -y chromium`) at 1280 x 800, waits until the page counts N tracks, and
then reads the page's own figures once a second for --seconds: frames drawn in the last
second (`#fps`: animation frames that drew a new frame), milliseconds per draw
(`#draw-ms`) and the frames the server skipped for this browser (`#dropped`: latest frame
wins). Frames offered per second are counted by track-web (`/api/health`).

Sources of the `<ns>/frame` key at 30 Hz:
- `frames`: this process publishes frames in the contract's format (N tracks on straight
  lines, all three statuses) from a Zenoh peer on loopback: the page alone is measured;
- `service`: `python -m zenoh_track --clock realtime --filter cv --no-display-keys` fed by
  `python -m zenoh_track.clients.feeds.feed swarm --targets N --realtime` (or `--feed`): the whole
  chain,
  sharing the cores with the service (0.6 of a core at 10,000 targets,
  docs/performance.md).

The machine's load average is printed with the figures: other processes on the cores
lower them.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import threading
import time
import urllib.request

import numpy as np
import zenoh

from zenoh_track.clients.lib.process import stop
from zenoh_track.wire import Keys, free_port, pack, peer_config, unpack

CHROMIUM = "/usr/bin/chromium"
# no sandbox (root in CI), software drawing, nothing fetched from the network
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync"]
RATE = 30.0
PY = sys.executable


class FramePublisher:
    """`<ns>/frame` at 30 Hz for N tracks on straight lines, from a peer listening on
    `endpoint`."""

    def __init__(self, endpoint: str, n: int, seed: int = 1) -> None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
        self.session = zenoh.open(conf)
        rng = np.random.default_rng(seed)
        self.pos = np.column_stack([rng.uniform(-150e3, 150e3, (n, 2)), rng.uniform(0, 1e4, n)])
        self.vel = np.column_stack([rng.normal(0, 150, (n, 2)), np.zeros(n)])
        self.sigma = rng.uniform(50, 1500, n)
        self.status = (np.arange(n) % 7 == 0).astype(np.uint8) * 2 + (np.arange(n) % 7 != 0)
        self.status[::11] = 0
        self.ids = [f"swarm-{i:05d}" for i in range(n)]
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        pub = self.session.declare_publisher(Keys().frame,
                                             congestion_control=zenoh.CongestionControl.DROP)
        start, k = time.monotonic(), 0
        while not self.stopping.is_set():
            t = k / RATE
            pos = self.pos + self.vel * t
            pub.put(pack({"t": 1000.0 + t, "ids": self.ids, "pos": pos.astype("<f8").tobytes(),
                          "vel": self.vel.astype("<f8").tobytes(),
                          "sigma": self.sigma.astype("<f8").tobytes(),
                          "status": self.status.tobytes()}))
            k += 1
            self.stopping.wait(max(start + k / RATE - time.monotonic(), 0.0))

    def close(self) -> None:
        self.stopping.set()
        self.thread.join(5)
        self.session.close()


def wait_http(url: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while True:
        try:
            urllib.request.urlopen(url, timeout=2).read()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def health(port: int) -> dict:
    return json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/api/health").read())


def texts(page, *ids: str) -> list[str]:
    return page.evaluate("ids => ids.map(i => document.getElementById(i).textContent)",
                         list(ids))


def measure(page, port: int, n: int, seconds: float, warmup: float) -> dict:
    deadline = time.monotonic() + 300
    while int(texts(page, "track-count")[0]) < 0.99 * n:
        if time.monotonic() > deadline:
            raise TimeoutError(f"the page never counted {n} tracks")
        time.sleep(0.5)
    time.sleep(warmup)
    fps, ms = [], []
    h0, d0, t0 = health(port)["frames_received"], int(texts(page, "dropped")[0]), time.monotonic()
    for _ in range(int(seconds)):
        time.sleep(1.0)
        f, d = texts(page, "fps", "draw-ms")
        fps.append(int(f))
        ms.append(float(d))
    span = time.monotonic() - t0
    return {"n": n, "fps_median": statistics.median(fps), "fps_min": min(fps),
            "fps_max": max(fps), "draw_ms": statistics.median(ms),
            "offered": (health(port)["frames_received"] - h0) / span,
            "skipped": (int(texts(page, "dropped")[0]) - d0) / span,
            "load": os.getloadavg()[0]}


def select_a_track(page, endpoint: str, port: int) -> None:
    """Click the confirmed track nearest the middle of the picture (found from a frame
    received here) after centring the view on it; then follow all tracks again."""
    session = zenoh.open(peer_config(endpoint))
    got: list[dict] = []
    sub = session.declare_subscriber(Keys().frame, lambda s: got.append(
        unpack(s.payload.to_bytes())))
    deadline = time.monotonic() + 10
    while not got and time.monotonic() < deadline:
        time.sleep(0.1)
    sub.undeclare()
    session.close()
    msg = got[-1]
    pos = np.frombuffer(msg["pos"], "<f8").reshape(-1, 3)
    confirmed = np.frombuffer(msg["status"], np.uint8) == 1 if "status" in msg \
        else np.ones(len(pos), bool)
    dist = np.hypot(*(pos[:, :2] - pos[:, :2].mean(0)).T)
    i = int(np.argmin(np.where(confirmed, dist, np.inf)))
    # 200 m a pixel: a track moves a few pixels while the page is told where to look
    page.goto(f"http://127.0.0.1:{port}/#{pos[i, 0]:.1f},{pos[i, 1]:.1f},200")
    page.wait_for_timeout(500)
    box = page.locator("#map").bounding_box()
    page.mouse.click(box["width"] / 2, box["height"] / 2)
    try:
        page.wait_for_function("document.getElementById('detail-body').textContent"
                               ".includes('updates')", timeout=10000)
    except Exception:
        print("bench_web: no details:", texts(page, "detail-id", "detail-body"), file=sys.stderr)
        raise
    page.keyboard.press("f")
    page.wait_for_timeout(2500)


def run(n: int, source: str, args: argparse.Namespace, playwright) -> dict:
    endpoint, port = f"tcp/127.0.0.1:{free_port()}", free_port()
    procs: list[subprocess.Popen] = []
    publisher = None
    try:
        if source == "frames":
            publisher = FramePublisher(endpoint, n)
        else:
            procs.append(subprocess.Popen([PY, "-m", "zenoh_track", "--clock", "realtime",
                                           *args.service.split(), "--no-display-keys",
                                           "--instance", "bench-web", "-l", endpoint]))
            procs.append(subprocess.Popen(
                [PY, "-m", "zenoh_track.clients.feeds.feed", *args.feed.format(n=n).split(), "-e",
                 endpoint],
                stdout=subprocess.DEVNULL))
        procs.append(subprocess.Popen([PY, "-m", "zenoh_track.clients.web.web", "-e", endpoint,
                                       "--port",
                                       str(port)], stderr=subprocess.DEVNULL))
        wait_http(f"http://127.0.0.1:{port}/api/health")
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(f"http://127.0.0.1:{port}/")
            result = measure(page, port, n, args.seconds, args.warmup) | {"source": source}
            if args.screenshot:
                select_a_track(page, endpoint, port)
                page.screenshot(path=args.screenshot)
                print(f"bench_web: screenshot {args.screenshot}", file=sys.stderr)
            return result
        finally:
            browser.close()
    finally:
        for p in reversed(procs):
            stop(p, timeout=10)
        if publisher:
            publisher.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000])
    p.add_argument("--source", choices=("frames", "service", "both"), default="both")
    p.add_argument("--seconds", type=float, default=10.0, help="measured window")
    p.add_argument("--warmup", type=float, default=3.0, help="s after the count is reached")
    p.add_argument("--screenshot", help="save a PNG of the page (last run) with a track "
                   "selected")
    p.add_argument("--feed", default="swarm --targets {n} --realtime --duration 3600",
                   help="track-feed arguments of the service source ({n}: the size)")
    p.add_argument("--service", default="--filter cv",
                   help="more track-service options of the service source")
    args = p.parse_args()
    from playwright.sync_api import sync_playwright

    sources = ("frames", "service") if args.source == "both" else (args.source,)
    rows = []
    with sync_playwright() as pw:
        for source in sources:
            for n in args.sizes:
                rows.append(run(n, source, args, pw))
                r = rows[-1]
                print(f"{r['source']:>8} {r['n']:>6} tracks: drawn {r['fps_median']:>3.0f}/s "
                      f"(min {r['fps_min']}, max {r['fps_max']}), {r['draw_ms']:.1f} ms per "
                      f"draw, offered {r['offered']:.1f}/s, skipped {r['skipped']:.1f}/s, "
                      f"load {r['load']:.1f}", flush=True)
    print(f"\nheadless chromium {CHROMIUM}, 1280 x 800, {os.cpu_count()} cores; drawn / 30 Hz:")
    for r in rows:
        print(f"  {r['source']:>8} {r['n']:>6}: {r['fps_median'] / RATE:.2f}")


if __name__ == "__main__":
    main()
