"""`track-demo`: service, feed and terminal display together on loopback (no router).

Starts `track-service --clock realtime` listening on a loopback port, a real-time feed
of a scenario, and the terminal display; Ctrl-C stops all three.
"""

from __future__ import annotations

import argparse
import subprocess
import sys

from service.wire import free_port

from .procs import stop


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="track-demo", description=__doc__)
    p.add_argument("--scenario", default="swarm",
                   choices=("swarm", "display", "radar3d", "maneuver"))
    p.add_argument("--targets", type=int, default=12, help="swarm size")
    p.add_argument("--duration", type=float, default=600.0, help="swarm: simulated seconds")
    p.add_argument("--runs", type=int, default=5, help="copies of the other scenarios")
    args = p.parse_args(argv)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    py = sys.executable
    service = subprocess.Popen([py, "-m", "service", "-l", endpoint, "--clock", "realtime",
                                "--blend", "1"])
    feed_args = ["--targets", str(args.targets), "--duration", str(args.duration)] \
        if args.scenario == "swarm" else ["--runs", str(args.runs)]
    feed = subprocess.Popen([py, "-m", "clients.feed", args.scenario, "--realtime",
                             "-e", endpoint, *feed_args], stdout=subprocess.DEVNULL)
    try:
        subprocess.run([py, "-m", "clients.display", "-e", endpoint], check=False)
    except KeyboardInterrupt:
        pass
    finally:
        for proc in (feed, service):
            stop(proc, timeout=10)


if __name__ == "__main__":
    main()
