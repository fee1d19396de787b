"""The worker's CPU per pass of k single labelled messages at 10,000 tracks, split by
stage (bench/bench_capacity.py --pass-cost [K ...]).

A `TrackService` (no flags: the default IMM, realtime clock) on a real Zenoh session that
listens on loopback; another Zenoh session in this process puts the feed's messages
(`<ns>/meas/radar1/swarm-NNNNNN`, the swarm feed's form: t, r, az, el, sr, saz, sel, seq)
into the service's FIFO channel, and a consumer process subscribes to a sample of the
`tracks/` ids (`tracks/swarm-$*0`, one in ten, as bench_capacity.py's latency sample;
with --full-listener every id's, `tracks/**`, as a recorder or a gateway).
The service's worker thread is not started: this thread runs its steps, one pass per k
messages once they have all arrived in the channel, and its thread CPU is split into

    take     taking the messages from the channel into the worker's batch
    look     who listens to tracks/ (`Publisher.look`)
    parse    `_take_singles`: keys, `wire.parse_singles`, seq, time policy, clock
    bulk     `Tracker.step` outside the filter (association, deletion, initiation, states)
    filter   `Tracker._update_rows` (`Tracker.update`): the IMM kernel (service/estimation)
    outputs  `Publisher.batch`: counts, the tracks/<id> bodies and puts
    rest     the rest of `_process` / `_flush`

(medians over the passes). The fixed part is the pass of k = 1; the per-row part the
slope of a least-squares line through the passes of k >= 16. The frame (`_tick`) is left
out: it is the same whatever the measurements (bench_capacity.py --encode).
"""

from __future__ import annotations

import time
from collections import defaultdict
from typing import Any

import numpy as np
import zenoh
from single_cost import listened_service, start_consumer  # bench/single_cost.py

STAGES = ("take", "look", "parse", "bulk", "filter", "outputs", "rest")


class Stopwatch:
    """Thread CPU per stage of the current pass, by wrapping the callables."""

    def __init__(self) -> None:
        self.spent: dict[str, float] = defaultdict(float)

    def wrap(self, name: str, fn: Any) -> Any:
        clock, spent = time.thread_time, self.spent

        def timed(*args: Any, **kw: Any) -> Any:
            c0 = clock()
            try:
                return fn(*args, **kw)
            finally:
                spent[name] += clock() - c0
        return timed


def pass_cost(sizes: list[int], log: Any, tracks: int = 10_000, reps: int = 40,
              full: bool = False) -> None:
    from zenoh_track.tracking.batches import Instant
    from zenoh_track.wire import Keys, free_port, pack, peer_config

    ep = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", f'["{ep}"]')
    session = zenoh.open(conf)
    feeder = zenoh.open(peer_config(ep))
    keys = Keys("pc")
    listened = keys.tracks("**" if full else "swarm-$*0")  # every track's, or a sample
    consumer = start_consumer(ep, listened)
    arrived = [0]
    marker = session.declare_subscriber(keys.space("meas"), zenoh.handlers.Callback(
        lambda _: arrived.__setitem__(0, arrived[0] + 1), indirect=False))
    svc = None
    try:
        svc = listened_service(session, keys, consumer)
        end = time.monotonic() + 10
        probe = feeder.declare_publisher(keys.space("meas"))
        while not probe.matching_status.matching and time.monotonic() < end:
            time.sleep(0.01)  # the feeder knows the service's subscriber: nothing is lost
        probe.undeclare()
        ids = [f"swarm-{i:06d}" for i in range(tracks)]
        meas_keys = [zenoh.KeyExpr(keys.meas("radar1", i)) for i in ids]
        rng = np.random.default_rng(0)
        r0, az = rng.uniform(5e3, 8e4, tracks), rng.uniform(-3, 3, tracks)
        seq = [0]
        t0 = time.time()

        def payload(i: int, t: float) -> bytes:
            seq[0] += 1
            return pack({"t": t, "r": float(r0[i]) + 10.0 * (t - t0), "az": float(az[i]),
                         "el": 0.1, "sr": 20.0, "saz": 0.003, "sel": 0.003, "seq": seq[0]})

        def send(rows: range | list[int]) -> None:
            """Put the messages of `rows` (now) and wait until the channel holds them."""
            want = arrived[0] + len(rows)
            t = time.time()
            for i in rows:
                feeder.put(meas_keys[i % tracks], payload(i % tracks, t),
                           congestion_control=zenoh.CongestionControl.BLOCK)
            end = time.monotonic() + 10
            while arrived[0] < want and time.monotonic() < end:
                time.sleep(0.0005)
            time.sleep(0.002)  # the marker and the channel are fed by the same callback loop

        def gather(k: int) -> list[Any]:
            """The k messages sent, as the worker takes them (in one go unless the
            channel lags the marker: then again, sleeping between, which costs no CPU)."""
            batch = take()
            end = time.monotonic() + 10
            while messages(batch) < k and time.monotonic() < end:
                time.sleep(0.001)
                batch += take()
            return batch

        def messages(batch: list[Any]) -> int:
            """Messages in a batch (a run of singles holds many)."""
            return sum(len(x) if hasattr(x, "keys") else 1 for x in batch)

        def take() -> list[Any]:
            if hasattr(svc, "ingest"):
                return svc.ingest.next_batch(0.0)  # type: ignore[union-attr]
            if hasattr(svc, "_next_batch"):  # the code before the staged adapter
                return svc._next_batch(0.0)  # type: ignore[union-attr]
            svc._ingest()  # type: ignore[union-attr]  # the code before _next_batch
            batch = []
            try:
                batch.append(svc.inbox.get(timeout=0.0))  # type: ignore[union-attr]
                while len(batch) < 1024:
                    batch.append(svc.inbox.get_nowait())  # type: ignore[union-attr]
            except Exception:
                pass
            return batch

        def full_scan() -> None:  # every track measured (not timed), in the feed's sectors
            for lo in range(0, tracks, 1024):
                rows = range(lo, min(lo + 1024, tracks))
                send(rows)
                svc._process(gather(len(rows)))  # type: ignore[union-attr]

        full_scan()
        full_scan()
        watch = Stopwatch()
        svc._take_singles = watch.wrap("parse", svc._take_singles)  # type: ignore[method-assign]
        svc.out.look = watch.wrap("look", svc.out.look)  # type: ignore[method-assign]
        svc.out.batch = watch.wrap("outputs", svc.out.batch)  # type: ignore[method-assign]
        svc.tracker._update_rows = watch.wrap(  # type: ignore[method-assign]
            "filter", svc.tracker._update_rows)
        plain, timed = svc.tracker.step, watch.wrap("bulk", svc.tracker.step)
        svc.tracker.step = lambda scan, *a, **k: (  # type: ignore[method-assign]
            plain if isinstance(scan, Instant) else timed)(scan, *a, **k)  # frames: "rest"
        clock = time.thread_time
        log(f"worker CPU per pass of k single messages at {tracks} tracks (no flags: IMM, "
            f"realtime; a consumer of {listened[3:]}), median of {reps} passes, us:")
        log(f"{'k':>6} " + " ".join(f"{s:>8}" for s in STAGES) + f" {'total':>8} "
            f"{'non-filt':>8} {'per row':>8}")
        medians: dict[int, dict[str, float]] = {}
        start = 0
        try:
            for k in sizes:
                full_scan()  # no track ages out while the small passes run
                per: dict[str, list[float]] = defaultdict(list)
                for _ in range(reps):
                    send(range(start, start + k))
                    start = (start + k) % tracks
                    watch.spent.clear()
                    c0 = clock()
                    batch = gather(k)
                    c1 = clock()
                    svc._process(batch)  # type: ignore[union-attr]
                    c2 = clock()
                    assert messages(batch) == k, (messages(batch), k)
                    s = watch.spent
                    per["take"].append(c1 - c0)
                    per["bulk"].append(s["bulk"] - s["filter"])
                    for name in ("look", "parse", "filter", "outputs"):
                        per[name].append(s[name])
                    per["rest"].append(c2 - c1 - s["look"] - s["parse"] - s["bulk"]
                                       - s["outputs"])
                    per["total"].append(c2 - c0)
                    per["non-filter"].append(c2 - c0 - s["filter"])
                m = medians[k] = {n: float(np.median(v)) * 1e6 for n, v in per.items()}
                log(f"{k:>6} " + " ".join(f"{m[s]:>8.0f}" for s in STAGES)
                    + f" {m['total']:>8.0f} {m['non-filter']:>8.0f}"
                    f" {m['total'] / k:>8.1f}")
        finally:
            del svc.tracker.step  # the class's own again
        summary(medians, log)
        consumer.stdin.write("\n")  # type: ignore[union-attr]
        consumer.stdin.flush()  # type: ignore[union-attr]
        got = int(consumer.stdout.readline())  # type: ignore[union-attr]
        log(f"  the consumer received {got} tracks/ messages; counters: "
            f"{svc.count.meas_accepted} accepted, {svc.count.meas_rejected} rejected, "
            f"{svc.count.tracks_puts} tracks/ puts")
    finally:
        if svc is not None:
            svc.out.close()
        marker.undeclare()
        consumer.kill()
        consumer.wait()
        feeder.close()
        session.close()


def summary(medians: dict[int, dict[str, float]], log: Any) -> None:
    """The fixed part (k = 1) and the per-row part (slope over k >= 16) of each stage."""
    ks = sorted(k for k in medians if k >= 16)
    if 1 not in medians or len(ks) < 2:
        return
    log(f"{'':>6} " + " ".join(f"{s:>8}" for s in STAGES) + f" {'total':>8} {'non-filt':>8}")
    cols = (*STAGES, "total", "non-filter")
    fixed = " ".join(f"{medians[1][s]:>8.0f}" for s in cols)
    log(f"{'fixed':>6} {fixed}   us per pass (k = 1)")
    x = np.array(ks, dtype=float)
    slopes = [float(np.polyfit(x, [medians[k][s] for k in ks], 1)[0]) for s in cols]
    log(f"{'/row':>6} " + " ".join(f"{v:>8.2f}" for v in slopes)
        + f"   us per row (slope over k = {', '.join(map(str, ks))})")
