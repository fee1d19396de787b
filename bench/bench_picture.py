"""The client library's Picture keeps up with the service's frames: the decode of one
`frame` into NumPy columns (`Frame.from_payload`, what a Picture does with each frame)
beside the service's own encoding of it (`zenoh_track.adapter.encode.pack_frame`) and the wire's
plain per-track reading (`zenoh_track.wire.decode_frame`), at N tracks; then, live, one
publisher putting N-track frames at 30 Hz for D seconds through Zenoh on loopback to a
Picture read in the same Python process: frames received of those sent, dropped, and the
time from put to the reader holding the decoded frame.

    python bench/bench_picture.py [--sizes 1000 10000 100000] [--live 10000] [--duration 5]
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time

import numpy as np
import zenoh

from zenoh_track.adapter.encode import pack_frame
from zenoh_track.clients import Client, Frame
from zenoh_track.wire import (
    MSGPACK_ENCODING,
    decode_frame,
    free_port,
    listen_config,
    pack,
    peer_config,
    unpack,
)

RATE = 30.0


def columns(n: int, seed: int = 1) -> tuple:
    rng = np.random.default_rng(seed)
    return (pack([f"swarm-{i:06d}" for i in range(n)]), rng.normal(0, 5e4, (n, 3)),
            rng.normal(0, 250, (n, 3)), rng.uniform(1, 80, n), rng.integers(0, 3, n))


def best(repeat: int, fn, *args) -> float:
    """The median of `repeat` timings of fn(*args) in ms (after one warm-up call)."""
    fn(*args)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def micro(sizes: list[int]) -> None:
    print(f"{'tracks':>8} {'encode ms':>10} {'decode ms':>10} {'dec/enc':>8} "
          f"{'budget %':>9} {'wire rows ms':>13} {'rows/dec':>9}")
    for n in sizes:
        ids, pos, vel, sigma, codes = columns(n)
        repeat = max(5, min(200, 2_000_000 // max(n, 1)))
        body = pack_frame(2.5, ids, pos, vel, sigma, codes)
        enc = best(repeat, pack_frame, 2.5, ids, pos, vel, sigma, codes)
        dec = best(repeat, Frame.from_payload, body)
        rows = best(max(3, repeat // 10), lambda b: decode_frame(unpack(b)), body)
        print(f"{n:>8,} {enc:>10.3f} {dec:>10.3f} {dec / enc:>8.2f} "
              f"{100 * dec * RATE / 1e3:>8.1f}% {rows:>13.2f} {rows / dec:>9.1f}")
    print("  encode: the service's pack_frame of the columns; decode: Frame.from_payload "
          "(the Picture's decoding); budget: decode time as a share of a 30 Hz frame "
          "period; wire rows: wire.decode_frame (per-track dicts), the plain reference")


def live(n: int, duration: float) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    pub_session = zenoh.open(listen_config(endpoint))
    client = Client(zenoh.open(peer_config(endpoint)), ns="benchpic")
    ids, pos, vel, sigma, codes = columns(n)
    frames = int(duration * RATE)
    put_at: dict[float, float] = {}
    lag: list[float] = []
    try:
        pic = client.picture(maxlen=8)
        publisher = pub_session.declare_publisher(
            "benchpic/frame", encoding=MSGPACK_ENCODING,
            congestion_control=zenoh.CongestionControl.BLOCK)
        matched = threading.Event()
        listener = publisher.declare_matching_listener(
            lambda status: matched.set() if status.matching else None)
        if not publisher.matching_status.matching and not matched.wait(10):
            raise SystemExit("the Picture's subscription never reached the publisher")
        listener.undeclare()

        def publish() -> None:
            start = time.monotonic()
            for k in range(frames):
                time.sleep(max(0.0, start + k / RATE - time.monotonic()))
                body = pack_frame(k / RATE, ids, pos, vel, sigma, codes)
                put_at[round(k / RATE, 9)] = time.monotonic()
                publisher.put(body)

        thread = threading.Thread(target=publish)
        thread.start()
        last = (frames - 1) / RATE
        while True:
            try:
                frame = pic.next(timeout=5.0)
            except TimeoutError:
                break
            lag.append(time.monotonic() - put_at[round(frame.t, 9)])
            if frame.t >= last - 1e-9:
                break
        thread.join()
        print(f"live, {n:,} tracks at {RATE:g} Hz for {duration:g} s: {pic.received} of "
              f"{frames} frames received, {pic.dropped} dropped, {len(lag)} read; put to "
              f"decoded frame in the reader: median {1e3 * statistics.median(lag):.1f} ms, "
              f"max {1e3 * max(lag):.1f} ms")
    finally:
        client.close()
        pub_session.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[1000, 10_000, 100_000])
    p.add_argument("--live", type=int, default=10_000, help="tracks of the live run (0: none)")
    p.add_argument("--duration", type=float, default=5.0)
    args = p.parse_args()
    micro(args.sizes)
    if args.live:
        live(args.live, args.duration)


if __name__ == "__main__":
    main()
