"""The client library's Picture keeps up with the service's frames: the decode of one
`frame` into NumPy columns (`Frame.from_payload`, what a Picture does with each frame)
beside the service's own encoding of it (`zenoh_track.adapter.encode.pack_frame`) and the wire's
plain per-track reading (`zenoh_track.wire.decode_frame`), at N tracks; then, live, one
publisher putting N-track frames at 30 Hz for D seconds through Zenoh on loopback to a
Picture read in the same Python process: frames received of those sent, dropped, and the
time from put to the reader holding the decoded frame. With `--instances K`: the cost of
one picture of N tracks drawn from K instances' frames (each of N / K tracks: K decodes
and the merge, `clients.lib.merge.Merge`) beside the decode of one frame of N.

    python bench/bench_picture.py [--sizes 1000 10000 100000] [--live 10000] [--duration 5]
    python bench/bench_picture.py --sizes 10000 --instances 4 --live 0
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time

import numpy as np
import zenoh

from zenoh_track.adapter.encode import pack_frame
from zenoh_track.clients import Client, Frame, Merge
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


def cpu(fn, *args) -> float:
    """The process's CPU time of one call of fn(*args), ms."""
    t0 = time.process_time()
    fn(*args)
    return 1e3 * (time.process_time() - t0)


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


def shards(n: int, k: int, steps: int, late: bool) -> list[list[bytes]]:
    """Each instant's frames of K instances holding N / K tracks each (`late`: the first
    instance's frames one period behind)."""
    ids, pos, vel, sigma, codes = columns(n)
    names = unpack(ids)
    out = []
    for s in range(steps):
        out.append([pack_frame(2.5 + (s - (late and j == 0)) / RATE,
                               pack([names[i] for i in rows]), pos[rows], vel[rows],
                               sigma[rows], codes[rows], f"shard-{j}")
                    for j, rows in enumerate(np.array_split(np.arange(n), k))])
    return out


def draw(instants: list[list[bytes]], kept: list[Frame | None]) -> int:
    """Decode and merge every frame as a Picture does (the first instant: a late
    joiner's replies), keeping the latest picture in kept[0]; the pictures drawn."""
    m, drawn = Merge(hold=None), 0
    for s, payloads in enumerate(instants):
        for j, body in enumerate(payloads):
            pics = m.add(Frame.from_payload(body), s / RATE, draw=s > 0)
            if not s and j == len(payloads) - 1:
                pics = m.ready(0.0)
            if pics:
                kept[0], drawn = pics[-1], drawn + len(pics)
    return drawn


def decode(bodies: list[bytes], kept: list[Frame | None]) -> None:
    """Decode every frame, keeping the latest in kept[0]."""
    for body in bodies:
        kept[0] = Frame.from_payload(body)


def merged(sizes: list[int], k: int, repeat: int = 21, steps: int = 60) -> None:
    """Per display instant: K frames of N / K tracks decoded and merged into one picture
    (what a client of K instances does), against one frame of N decoded; the instances'
    frames come in turn, the last completes the instant. Also with one instance a frame
    period behind (its rows moved on to the instant). Both keep their latest picture, as
    a viewer does; a new payload every instant, as a client gets them."""
    print(f"{'tracks':>8} {'one frame ms':>13} {f'{k} merged ms':>12} {'ratio':>6} "
          f"{'one behind ms':>14} {'ratio':>6}")
    for n in sizes:
        ids, pos, vel, sigma, codes = columns(n)
        wholes = [pack_frame(2.5 + s / RATE, ids, pos, vel, sigma, codes, "one")
                  for s in range(steps)]
        aligned, behind = shards(n, k, steps, False), shards(n, k, steps, True)
        kept: list[Frame | None] = [None]
        assert draw(aligned, kept) == steps and len(kept[0]) == n  # type: ignore[arg-type]
        assert draw(behind, kept) == steps and len(kept[0]) == n  # type: ignore[arg-type]
        runs: list[tuple[float, float, float]] = []
        for _ in range(repeat):  # interleaved, in CPU time: other processes do not count
            runs.append((cpu(decode, wholes, kept) / steps, cpu(draw, aligned, kept) / steps,
                         cpu(draw, behind, kept) / steps))
        dec, mer, lag = (statistics.median(r[i] for r in runs) for i in range(3))
        ratio = statistics.median(r[1] / r[0] for r in runs)
        ratio_lag = statistics.median(r[2] / r[0] for r in runs)
        print(f"{n:>8,} {dec:>13.3f} {mer:>12.3f} {ratio:>6.2f} {lag:>14.3f} "
              f"{ratio_lag:>6.2f}")
    print(f"  one frame: Frame.from_payload of N tracks; {k} merged: {k} frames of N/{k} "
          f"decoded and merged into the picture of the instant (Merge.add); one behind: "
          f"the same with one instance's frames a period late (moved on to the instant); "
          f"CPU ms per display instant (runs of {steps} instants), medians of {repeat} "
          f"interleaved runs; ratio: the median of each run's ratio to one frame")


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
    p.add_argument("--instances", type=int, default=0,
                   help="also the picture of N tracks merged from this many instances")
    args = p.parse_args()
    micro(args.sizes)
    if args.instances:
        merged(args.sizes, args.instances)
    if args.live:
        live(args.live, args.duration)


if __name__ == "__main__":
    main()
