"""A full `tracks/` listener in a process of its own, as a recorder or a gateway would be.

    python bench/full_listener.py ENDPOINT NS OUT [--key tracks/**]

Subscribes `<ns>/tracks/**` (or `--key`), and records every `tracks/<id>` message it
receives: the id, its `t` and its arrival. The samples wait in a FIFO channel (Zenoh's
default handler, as a recorder's would: about 2 us of this process's CPU per message,
against 9 us for a Python callback on Zenoh's receive thread) and a thread takes them
out; the arrival is stamped then (time.time(): never earlier than the true arrival, so
the latency is if anything overstated). It
prints `ready` once subscribed; a line on stdin (or its end) makes it write the records
to OUT (an .npz: `ids` (str), `t`, `arrival`, and `deletes`, the count of deletions) and
exit. bench/bench_capacity.py --full-listener starts it and pairs what it received with
the measurements sent.
"""

from __future__ import annotations

import argparse
import struct
import sys
import threading
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run from a checkout

import zenoh  # noqa: E402

from zenoh_track.wire import peer_config  # noqa: E402

CHANNEL = 1 << 16  # samples the channel holds before Zenoh pushes back


def t_of(body: bytes) -> float:
    """`t` of a tracks/ body: a map whose first key is "t" (0xa1 0x74), a float 64 (0xcb)
    read in place; anything else through msgpack."""
    if len(body) >= 12 and body[1] == 0xA1 and body[2] == 0x74 and body[3] == 0xCB:
        return struct.unpack_from(">d", body, 4)[0]
    up = msgpack.Unpacker(raw=False)
    up.feed(body[:64])
    up.read_map_header()
    up.skip()
    return float(up.unpack())


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("endpoint")
    p.add_argument("ns")
    p.add_argument("out")
    p.add_argument("--key", default="tracks/**", help="subscribed under <ns>/")
    p.add_argument("--callback", action="store_true",
                   help="a Python callback on Zenoh's receive thread instead of the FIFO "
                        "channel (arrivals stamped there; ~9 us of CPU a message)")
    args = p.parse_args(argv)
    ids: list[str] = []
    ts: list[float] = []
    arrivals: list[float] = []
    deletes = [0]
    cut = len(args.ns) + len("/tracks/")

    def on(sample: Any) -> None:
        now = time.time()
        if sample.kind != zenoh.SampleKind.PUT:
            deletes[0] += 1
            return
        ids.append(str(sample.key_expr)[cut:])
        ts.append(t_of(sample.payload.to_bytes()))
        arrivals.append(now)

    session = zenoh.open(peer_config(args.endpoint))
    handler: Any = zenoh.handlers.Callback(on, indirect=False) if args.callback else \
        zenoh.handlers.FifoChannel(CHANNEL)
    sub = session.declare_subscriber(f"{args.ns}/{args.key}", handler)

    def drain() -> None:
        if not args.callback:
            for sample in sub:  # until the subscriber is undeclared
                on(sample)

    taker = threading.Thread(target=drain, daemon=True)
    taker.start()
    print("ready", flush=True)
    sys.stdin.readline()
    sub.undeclare()
    taker.join(timeout=10)
    n = len(arrivals)
    np.savez(args.out, ids=np.array(ids[:n], dtype=str), t=np.array(ts[:n]),
             arrival=np.array(arrivals[:n]), deletes=np.array(deletes[0]))
    session.close()


if __name__ == "__main__":
    main()
