"""Benchmark of `track-foxglove`: frames a Foxglove protocol client receives per second,
and what a slow client gets.

    python bench/bench_foxglove.py                        # 1,000 and 10,000 tracks
    python bench/bench_foxglove.py --sizes 10000 --seconds 20 --slow 15

For each N this process publishes `<ns>/frame` at 30 Hz (N tracks on straight lines, all
statuses; bench_web's publisher) from a Zenoh peer on loopback, starts `track-foxglove
--origin ...` (a separate process) and connects the protocol client of the tests
(tests/foxglove_client.py, subprotocol foxglove.sdk.v1), subscribed to every channel as
the shipped layout is (scene, location fixes, counters, status). It prints, over
--seconds after a warm-up: scene messages received per second (over the whole intervals
from the first scene's arrival to the last's), MB/s, the server's time to encode a frame
(its /counters), the frames missing from those received (gaps in their times) of those
offered over the window, how many of them the server skipped (its client library's queue
of one: two frames came while it was busy) and how many it took but did not give this
client (it had not taken the previous one when a newer came), the frames the publisher
put more than a period late (back to back after a stall of its thread), and the server's
CPU. Then a second
client reads one message a second for --slow seconds (the tests' client, then one that
takes one message at a time off its socket and reads nothing ahead): how far behind the
newest frame each scene it reads is, how long ago the server took that frame from its
queue (the message's log time; it is given to a viewer within a frame period of that),
and the server's resident memory meanwhile.

The machine's load average is printed with the figures: other processes on the cores
lower them.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))  # the protocol client of the tests
sys.path.insert(0, str(ROOT / "bench"))

from bench_web import RATE, FramePublisher  # noqa: E402
from foxglove_client import FoxgloveClient, PlainViewer, message_class  # noqa: E402

from zenoh_track.clients.foxglove.server import (  # noqa: E402
    COUNTERS_TOPIC,
    FIXES_TOPIC,
    STATUS_TOPIC,
)
from zenoh_track.clients.lib import scene  # noqa: E402
from zenoh_track.clients.lib.process import stop  # noqa: E402
from zenoh_track.wire import free_port  # noqa: E402


class Publisher(FramePublisher):
    """bench_web's frames, the newest one's time kept (`t`) to measure lags against, and
    the frames put more than a period behind their time (`late`: after a stall, the
    frames due meanwhile are put back to back)."""

    t = 0.0
    late: list[float]  # set as the thread starts

    def run(self) -> None:
        import zenoh

        from zenoh_track.wire import Keys, pack

        pub = self.session.declare_publisher(Keys().frame,
                                             congestion_control=zenoh.CongestionControl.DROP)
        start, k, self.late = time.monotonic(), 0, []
        while not self.stopping.is_set():
            t = 1000.0 + k / RATE
            if time.monotonic() - (start + k / RATE) > 1 / RATE:
                self.late.append(t)
            pub.put(pack({"t": t, "ids": self.ids,
                          "pos": (self.pos + self.vel * (t - 1000.0)).astype("<f8").tobytes(),
                          "vel": self.vel.astype("<f8").tobytes(),
                          "sigma": self.sigma.astype("<f8").tobytes(),
                          "status": self.status.tobytes()}))
            self.t = t
            k += 1
            self.stopping.wait(max(start + k / RATE - time.monotonic(), 0.0))


TOPICS = (scene.TOPIC, FIXES_TOPIC, COUNTERS_TOPIC, STATUS_TOPIC)
TICK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


async def client(port: int, rcvbuf: int | None = None) -> FoxgloveClient:
    deadline = time.monotonic() + 60
    while True:
        c = FoxgloveClient()
        try:
            await c.connect(f"ws://127.0.0.1:{port}", advertised=set(TOPICS), rcvbuf=rcvbuf)
            return c
        except OSError:
            await c.close()
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)


async def fast(port: int, pid: int, n: int, seconds: float, warmup: float,
               publisher: Publisher) -> dict:
    c = await client(port)
    try:
        await c.subscribe(*TOPICS)
        start = time.monotonic()
        while True:  # until the scenes hold N tracks, then the warm-up
            topic, _, payload = await c.receive(60)
            if topic == COUNTERS_TOPIC and c.decode(topic, payload)["tracks"] >= n:
                break
            if time.monotonic() - start > 120:
                raise TimeoutError(f"the scenes never held {n} tracks")
        end = time.monotonic() + warmup
        while time.monotonic() < end:
            await c.receive(60)
        arrivals, size, encode, skipped, times, taken = [], 0, [], [], [], []
        late0 = len(publisher.late)
        cpu0, t0 = cpu_s(pid), time.monotonic()
        while time.monotonic() - t0 < seconds:
            topic, _, payload = await c.receive(60)
            if topic == scene.TOPIC:
                arrivals.append(time.monotonic())
                size += len(payload)
            elif topic == COUNTERS_TOPIC:
                counters = c.decode(topic, payload)
                encode.append(counters["encode_ms"])
                skipped.append(counters["skipped"])
                times.append(counters["t"])
                taken.append(counters["frames"])
        cpu1, wall = cpu_s(pid), time.monotonic() - t0
        # the rate over whole intervals between scenes: the first scene's arrival to the
        # last's, (scenes - 1) intervals
        scenes = len(arrivals)
        span = arrivals[-1] - arrivals[0]
        steps = np.round(np.diff(times) * RATE).astype(int)
        return {"scenes_per_s": (scenes - 1) / span, "mb_per_s": size / wall / 1e6,
                "mb_per_scene": size / max(scenes, 1) / 1e6,
                "encode_ms": sorted(encode)[len(encode) // 2] if encode else float("nan"),
                "skipped": skipped[-1] - skipped[0] if skipped else 0,
                "missing": int(np.sum(steps - 1)), "offered": int(np.sum(steps)),
                "not_given": int(np.sum(np.diff(taken) - 1)),
                "late": len([t for t in publisher.late[late0:] if times[0] < t <= times[-1]]),
                "cpu": (cpu1 - cpu0) / wall}
    finally:
        await c.close()


async def slow(port: int, pid: int, publisher: Publisher, seconds: int) -> dict:
    c = await client(port, rcvbuf=1 << 18)
    try:
        await c.subscribe(scene.TOPIC)
        lags, held, memory = [], [], []
        for _ in range(seconds):
            while True:
                topic, log_time, payload = await c.receive(60)
                if topic == scene.TOPIC:
                    break
            stamp = c.decode(topic, payload).entities[0].timestamp
            lags.append(publisher.t - (stamp.seconds + stamp.nanos / 1e9))
            held.append(time.time() - log_time / 1e9)
            memory.append(rss_mb(pid))
            await asyncio.sleep(1.0)
        return {"lags": lags, "held": held, "memory": memory}
    finally:
        await c.close()


def slow_plain(port: int, pid: int, publisher: Publisher, seconds: int) -> dict:
    """The slow client again, taking one message at a time off its socket and nothing
    ahead: only its kernel's receive buffer holds frames on its side."""
    viewer = PlainViewer(port, (scene.TOPIC,), rcvbuf=1 << 18, timeout=60)
    decode = message_class(scene.SCENE_SCHEMA, scene.schema(scene.SCENE_SCHEMA)).FromString
    try:
        lags, held, memory = [], [], []
        for _ in range(seconds):
            _, log_time, payload = viewer.receive()
            stamp = decode(payload).entities[0].timestamp
            lags.append(publisher.t - (stamp.seconds + stamp.nanos / 1e9))
            held.append(time.time() - log_time / 1e9)
            memory.append(rss_mb(pid))
            time.sleep(1.0)
        return {"plain_lags": lags, "plain_held": held, "plain_memory": memory}
    finally:
        viewer.close()


def run(n: int, args: argparse.Namespace) -> dict:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    publisher = Publisher(endpoint, n)
    port = free_port()
    fox = subprocess.Popen([sys.executable, "-m", "zenoh_track.clients.foxglove.server",
                            "-e", endpoint, "--port", str(port), "--origin", "48.85,2.35,35"],
                           stderr=subprocess.DEVNULL)
    try:
        out = asyncio.run(fast(port, fox.pid, n, args.seconds, args.warmup, publisher))
        if args.slow:
            out |= asyncio.run(slow(port, fox.pid, publisher, args.slow))
            out |= slow_plain(port, fox.pid, publisher, args.slow)
    finally:
        stop(fox)
        publisher.close()
    return out | {"n": n, "load": os.getloadavg()[0]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000])
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--warmup", type=float, default=3.0)
    p.add_argument("--slow", type=int, default=10, metavar="S",
                   help="seconds of the slow client (0: none)")
    args = p.parse_args()
    print(f"frames offered: {RATE:g} per second; the client subscribes {', '.join(TOPICS)}")
    print(f"{'tracks':>7} {'scenes/s':>9} {'MB/scene':>9} {'MB/s':>7} {'encode ms':>10} "
          f"{'missing':>8} {'skipped':>8} {'not given':>10} {'late':>5} {'server CPU':>11} "
          f"{'load':>5}")
    for n in args.sizes:
        r = run(n, args)
        print(f"{r['n']:>7} {r['scenes_per_s']:>9.1f} {r['mb_per_scene']:>9.2f} "
              f"{r['mb_per_s']:>7.0f} {r['encode_ms']:>10.1f} "
              f"{r['missing']:>4}/{r['offered']:<3} {r['skipped']:>8} {r['not_given']:>10} "
              f"{r['late']:>5} "
              f"{r['cpu']:>10.0%} {r['load']:>5.1f}", flush=True)
        if args.slow:
            for name, key in (("slow client (aiohttp, 1 read/s)", ""),
                              ("slow client (no read-ahead, 1 read/s)", "plain_")):
                print(f"        {name}: lag behind the newest frame, s: "
                      f"{' '.join(f'{x:.1f}' for x in r[key + 'lags'])}")
                print(f"          of which since the server took it, s: "
                      f"{' '.join(f'{x:.1f}' for x in r[key + 'held'])}")
                print(f"          server RSS, MB: "
                      f"{' '.join(f'{m:.0f}' for m in r[key + 'memory'])}", flush=True)


if __name__ == "__main__":
    main()
