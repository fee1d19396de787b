"""What a `tracks/` put costs a Python thread while another Python thread of the same
process wants the GIL (zenoh-python releases the GIL in every put, so each put of the
service's sender thread can hand the GIL to the busy worker and wait to take it back).

    python bench/put_gil.py [--puts 40000]

Puts 1,031-byte bodies (a 3-D IMM track's `tracks/` body) on 5,000 keys to a subscriber
in another process (loopback, a ring channel of one: Zenoh drops them in Rust), alone,
then with a second thread of this process running Python code, and prints the putting
thread's CPU and wall time per put. docs/performance.md quotes it.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from importlib.metadata import version
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run from a checkout

from zenoh_track.wire import free_port, peer_config  # noqa: E402

SUBSCRIBER = """
import sys, zenoh
from zenoh_track.wire import listen_config
s = zenoh.open(listen_config(sys.argv[1]))
sub = s.declare_subscriber("tracks/**", zenoh.handlers.RingChannel(1))
print("ready", flush=True)
sys.stdin.readline()
"""


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--puts", type=int, default=40_000)
    args = p.parse_args(argv)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, endpoint], text=True,
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    assert sub.stdout is not None and sub.stdin is not None
    if sub.stdout.readline().strip() != "ready":
        raise SystemExit("the subscriber did not start")
    session = zenoh.open(peer_config(endpoint))
    keys = [zenoh.KeyExpr(f"tracks/T{i:05d}") for i in range(5000)]
    body, block = os.urandom(1031), zenoh.CongestionControl.BLOCK
    for k in keys:  # the route to the subscriber known before timing
        session.put(k, body, congestion_control=block)
    busy = threading.Event()

    def spin() -> None:
        x = 0
        while busy.is_set():
            for i in range(1000):
                x += i

    print(f"# {time.strftime('%Y-%m-%dT%H:%M:%S')}; eclipse-zenoh {version('eclipse-zenoh')}, "
          f"{os.cpu_count()} CPUs; {args.puts} puts of {len(body)} bytes")
    for label, spinning in (("alone", False), ("beside a busy Python thread", True)):
        if spinning:
            busy.set()
            thread = threading.Thread(target=spin)
            thread.start()
        cpu, wall = time.thread_time(), time.perf_counter()
        for i in range(args.puts):
            session.put(keys[i % len(keys)], body, congestion_control=block)
        cpu, wall = time.thread_time() - cpu, time.perf_counter() - wall
        if spinning:
            busy.clear()
            thread.join()
        print(f"{label:<30} CPU {cpu / args.puts * 1e6:6.2f} us a put, wall "
              f"{wall / args.puts * 1e6:8.2f} us a put")
    session.close()
    sub.stdin.write("\n")
    sub.stdin.flush()
    sub.wait(timeout=10)


if __name__ == "__main__":
    main()
