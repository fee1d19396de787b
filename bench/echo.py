"""The echo floor: the least a Python Zenoh process can do per measurement.

    python bench/echo.py -l tcp/127.0.0.1:PORT --ns NS

Takes each `<ns>/meas/<sensor>/<target>` sample from a FIFO channel (as the service
does), decodes its MessagePack body and puts a small reply `{t, id}` on
`<ns>/tracks/<target>` (`--reply-bytes N`: padded to about N bytes); declares the
tracker's liveliness token and answers `<ns>/status` (`meas_accepted`), so a feed and
the capacity benchmark treat it as a tracker. The service's throughput is compared with
this process's, measured in the same run (bench/bench_capacity.py --throughput).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run from a checkout

from zenoh_track.wire import Keys, add_zenoh_args, pack, unpack, zenoh_config  # noqa: E402

CHANNEL = 1 << 13  # as the service's measurement channel


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--reply-bytes", type=int, default=0, metavar="N",
                   help="pad each reply to about N bytes (a `pad` field), the size of the "
                        "service's `tracks/` body, to measure what the body's size costs")
    args = p.parse_args(argv)
    pad = bytes(max(0, args.reply_bytes - 40))
    keys = Keys(args.ns)
    session = zenoh.open(zenoh_config(args, serve=True))
    count = [0]
    targets: set[str] = set()  # the targets answered, as a tracker's tracks
    stop = threading.Event()
    sub = session.declare_subscriber(keys.space("meas"), zenoh.handlers.FifoChannel(CHANNEL))
    status = session.declare_queryable(
        keys.status, lambda q: q.reply(keys.status, pack({
            "meas_accepted": count[0], "tracks": len(targets), "queue": 0,
            "frames_published": 0, "frames_missed": 0})))
    token = session.liveliness().declare_token(keys.alive("echo"))
    block = zenoh.CongestionControl.BLOCK
    prefix = len(keys.space("meas")) - 2  # "<ns>/meas/"

    def work() -> None:
        put = session.put
        while not stop.is_set():
            s = sub.try_recv()
            if s is None:
                time.sleep(0.0005)
                continue
            key = str(s.key_expr)
            msg = unpack(s.payload.to_bytes())
            target = key[prefix:].split("/", 1)[1]
            reply = {"t": msg["t"], "id": target}
            if pad:
                reply["pad"] = pad
            put(keys.tracks(target), pack(reply), congestion_control=block)
            targets.add(target)
            count[0] += 1

    worker = threading.Thread(target=work, daemon=True)
    worker.start()
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    print("echo: ready", flush=True)
    done.wait()
    stop.set()
    worker.join(timeout=5)
    token.undeclare()
    status.undeclare()
    session.close()


if __name__ == "__main__":
    main()
