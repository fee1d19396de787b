"""Soak: the compose topology under load for a bounded time, with faults injected.

    python bench/bench_soak.py --minutes 10 --targets 300     # the benchmark
    (tests/test_soak.py runs it for one minute in CI)

As processes on 127.0.0.1 (free port, multicast off, the deploy/ config files of
docker-compose.yml): `track-router -c deploy/router.json5`, the service as a client
(`-c deploy/shard-a.json5 --state FILE --delete-after 12`, realtime) and a realtime swarm
feed of --targets targets (`-c deploy/client.json5`). From this process, clients of the
router: an observer of the reliable keys (tracks/**, errors/**, the ghosts' display/
keys, a sample of meas/**), a slow subscriber (display/** and frame, blocking its receive
thread --slow-ms per sample, from 55 % to 70 % of the run) and an injector. Zenoh drops
display states for the slow subscriber (realtime DROP) but not deletions (BLOCK): each
one waits for it, up to the router's `block/wait_before_close` (5 s), and meanwhile the
service's link is held up too (docs/operations.md).

Faults: every second one bad input (unreadable MessagePack, a missing t, a negative
range, a non-finite value, in turn) and every 3 s a ghost target (two measurements, then
silence: deleted 12 s later); at 40 % of the run the router is stopped for --outage s and
started again. Checked at the end:
- nothing lost on reliable keys: the `updates` count of every track's tracks/ messages
  has no gap (outside the outage), every bad input has its errors/ message and is
  counted in status, every ghost's deletion is announced on tracks/ and display/;
- tracking resumed after the outage and no swarm track was lost;
- memory: the service's RSS at 30 % (warmed up), 50 % (after the outage), 80 % (after
  the slow subscriber) and at the end;
- latency: measurement -> tracks/ (pairs of (id, t) seen here, stamped on arrival) in
  the first and the last quarter of the run, outage excluded.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from zenoh_track.clients.lib.process import stop  # noqa: E402
from zenoh_track.wire import Keys, free_port, pack, quick_retry, unpack  # noqa: E402

DEPLOY = ROOT / "deploy"
DELETE_AFTER = 12.0  # s: ghosts go this long after their last measurement (> the outage
# and > the stalls a slow subscriber causes, so that no swarm track ages out meanwhile)
SLOW = (0.55, 0.70)  # the slow subscriber is there for this part of the run
BAD = [b"\xc1", pack({"r": 1.0, "az": 0.0}), None, None]  # None: made with the time


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return math.nan


def client(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config.from_file(str(DEPLOY / "client.json5"))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return zenoh.open(quick_retry(conf))


class Observer:
    """The reliable keys, stamped on arrival (monotonic)."""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self.lock = threading.Lock()
        self.updates: dict[str, list[tuple[float, int]]] = {}
        self.deleted: set[str] = set()
        self.display_deleted: set[str] = set()
        self.errors: list[dict] = []
        self.meas: dict[tuple[str, float], float] = {}
        self.latency: list[tuple[float, float]] = []  # (arrival, seconds)
        self.newest_t = -math.inf
        d = zenoh.handlers.Callback
        self.subs = [
            session.declare_subscriber(keys.space("tracks"), d(self.on_track, indirect=False)),
            session.declare_subscriber(keys.space("errors"), d(self.on_error, indirect=False)),
            session.declare_subscriber(keys.display("ghost-$*"), self.on_ghost_display),
            session.declare_subscriber(keys.meas("*", "swarm-$*0"), d(self.on_meas,
                                                                      indirect=False))]

    def on_track(self, s: Any) -> None:
        now = time.monotonic()
        tid = str(s.key_expr).rsplit("/", 1)[1]
        if s.kind == zenoh.SampleKind.DELETE:
            with self.lock:
                self.deleted.add(tid)
            return
        b = unpack(s.payload.to_bytes())
        with self.lock:
            self.updates.setdefault(tid, []).append((now, b["updates"]))
            self.newest_t = max(self.newest_t, b["t"])
            sent = self.meas.pop((tid, b["t"]), None)
            if sent is not None:
                self.latency.append((now, now - sent))

    def on_meas(self, s: Any) -> None:
        b = unpack(s.payload.to_bytes())
        with self.lock:
            self.meas[(str(s.key_expr).rsplit("/", 1)[1], b["t"])] = time.monotonic()
            if len(self.meas) > 100_000:
                self.meas.clear()

    def on_error(self, s: Any) -> None:
        with self.lock:
            self.errors.append(unpack(s.payload.to_bytes()))

    def on_ghost_display(self, s: Any) -> None:
        if s.kind == zenoh.SampleKind.DELETE:
            with self.lock:
                self.display_deleted.add(str(s.key_expr).rsplit("/", 1)[1])


class SlowSubscriber:
    """A consumer of display/** and frame that blocks its receive thread `ms` per sample."""

    def __init__(self, session: zenoh.Session, keys: Keys, ms: float) -> None:
        self.session, self.keys, self.ms = session, keys, ms
        self.count, self.subs = 0, []

    def on(self) -> None:
        self.subs = [self.session.declare_subscriber(k, self.slow)
                     for k in (self.keys.space("display"), self.keys.frame)]

    def off(self) -> None:
        for s in self.subs:
            s.undeclare()
        self.subs = []

    def slow(self, _: Any) -> None:
        self.count += 1
        time.sleep(self.ms / 1000)


def router_proc(endpoint: str) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-m", "zenoh_track.router", "-c",
                          str(DEPLOY / "router.json5"), "-l", endpoint],
                         stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    if "listening" not in p.stdout.readline():
        raise RuntimeError("router did not start")
    return p


def status(session: zenoh.Session, keys: Keys) -> dict:
    for r in session.get(keys.status, timeout=10):
        if r.ok is not None:
            return unpack(r.ok.payload.to_bytes())
    return {}


def run(minutes: float, targets: int, outage: float = 3.0, slow_ms: float = 2.0,
        log=print) -> dict[str, Any]:
    """One soak run; the figures and the checks' outcomes."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = Keys(f"soak{free_port()}")
    duration = minutes * 60
    tmp = tempfile.TemporaryDirectory()
    state = Path(tmp.name) / "soak.state"
    router = router_proc(endpoint)
    procs: list[subprocess.Popen] = []
    sessions: list[zenoh.Session] = []
    rep: dict[str, Any] = {"minutes": minutes, "targets": targets}
    try:
        svc = subprocess.Popen(
            [sys.executable, "-m", "zenoh_track", "-c", str(DEPLOY / "shard-a.json5"), "-e",
             endpoint, "--ns", keys.ns, "--instance", "soak", "--delete-after",
             str(DELETE_AFTER),
             "--state", str(state)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            text=True)
        procs.append(svc)
        obs_s, slow_s, inj = client(endpoint), client(endpoint), client(endpoint)
        sessions += [obs_s, slow_s, inj]
        obs = Observer(obs_s, keys)
        slow = SlowSubscriber(slow_s, keys, slow_ms)
        feed = subprocess.Popen(
            [sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm", "--targets",
             str(targets),
             "--duration", str(duration + 60), "--realtime", "-c",
             str(DEPLOY / "client.json5"), "-e", endpoint, "--ns", keys.ns],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        procs.append(feed)
        start = time.monotonic()
        while len(obs.updates) < targets and time.monotonic() - start < 60:
            time.sleep(0.1)
        start = time.monotonic()
        log(f"soak: {targets} targets tracked; running {duration:.0f} s")
        bad_sent, ghosts, rss = 0, [], []
        down = up = None
        tick = 0
        while (now := time.monotonic()) - start < duration:
            tick += 1
            if down is None and now - start >= 0.4 * duration:
                stop(router)
                down = time.monotonic()
                log(f"soak: router stopped at {down - start:.0f} s")
                time.sleep(outage)
                router = router_proc(endpoint)
                up = time.monotonic()
                continue
            if not slow.subs and SLOW[0] * duration <= now - start < SLOW[1] * duration:
                slow.on()
            elif slow.subs and now - start >= SLOW[1] * duration:
                slow.off()
            t = obs.newest_t
            if math.isfinite(t) and (up is None or now - up > 3):  # not across the outage
                kind = tick % len(BAD)
                payload = BAD[kind] if BAD[kind] is not None else pack(
                    {"t": t, "r": -5.0, "az": 0.0} if kind == 2 else {"t": t, "r": math.nan,
                                                                      "az": 0.0})
                inj.put(keys.meas("junk", f"bad-{tick}"), payload)
                bad_sent += 1
                if tick % 3 == 0:
                    g = f"ghost-{tick}"
                    for dt in (0.0, 0.5):
                        inj.put(keys.meas("ghost", g), pack({"t": t + dt, "pos": [1e3 * tick,
                                                                                   0.0]}))
                    ghosts.append((g, time.monotonic()))
            rss.append((now - start, rss_mb(svc.pid)))
            time.sleep(max(0.0, 1.0 - (time.monotonic() - now)))
        time.sleep(DELETE_AFTER + 2.0)  # the last ghosts age out and go
        st = status(obs_s, keys)
        end = time.monotonic()
        with obs.lock:
            updates = {k: list(v) for k, v in obs.updates.items()}
            errors, deleted = list(obs.errors), set(obs.deleted)
            display_deleted, latency = set(obs.display_deleted), list(obs.latency)
        # reliable keys: each track's tracks/ messages, in order, with no update missing
        gaps, outage_gaps = 0, 0
        for seq in updates.values():
            for (_, a), (arr, b) in zip(seq, seq[1:], strict=False):
                if b > a + 1:
                    if down is not None and down <= arr <= up + 5.0:
                        outage_gaps += b - a - 1
                    else:
                        gaps += b - a - 1
        swarm = {f"swarm-{i:05d}" for i in range(targets)}
        resumed = {k for k, v in updates.items() if k in swarm and v[-1][0] > up}
        # a ghost whose deletion fell in the outage had it announced to no one
        gone = {g: sent + DELETE_AFTER for g, sent in ghosts if sent < end - DELETE_AFTER - 2}
        due_ghosts = {g for g, when in gone.items() if not down - 2 <= when <= up + 4}
        first_q = [s for a, s in latency if a - start < duration / 4]
        last_q = [s for a, s in latency if a - start > duration * 3 / 4 and a - up > 5]
        warm = [m for s, m in rss if s >= 0.3 * duration]
        settled = [m for s, m in rss if s >= 0.5 * duration]
        late = [m for s, m in rss if s >= 0.8 * duration]
        rep.update(
            bad_sent=bad_sent, errors_received=len(errors),
            rejected=st.get("meas_rejected"), gaps=gaps, outage_gaps=outage_gaps,
            ghosts=len(due_ghosts), ghosts_deleted=len(due_ghosts & deleted),
            ghosts_display_deleted=len(due_ghosts & display_deleted),
            tracks=st.get("tracks"), swarm_resumed=len(resumed),
            swarm_deleted=len(swarm & deleted), frames_missed=st.get("frames_missed"),
            frames_published=st.get("frames_published"), slow_received=slow.count,
            lat_slow_max=max((x for a, x in latency
                              if SLOW[0] <= (a - start) / duration < SLOW[1] + 0.05),
                             default=math.nan),
            rss_warm_mb=warm[0] if warm else math.nan, rss_end_mb=rss[-1][1],
            rss_mid_mb=settled[0] if settled else math.nan,
            rss_late_mb=late[0] if late else math.nan,
            lat_first_p50=pct(first_q, 50), lat_first_p99=pct(first_q, 99),
            lat_last_p50=pct(last_q, 50), lat_last_p99=pct(last_q, 99),
            outage_s=(up - down) if down else None, alive=svc.poll() is None,
            lat_series=[(b * 5, round(max((x for a, x in latency if b * 5 <= a - start
                                            < b * 5 + 5), default=math.nan), 3))
                        for b in range(int(duration // 5))],
            state_written=state.is_file())
        return rep
    finally:
        for s in sessions:
            s.close()
        for p in reversed(procs):
            stop(p)
        stop(router)
        tmp.cleanup()


def pct(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q / 100 * (len(v) - 1))))]


def report(r: dict[str, Any]) -> str:
    ms = lambda s: f"{s * 1e3:.0f} ms"  # noqa: E731
    growth = (r["rss_end_mb"] / r["rss_late_mb"] - 1) * 100
    return "\n".join([
        f"soak {r['minutes']:g} min, {r['targets']} targets, router down "
        f"{r['outage_s']:.1f} s at 40 %, bad inputs every second, ghosts every 3 s, "
        "a slow subscriber",
        f"  service alive: {r['alive']}; tracks at the end {r['tracks']} (swarm "
        f"{r['targets']}, resumed after the outage {r['swarm_resumed']}, deleted "
        f"{r['swarm_deleted']})",
        f"  reliable keys: tracks/ updates missing {r['gaps']} (around the outage "
        f"{r['outage_gaps']}); errors/ {r['errors_received']} of {r['bad_sent']} bad "
        f"inputs (status meas_rejected {r['rejected']}); ghost deletions announced "
        f"tracks/ {r['ghosts_deleted']}/{r['ghosts']}, display/ "
        f"{r['ghosts_display_deleted']}/{r['ghosts']}",
        f"  frames published {r['frames_published']}, missed {r['frames_missed']}; the "
        f"slow subscriber (55-70 % of the run) took {r['slow_received']} display samples; "
        f"largest latency while it was there {ms(r['lat_slow_max'])}",
        f"  service RSS {r['rss_warm_mb']:.1f} MB at 30 % (before the outage), "
        f"{r['rss_mid_mb']:.1f} MB at 50 % (after it), {r['rss_late_mb']:.1f} MB at 80 % "
        f"(after the slow subscriber), {r['rss_end_mb']:.1f} MB at the end ({growth:+.1f} % "
        "over the last fifth)",
        f"  latency meas -> tracks/: first quarter p50 {ms(r['lat_first_p50'])} p99 "
        f"{ms(r['lat_first_p99'])}; last quarter p50 {ms(r['lat_last_p50'])} p99 "
        f"{ms(r['lat_last_p99'])}",
        f"  state file written: {r['state_written']}"])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--targets", type=int, default=300)
    p.add_argument("--outage", type=float, default=3.0, help="router down, s")
    p.add_argument("--slow-ms", type=float, default=2.0)
    args = p.parse_args()
    r = run(args.minutes, args.targets, args.outage, args.slow_ms)
    print(report(r), flush=True)
    ok = (r["gaps"] == 0 and r["errors_received"] == r["bad_sent"] == r["rejected"]
          and r["ghosts_deleted"] == r["ghosts"] == r["ghosts_display_deleted"]
          and r["swarm_resumed"] == r["targets"] and r["alive"])
    print("soak: " + ("passed" if ok else "FAILED"))
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
