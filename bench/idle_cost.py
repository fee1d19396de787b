"""What a realtime service costs while nothing comes, against a bare Zenoh peer.

    python bench/idle_cost.py [--settle 12] [--seconds 10]

Starts a realtime service (no flags) on a free loopback port and, as its peer in the
same run, a Python process that only opens a Zenoh session on another port; waits until
the service is alive and `--settle` s have passed without input (the service looks in
its channels less often once nothing has come for a while), then reads both processes'
CPU from /proc over `--seconds` s and prints it as % of one core, with the service's
busiest thread.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run from a checkout
sys.path.insert(0, str(Path(__file__).resolve().parent))

from procstat import cpu_seconds, thread_cpu  # noqa: E402

from zenoh_track.clients.lib import ServiceProcess  # noqa: E402
from zenoh_track.wire import free_port  # noqa: E402

PEER = """
import sys, time, zenoh
from zenoh_track.wire import listen_config
s = zenoh.open(listen_config(sys.argv[1]))
print("ready", flush=True)
sys.stdin.readline()
"""


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--settle", type=float, default=12.0)
    p.add_argument("--seconds", type=float, default=10.0)
    args = p.parse_args(argv)
    peer = subprocess.Popen([sys.executable, "-c", PEER, f"tcp/127.0.0.1:{free_port()}"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert peer.stdout is not None and peer.stdin is not None
    if peer.stdout.readline().strip() != "ready":
        raise SystemExit("the bare peer did not start")
    with ServiceProcess(clock="realtime") as svc:
        svc.wait(timeout=120)
        assert svc.proc is not None
        time.sleep(args.settle)  # the quiet the measurement is about
        pids = {"track-service": svc.proc.pid, "bare Zenoh peer": peer.pid}
        before = {k: cpu_seconds(v) for k, v in pids.items()}
        threads = thread_cpu(svc.proc.pid)
        time.sleep(args.seconds)
        after = {k: cpu_seconds(v) for k, v in pids.items()}
        busiest = max((cpu - threads.get(tid, (name, 0.0))[1], name)
                      for tid, (name, cpu) in thread_cpu(svc.proc.pid).items())
    peer.stdin.write("\n")
    peer.stdin.flush()
    peer.wait(timeout=10)
    print(f"# {time.strftime('%Y-%m-%dT%H:%M:%S')}; idle for {args.settle:.0f} s, then "
          f"{args.seconds:.0f} s measured")
    for name in pids:
        print(f"{name:<18} {(after[name] - before[name]) / args.seconds * 100:5.1f} % of a core")
    print(f"{'  busiest thread':<18} {busiest[0] / args.seconds * 100:5.1f} % ({busiest[1]})")


if __name__ == "__main__":
    main()
