"""`track-demo`: service, feed and terminal display together on loopback (no router).

Starts `track-service --clock realtime` listening on a loopback port, a real-time feed
of a scenario, and the terminal display; Ctrl-C stops all three. `--web`: the live map
in a browser (`track-web` on http://127.0.0.1:8080/, `--port`) instead of the terminal
display.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import webbrowser

from zenoh_track.clients.lib.origin import parse_origin
from zenoh_track.clients.lib.process import stop_all
from zenoh_track.wire import STOP_GRACE, add_version, free_port, missing_extra, on_signals

# s: the most the service may take to come up: its first start on a machine compiles the
# filter kernels (docs/operations.md), longer than the feed's own wait on a busy machine
START_WAIT = 600.0


def _alive(service: subprocess.Popen, endpoint: str) -> bool:
    """Wait for the service's liveliness token while it runs (at most START_WAIT s)."""
    from zenoh_track.clients.lib import connect

    with connect(endpoint) as client:
        for _ in range(int(START_WAIT)):
            if service.poll() is not None:
                return False
            try:
                client.wait_for_service(timeout=1.0)
                return True
            except TimeoutError:
                continue
    return False


DEMO_ORIGIN = "51.0,1.45,0"


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-demo", description=__doc__)
    p.add_argument("--scenario", default="swarm",
                   choices=("swarm", "display", "radar3d", "maneuver", "crossing",
                            "multisensor"))
    p.add_argument("--targets", type=int, default=12, help="swarm size")
    p.add_argument("--duration", type=float, default=600.0, help="swarm: simulated seconds")
    p.add_argument("--runs", type=int, default=5, help="copies of the other scenarios")
    p.add_argument("--web", action="store_true",
                   help="show the live map in a browser (track-web) instead of the terminal")
    p.add_argument("--port", type=int, default=8080, help="track-web's port with --web")
    p.add_argument("--origin", type=parse_origin, default=DEMO_ORIGIN, metavar="LAT,LON,ALT",
                   help="where on Earth the scenario's frame sits (the service's origin), "
                        "for the basemap of --web (default %(default)s: the Strait of Dover, "
                        "both coasts in view)")
    add_version(p)
    return p


def main(argv: list[str] | None = None) -> None:
    args = parser().parse_args(argv)
    on_signals(interrupt=True)  # a stop ends the children too (the finally blocks below)
    if args.web:
        try:
            import aiohttp  # noqa: F401 - track-web's, checked before anything starts
        except ImportError as exc:
            missing_extra(exc, "web", "track-demo --web")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    py = sys.executable
    service = subprocess.Popen([py, "-m", "zenoh_track", "-l", endpoint, "--clock", "realtime",
                                "--blend", "1", "--origin",
                                ",".join(f"{v:g}" for v in args.origin)])
    try:
        if not _alive(service, endpoint):
            stop_all([service], timeout=STOP_GRACE)
            sys.exit("track-demo: track-service did not start")
    except BaseException:
        stop_all([service], timeout=STOP_GRACE)
        raise
    feed_args = {"swarm": ["--targets", str(args.targets), "--duration", str(args.duration)],
                 "crossing": [], "multisensor": ["--radars", "3"]}.get(
                     args.scenario, ["--runs", str(args.runs)])
    feed = subprocess.Popen([py, "-m", "zenoh_track.clients.feeds.feed", args.scenario,
                            "--realtime",
                             "-e", endpoint, *feed_args], stdout=subprocess.DEVNULL)
    web = None
    try:
        if args.web:
            web = subprocess.Popen([py, "-m", "zenoh_track.clients.web.web", "-e", endpoint,
                                    "--port", str(args.port)])  # the service's origin
            url = f"http://127.0.0.1:{args.port}/"
            print(f"track-demo: the live map is on {url} (Ctrl-C stops the demo)", flush=True)
            if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") \
                    or sys.platform in ("darwin", "win32"):  # never a text browser here
                webbrowser.open(url)
            web.wait()
        else:
            subprocess.run([py, "-m", "zenoh_track.clients.display.display", "-e", endpoint],
                           check=False)
    finally:  # every child stopped at once, within the one bound of a stop
        stop_all([web, feed, service], timeout=STOP_GRACE)


if __name__ == "__main__":
    main()
