"""Capacity benchmark: the real service over Zenoh, in real time, on loopback.

    python bench/bench_capacity.py [--sizes 1000 5000 10000] [--modes frame display]
                                   [--duration 30] [--warmup 6]
    python bench/bench_capacity.py --minutes 10 --memory-targets 2000   # memory flatness

For each N and each display mode this starts, as separate processes on 127.0.0.1 (free
port, multicast scouting off):

    python -m zenoh_track --clock realtime --filter cv -l tcp/127.0.0.1:PORT [--no-display-keys]
    python -m zenoh_track.clients.feeds.feed swarm --targets N --realtime --duration D \
        -e tcp/127.0.0.1:PORT

(N targets, one radar measurement each per second, reported by sector as the beam turns)
and observes them from this process's own Zenoh session:

- input: `<ns>/status` queried once a second, half-way between two scans (all of a
  scan's measurements have arrived by then if the service keeps up): measurements
  accepted per second over the steady window (after --warmup s), the inbox `queue` depth,
  frames_published / frames_missed. The offered rate is measured too, from the arrivals
  of the sampled measurement keys at this process (the feed can fall behind its pace).
- frames: a subscriber of `<ns>/frame` reads only the head of each message (t and the
  number of ids): inter-arrival jitter, the fraction of display instants n/30 that never
  arrived (missed by the service or dropped by Zenoh, congestion control DROP), and the
  lateness of each frame against its display instant (instant - offset, the offset
  estimated as the service does: max(t - arrival) of the measurements seen here).
- latency: `<ns>/tracks/<id>` and `<ns>/meas/*/<id>` of a sample of the targets (ids
  ending in fixed digits, `swarm-$*0`, so the sample is spread over the turn; at most
  --sample targets) are subscribed here; each tracks/ message is paired with the
  measurement of the same (id, t) and latency = arrival of the track - arrival of the
  measurement, both stamped by this process's clock on Zenoh's receive thread. That is
  the service's own latency (queueing, batch step, publication) plus one loopback hop,
  independent of the feed's pacing.
- display/ keys (mode `display`): `<ns>/display/**` is subscribed with a ring channel
  of one (Zenoh delivers every message to this process, which drops them in Rust), and
  a Python subscriber of --display-sample targets counts the display instants received
  per target.
- resources of the service process from /proc: CPU (user + sys, all threads, % of one
  core), CPU of its hottest Python thread (the worker), RSS (VmRSS); and the whole
  machine's busy fraction (/proc/stat), since the feed, this process and anything else
  running share the same cores.

A run is "sustained" when accepted >= 99 % of offered, status frames_missed <= 1 % of
the display instants and the inbox does not keep a backlog of a whole scan. Otherwise the
table says which limit was hit.

--minutes M runs one long run (N = --memory-targets, frame only unless --memory-mode
display), samples RSS every 10 s and reports its growth after --memory-warmup s.
Everything runs on 127.0.0.1; every process started is terminated (then killed) on the
way out, and each run is bounded by its duration plus fixed timeouts.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import math
import os
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import zenoh

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # run from a checkout

from procstat import cpu_seconds, rss_mb, thread_cpu  # noqa: E402  # bench/procstat.py

from zenoh_track.clients.evaluation.progress import bar  # noqa: E402
from zenoh_track.clients.lib.process import stop  # noqa: E402
from zenoh_track.wire import Keys, free_port, unpack, wait_for_tracker  # noqa: E402

RATE = 30.0
STOP_WAIT = 20.0  # s a process is given to exit on SIGTERM before it is killed


def machine_jiffies() -> tuple[int, int]:
    """(busy, total) jiffies of all CPUs."""
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:]]
    idle = v[3] + v[4]
    total = sum(v[:8])
    return total - idle, total


def wait_idle(limit: float, budget: float, log: Any) -> float:
    """Wait up to `budget` s for a 2-s sample of the machine to be less than `limit`
    busy (a fraction of all cores); return the busy fraction last seen."""
    end = time.time() + budget
    while True:
        b0, t0 = machine_jiffies()
        time.sleep(2.0)
        b1, t1 = machine_jiffies()
        busy = (b1 - b0) / max(1, t1 - t0)
        if busy < limit or time.time() >= end:
            if busy >= limit:
                log(f"# machine still {busy:.0%} busy after waiting {budget:.0f} s; running")
            return busy


# ---------------------------------------------------------------- helpers
def head(payload: bytes) -> tuple[float, int]:
    """t (and the length of the second field if it is an array) from the head of a map
    whose first key is "t": frame, tracks/, meas/ and display/ messages all start so."""
    up = msgpack.Unpacker(raw=False)
    up.feed(payload[:96])
    up.read_map_header()
    up.skip()
    t = up.unpack()
    n = -1
    try:
        up.skip()
        n = up.read_array_header()
    except Exception:  # not an array (tracks/, meas/): no count
        pass
    return float(t), n


def pct(a: np.ndarray | list, q: float) -> float:
    a = np.asarray(a, float)
    return float(np.percentile(a, q)) if a.size else float("nan")


def sample_suffix(n: int, sample: int) -> tuple[str, int]:
    """Id pattern of a sample of at most `sample` of the ids swarm-00000 ... swarm-<n-1>,
    by fixed last digits (spread over the burst), and its size."""
    for digits in range(0, 6):
        size = len([i for i in range(n) if i % 10**digits == 0])
        if size <= sample:
            return ("*" if digits == 0 else "swarm-$*" + "0" * digits), size
    return "swarm-00000", 1


def session_open(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    return zenoh.open(conf)


def direct(fn: Any) -> zenoh.handlers.Callback:
    # run on Zenoh's receive thread: arrival stamps are not delayed by a handler thread
    return zenoh.handlers.Callback(fn, indirect=False)


def service_flags(args: argparse.Namespace, display: bool = False) -> list[str]:
    """The service's options of a run: none (the defaults a new user gets: IMM, display/
    keys for whoever subscribes) or the tuned set (--filter cv --no-display-keys)."""
    if args.tuned:
        return ["--filter", "cv"] + ([] if display else ["--no-display-keys"])
    return ["--filter", args.filter] if args.filter else []


# ---------------------------------------------------------------- one run
class Observer:
    """Subscribers and samplers of one run; everything stamped with time.time()."""

    def __init__(self, session: zenoh.Session, keys: Keys, pattern: str, display: bool,
                 display_pattern: str, batched: bool = False, tracks: bool = True) -> None:
        self.keys = keys
        self.frames: list[tuple[float, float, int]] = []  # (arrival, t, ids)
        self.meas: list[tuple[str, float, float]] = []  # (id, t, arrival)
        self.tracks: list[tuple[str, float, float]] = []
        self.disp: list[tuple[str, float, float]] = []
        self.subs = [
            session.declare_subscriber(keys.frame, direct(self._on_frame)),
            session.declare_subscriber(keys.meas("*", pattern), direct(self._on(self.meas))),
        ]
        if tracks:  # else the full listener's (another process) are paired instead
            self.subs.append(session.declare_subscriber(keys.tracks(pattern),
                                                        direct(self._on(self.tracks))))
        if batched:  # the sampled rows of each batched scan (scan/<sensor>)
            self.suffix = pattern.split("$*")[-1] if "$*" in pattern else ""
            self.subs.append(session.declare_subscriber(keys.scan("*"),
                                                        direct(self._on_scan)))
        if display:
            # every display/ message delivered to this process, dropped in Rust
            self.subs.append(session.declare_subscriber(keys.display("*"),
                                                        zenoh.handlers.RingChannel(1)))
            self.subs.append(session.declare_subscriber(keys.display(display_pattern),
                                                        direct(self._on(self.disp))))

    def _on_frame(self, s: Any) -> None:
        now = time.time()
        if s.kind != zenoh.SampleKind.PUT:
            return
        t, n = head(s.payload.to_bytes())
        self.frames.append((now, t, n))

    def _on_scan(self, s: Any) -> None:
        now = time.time()
        msg = unpack(s.payload.to_bytes())
        ids, t = msg["ids"], msg["t"]
        times = np.frombuffer(t, "<f8") if isinstance(t, bytes) else np.full(len(ids), t)
        suffix = self.suffix
        self.meas.extend((k, float(times[i]), now) for i, k in enumerate(ids)
                         if k.endswith(suffix))

    def _on(self, out: list) -> Any:
        def cb(s: Any) -> None:
            now = time.time()
            if s.kind != zenoh.SampleKind.PUT:
                return
            key = str(s.key_expr)
            out.append((key[key.rindex("/") + 1:], head(s.payload.to_bytes())[0], now))
        return cb

    def close(self) -> None:
        for s in self.subs:
            try:
                s.undeclare()
            except Exception:
                pass


class Sampler(threading.Thread):
    """Every `period` s: service CPU / RSS / threads, machine busy, feed CPU."""

    def __init__(self, pid: int, period: float = 1.0) -> None:
        super().__init__(daemon=True)
        self.pid, self.period = pid, period
        self.feed_pid: int | None = None
        self.listener_pid: int | None = None
        self.rows: list[dict[str, Any]] = []
        self.halt = threading.Event()

    def run(self) -> None:
        nxt = time.time()
        while not self.halt.is_set():
            try:
                busy, total = machine_jiffies()
                row = {"wall": time.time(), "cpu": cpu_seconds(self.pid),
                       "rss": rss_mb(self.pid), "threads": thread_cpu(self.pid),
                       "busy": busy, "total": total, "feed_cpu": None,
                       "self_cpu": cpu_seconds(os.getpid())}
                if self.feed_pid:
                    try:
                        row["feed_cpu"] = cpu_seconds(self.feed_pid)
                    except (FileNotFoundError, ProcessLookupError):
                        pass
                if self.listener_pid:
                    try:
                        row["listener_cpu"] = cpu_seconds(self.listener_pid)
                    except (FileNotFoundError, ProcessLookupError):
                        pass
                self.rows.append(row)
            except (FileNotFoundError, ProcessLookupError):
                return
            nxt += self.period
            self.halt.wait(max(0.0, nxt - time.time()))


class StatusPoller(threading.Thread):
    """Queries <ns>/status once a second at phase `phase` of the scan period, once the
    scan clock (wall time of scan 0 at this process) is known."""

    def __init__(self, session: zenoh.Session, keys: Keys, scan0: Any, phase: float = 0.5):
        super().__init__(daemon=True)
        self.session, self.keys, self.scan0, self.phase = session, keys, scan0, phase
        self.rows: list[tuple[float, float, dict | None]] = []  # (asked, answered, status)
        self.halt = threading.Event()

    def ask(self, timeout: float = 2.0) -> tuple[float, float, dict | None]:
        asked = time.time()
        body = None
        try:
            for r in self.session.get(self.keys.status, timeout=timeout):
                if r.ok is not None:
                    body = unpack(r.ok.payload.to_bytes())
        except Exception:
            body = None
        return asked, time.time(), body

    def run(self) -> None:
        while not self.halt.is_set():
            w0 = self.scan0()
            now = time.time()
            if w0 is None:
                nxt = now + 0.2
            else:
                k = math.floor(now - w0 - self.phase) + 1
                nxt = w0 + k + self.phase
            if self.halt.wait(max(0.0, nxt - time.time())):
                return
            self.rows.append(self.ask())


def run_one(n: int, display: bool, args: argparse.Namespace, duration: float,
            warmup: float, log: Any, floor: bool = False) -> dict[str, Any]:
    """One run of the service (`floor`: of bench/echo.py in its place, replies of a
    `tracks/` body's size) against the feed, watched from this process."""
    ns = f"cap{uuid.uuid4().hex[:8]}"
    keys = Keys(ns)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    pattern, n_sample = sample_suffix(n, args.sample)
    dpattern, _ = sample_suffix(n, args.display_sample)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    svc_cmd = [sys.executable, "-m", "zenoh_track", "--clock", "realtime", "-l", endpoint,
               "--ns", ns, *service_flags(args, display)]
    if floor:
        from throughput import TRACKS_BODY  # bench/throughput.py

        svc_cmd = [sys.executable, str(ROOT / "bench" / "echo.py"), "-l", endpoint,
                   "--ns", ns, "--reply-bytes", str(TRACKS_BODY)]
    feed_cmd = [sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm", "--targets",
                str(n),
                "--realtime", "--duration", str(duration), "-e", endpoint, "--ns", ns,
                "--sectors", str(args.sectors)] + (["--batched"] if args.batched else [])
    svc = feed = session = obs = sampler = poller = listener = None
    full = getattr(args, "full_listener", False)
    listen_out = Path(tempfile.mkdtemp(prefix="full-listener-")) / "tracks.npz"
    svc_log = tempfile.TemporaryFile(mode="w+")
    feed_log = tempfile.TemporaryFile(mode="w+")
    res: dict[str, Any] = {"n": n, "mode": "echo" if floor else "display" if display else "frame",
                           "duration": duration, "sample": n_sample, "pattern": pattern,
                           "cmd_service": " ".join(svc_cmd[1:]), "cmd_feed": " ".join(feed_cmd[1:])}
    try:
        svc = subprocess.Popen(svc_cmd, cwd=ROOT, env=env, stdout=svc_log, stderr=svc_log)
        session = session_open(endpoint)
        if not wait_for_tracker(session, keys, 1, timeout=30):
            raise RuntimeError("service did not come up")
        obs = Observer(session, keys, pattern, display, dpattern, args.batched,
                       tracks=not full)
        sampler = Sampler(svc.pid, args.proc_period)
        if full:  # every tracks/ message, in a process of its own (bench/full_listener.py)
            listener = subprocess.Popen(
                [sys.executable, str(ROOT / "bench" / "full_listener.py"), endpoint, ns,
                 str(listen_out)] + (["--callback"] if full == "callback" else []),
                cwd=ROOT, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            if listener.stdout.readline().strip() != "ready":  # type: ignore[union-attr]
                raise RuntimeError("the full listener did not start")
            sampler.listener_pid = listener.pid
        sampler.start()

        def scan0() -> float | None:
            m = obs.meas
            if not m:
                return None
            return min(a - t for _, t, a in m[:200])  # wall of scan 0 at this process

        poller = StatusPoller(session, keys, scan0)
        poller.start()
        time.sleep(1.0)
        feed = subprocess.Popen(feed_cmd, cwd=ROOT, env=env, stdout=feed_log, stderr=feed_log)
        sampler.feed_pid = feed.pid
        try:
            feed.wait(timeout=duration + args.feed_timeout)
        except subprocess.TimeoutExpired:
            res["feed_timeout"] = True
            stop(feed, timeout=STOP_WAIT)
        feed_end = time.time()
        time.sleep(args.tail)  # let the service drain what it has queued
        res["final_status"] = poller.ask(timeout=10)[2]
        poller.halt.set()
        sampler.halt.set()
        poller.join(timeout=15)
        sampler.join(timeout=5)
        if listener is not None:
            listener.communicate("stop\n", timeout=60)
            got = np.load(listen_out)
            obs.tracks = list(zip(got["ids"].tolist(), got["t"].tolist(),
                                  got["arrival"].tolist(), strict=True))
            res["listener_deletes"] = int(got["deletes"])
        feed_log.seek(0)
        res["feed_out"] = feed_log.read().strip()[-500:]
        res.update(analyse(n, display, obs, sampler, poller, duration, feed_end, warmup,
                           n_sample, full))
        res["loadavg_end"] = os.getloadavg()
    finally:
        if obs is not None:
            obs.close()
        if poller is not None:
            poller.halt.set()
        if sampler is not None:
            sampler.halt.set()
        stop(feed, timeout=STOP_WAIT)
        stop(listener, timeout=STOP_WAIT)
        stop(svc, timeout=STOP_WAIT)
        listen_out.unlink(missing_ok=True)
        listen_out.parent.rmdir()
        if session is not None:
            session.close()
        if svc is not None and svc.returncode not in (0, -15, None):
            svc_log.seek(0)
            log(f"# service exited {svc.returncode}: {svc_log.read()[-2000:]}")
        svc_log.close()
        feed_log.close()
    return res


# ---------------------------------------------------------------- analysis
def analyse(n: int, display: bool, obs: Observer, sampler: Sampler, poller: StatusPoller,
            duration: float, feed_end: float, warmup: float, n_sample: int,
            full: bool = False) -> dict[str, Any]:
    r: dict[str, Any] = {}
    meas, tracks, frames = list(obs.meas), list(obs.tracks), list(obs.frames)
    if not meas:
        r["error"] = "no measurement seen"
        return r
    wall0 = min(a - t for _, t, a in meas)  # scan 0 left the feed no earlier than this
    m_arr = np.array([a for _, _, a in meas])
    order = np.argsort(m_arr)
    m_arr, m_off = m_arr[order], np.array([t - a for _, t, a in meas])[order]

    def offset_at(wall: float) -> float:
        """The realtime clock's offset as the service estimates it (max of t - arrival
        over the last 10 s), from the sampled measurements seen here."""
        i, j = np.searchsorted(m_arr, [wall - 10.0, wall], side="right")
        return float(m_off[i:j].max()) if j > i else float(m_off[:j].max())

    # the steady window, aligned half-way between scans: scans ceil(warmup) + 1 ... D - 1
    # (the feed's closing clock message, one scan after the last, is left outside: it
    # moves the service's realtime offset by up to one second)
    lo = wall0 + math.ceil(warmup) + 0.5
    hi = min(wall0 + round(duration) - 0.5, feed_end)
    # settled: every target has a track and less than half a scan is queued, at the
    # status query half-way between two scans. Before that the service is initiating
    # tracks and draining what queued meanwhile;
    # the window starts no earlier.
    ok = [s is not None and asked >= wall0 and s["tracks"] >= n and s["queue"] < n / 2
          for asked, _, s in poller.rows]
    ready = next((poller.rows[i][0] for i in range(len(ok)) if all(ok[i:i + 3])
                  and i + 3 <= len(ok)), None)  # three answers in a row
    r["ready_s"] = None if ready is None else ready - wall0
    if ready is not None and ready > lo:
        lo = wall0 + math.floor(ready - wall0) + 0.5
    r["window"] = hi - lo
    r["window_from_s"] = lo - wall0
    if hi - lo < 2:
        r["error"] = "window too short (duration - warmup)"
        return r

    # offered rate (sampled measurement arrivals, scaled) and the feed's pacing
    m_in = [(t, a) for _, t, a in meas if lo <= a < hi]
    r["offered"] = len(m_in) / (hi - lo) * n / n_sample if m_in else float("nan")
    r["feed_lag_p99"] = pct([a - (wall0 + t) for t, a in m_in], 99)

    # status: accepted per second between the first and last answer in the window
    inside = [(asked, ans, s) for asked, ans, s in poller.rows
              if lo - 0.2 <= asked <= hi + 0.2]
    st = [x for x in inside if x[2] is not None]
    r["status_timeouts"] = len(inside) - len(st)
    if len(st) >= 2:
        (a0, _, s0), (a1, _, s1) = st[0], st[-1]
        dt = a1 - a0
        r["accepted"] = (s1["meas_accepted"] - s0["meas_accepted"]) / dt
        r["frames_pub"] = (s1["frames_published"] - s0["frames_published"]) / dt
        r["frames_missed"] = s1["frames_missed"] - s0["frames_missed"]
        due = r["frames_missed"] + s1["frames_published"] - s0["frames_published"]
        r["frames_missed_frac"] = r["frames_missed"] / max(1, due)  # of the instants due
        q = [s["queue"] for _, _, s in st]
        r["queue_max"], r["queue_last"] = max(q), q[-1]
        r["status_delay_p99"] = pct([b - a for a, b, _ in st], 99)

    # frames at the subscriber
    fr = [(a, t, k) for a, t, k in frames if lo <= a < hi]
    if len(fr) >= 2:
        arr = np.array([a for a, _, _ in fr])
        ts = np.array([t for _, t, _ in fr])
        nn = np.rint(ts * RATE).astype(int)
        span = nn.max() - nn.min() + 1
        r["frames_recv"] = len(fr) / (hi - lo)
        r["frames_skipped_frac"] = 1 - len(np.unique(nn)) / span
        d = np.diff(arr)
        # a skipped instant after a normal gap comes from the clock's offset estimate moving
        # forward (the maximum of t - arrival over 10 s); after a long gap, from a late tick
        jump = np.diff(nn) > 1
        r["skips_clock"] = int((jump & (d < 1.5 / RATE)).sum())
        r["skips_late"] = int((jump & (d >= 1.5 / RATE)).sum())
        r["jitter_std_ms"] = float(np.std(d) * 1e3)
        r["interarrival_p99_ms"] = pct(d * 1e3, 99)
        r["interarrival_max_ms"] = float(d.max() * 1e3)
        late = arr - (ts - np.array([offset_at(a) for a in arr]))
        r["frame_late_p50_ms"] = pct(late * 1e3, 50)
        r["frame_late_p99_ms"] = pct(late * 1e3, 99)
        r["frames_late_frac"] = float(np.mean(late > 1 / RATE))
        # instants whose frame arrived within one period of it, of all the window's instants
        r["frames_on_time_frac"] = len(np.unique(nn[late <= 1 / RATE])) / span
        r["frame_ids"] = int(np.median([k for _, _, k in fr]))

    # latency: tracks/ arrival - meas/ arrival of the same (id, t)
    sent = {(i, round(t, 6)): a for i, t, a in meas}
    lat, seen = [], set()
    for i, t, a in tracks:
        key = (i, round(t, 6))
        m = sent.get(key)
        if m is not None and lo <= m < hi and key not in seen:
            seen.add(key)
            lat.append(a - m)
    n_meas_win = sum(1 for _, _, a in meas if lo <= a < hi)
    r["lat_n"] = len(lat)
    r["lat_unpaired_frac"] = 1 - len(lat) / n_meas_win if n_meas_win else float("nan")
    r["lat_p50_ms"] = pct(np.array(lat) * 1e3, 50)
    r["lat_p99_ms"] = pct(np.array(lat) * 1e3, 99)
    r["lat_max_ms"] = float(max(lat) * 1e3) if lat else float("nan")
    if full:  # at the full listener: every tracks/ message of the run, and the sample's
        sampled = {(i, round(t, 6)) for i, t, a in meas if lo <= a < hi}
        got = {(i, round(t, 6)) for i, t, _ in tracks}
        r["full_expected"] = len(sampled)
        r["full_missing"] = len(sampled - got)
        r["full_received"] = len(tracks)
        r["full_unique"] = len(got)

    # display/ keys at the sampled subscriber
    if display:
        dd = [(i, t) for i, t, a in obs.disp if lo <= a < hi]
        ids = {i for i, _ in dd}
        if ids:
            per = len(dd) / len(ids) / (hi - lo)
            r["display_rate"] = per  # display messages per second per target
            r["display_skipped_frac"] = max(0.0, 1 - per / RATE)

    # resources over the window
    rows = [x for x in sampler.rows if lo <= x["wall"] < hi]
    if len(rows) >= 2:
        a, b = rows[0], rows[-1]
        dt = b["wall"] - a["wall"]
        r["cpu_pct"] = (b["cpu"] - a["cpu"]) / dt * 100
        per_s = [(y["cpu"] - x["cpu"]) / (y["wall"] - x["wall"]) * 100
                 for x, y in zip(rows, rows[1:], strict=False)]
        r["cpu_pct_max1s"] = max(per_s)
        comm0 = a["threads"].get(sampler.pid, ("python", 0))[0]
        worker = 0.0
        for tid, (comm, c1) in b["threads"].items():
            if tid == sampler.pid or comm != comm0 or tid not in a["threads"]:
                continue
            worker = max(worker, (c1 - a["threads"][tid][1]) / dt * 100)
        r["worker_cpu_pct"] = worker
        r["machine_busy_pct"] = (b["busy"] - a["busy"]) / max(1, b["total"] - a["total"]) * 100
        r["observer_cpu_pct"] = (b["self_cpu"] - a["self_cpu"]) / dt * 100
        r["machine_cores"] = os.cpu_count()
        if a["feed_cpu"] is not None and b["feed_cpu"] is not None:
            r["feed_cpu_pct"] = (b["feed_cpu"] - a["feed_cpu"]) / dt * 100
        if "listener_cpu" in a and "listener_cpu" in b:
            r["listener_cpu_pct"] = (b["listener_cpu"] - a["listener_cpu"]) / dt * 100
        # cores busy with anything else than the service, the feed and this process
        r["other_cores"] = max(0.0, (r["machine_busy_pct"] * r["machine_cores"] - r["cpu_pct"]
                                     - r.get("feed_cpu_pct", 0) - r["observer_cpu_pct"]
                                     - r.get("listener_cpu_pct", 0)) / 100)
        r["rss_mb"] = b["rss"]
        r["rss_max_mb"] = max(x["rss"] for x in rows)
    r["rss_series"] = [(round(x["wall"] - wall0, 1), round(x["rss"], 1)) for x in sampler.rows]
    rs = sampler.rows
    r["cpu_series"] = [(round(y["wall"] - wall0, 1),
                        round((y["cpu"] - x["cpu"]) / (y["wall"] - x["wall"]) * 100, 1))
                       for x, y in zip(rs, rs[1:], strict=False)]
    r["verdict"] = verdict(n, r)
    return r


def verdict(n: int, r: dict[str, Any]) -> str:
    """sustained / frames missed (input kept up) / saturated, with the limits hit."""
    inp, frm, ctx = [], [], []
    if r.get("ready_s") is None:
        inp.append("never settled (not every target tracked with < N/2 queued)")
    off = r.get("offered", float("nan"))
    if off < 0.97 * n:
        ctx.append(f"feed paced {off / n:.0%} of N")
    if r.get("accepted", 0) < 0.99 * min(off, n):
        inp.append(f"accepted {r.get('accepted', 0) / n:.0%} of N")
    if r.get("queue_max", 0) >= n:
        inp.append(f"inbox backlog up to {r.get('queue_max')}")
    if r.get("status_timeouts", 0):
        inp.append(f"{r['status_timeouts']} status queries unanswered in 2 s")
    if r.get("frames_missed_frac", 0) > 0.01:
        frm.append(f"frames missed {r['frames_missed_frac']:.0%}")
    if r.get("frames_skipped_frac", 0) > 0.01:
        frm.append(f"instants not received {r['frames_skipped_frac']:.0%}")
    if r.get("frames_late_frac", 0) > 0.01:
        frm.append(f"frames late {r['frames_late_frac']:.0%}")
    if r.get("worker_cpu_pct", 0) > 85:
        ctx.append(f"worker thread {r['worker_cpu_pct']:.0f}% of a core")
    if r.get("other_cores", 0) > 0.3:
        ctx.append(f"other load {r['other_cores']:.1f} cores")
    tail = f" [{', '.join(ctx)}]" if ctx else ""
    if inp:
        return "SATURATED: " + ", ".join(inp + frm) + tail
    if frm:
        return "input sustained; " + ", ".join(frm) + tail
    return "sustained" + tail


# ---------------------------------------------------------------- output
def fmt(x: Any, spec: str) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return format(x, spec)


def table(results: list[dict[str, Any]]) -> str:
    nan = float("nan")
    lines = [f"{'N':>6} {'mode':>7} {'ready':>5} {'offered':>7} {'accept':>7} {'late%':>6} "
             f"{'fr/s':>5} {'miss%':>5} {'skip%':>5} {'jit':>5} {'late99':>6} "
             f"{'lat50':>6} {'lat99':>6} {'cpu%':>5} {'wrk%':>5} {'other':>5} {'RSS':>5}"]
    for r in results:
        lines.append(
            f"{r['n']:>6} {r['mode']:>7} {fmt(r.get('ready_s'), '5.1f')} "
            f"{fmt(r.get('offered'), '7.0f')} {fmt(r.get('accepted'), '7.0f')} "
            f"{fmt(100 * r.get('frames_late_frac', nan), '6.2f')} "
            f"{fmt(r.get('frames_pub'), '5.1f')} "
            f"{fmt(100 * r.get('frames_missed_frac', nan), '5.1f')} "
            f"{fmt(100 * r.get('frames_skipped_frac', nan), '5.1f')} "
            f"{fmt(r.get('jitter_std_ms'), '5.1f')} {fmt(r.get('frame_late_p99_ms'), '6.0f')} "
            f"{fmt(r.get('lat_p50_ms'), '6.0f')} {fmt(r.get('lat_p99_ms'), '6.0f')} "
            f"{fmt(r.get('cpu_pct'), '5.0f')} {fmt(r.get('worker_cpu_pct'), '5.0f')} "
            f"{fmt(r.get('other_cores'), '5.2f')} {fmt(r.get('rss_mb'), '5.0f')}")
    lines.append("""\
  ready: s from scan 0 until every target has a track and the inbox holds < N/2 (three
    status answers in a row); the steady window starts then (or after --warmup) and ends
    half a scan before the last
  offered / accept: measurements per second sent by the feed / accepted by the service;
    late%: frames received more than one frame period (33 ms) after their instant
  fr/s: frames published per s; miss%: status frames_missed, % of the instants due;
    skip%: display instants n/30 never received by the frame subscriber
  jit: std of frame inter-arrival, ms; late99: p99 of frame arrival - its instant's
    wall time (offset estimated as the service does), ms
  lat50 / lat99: tracks/<id> arrival - meas/.../<id> arrival, same (id, t), ms
  cpu%: service process, all threads, % of one core; wrk%: its busiest Python thread (the
    worker); other: cores busy with anything but the service, the feed and this process;
    RSS: service VmRSS at the end of the window, MB""")
    for r in results:
        extra = ""
        if r["mode"] == "display" and "display_rate" in r:
            extra = f"; display/ msgs per target {r['display_rate']:.1f}/s"
        lines.append(f"  N={r['n']} {r['mode']}: {r.get('verdict', r.get('error'))}\n"
                     f"    (window {fmt(r.get('window_from_s'), '.1f')} s + "
                     f"{fmt(r.get('window'), '.0f')} s; sample {r['sample']} ids "
                     f"'{r['pattern']}', {r.get('lat_n', 0)} pairs, unpaired "
                     f"{fmt(100 * r.get('lat_unpaired_frac', nan), '.1f')}%; feed CPU "
                     f"{fmt(r.get('feed_cpu_pct'), '.0f')}%, feed lag p99 "
                     f"{fmt(r.get('feed_lag_p99'), '.2f')} s; observer CPU "
                     f"{fmt(r.get('observer_cpu_pct'), '.0f')}%; skipped instants after a "
                     f"long gap {r.get('skips_late', '-')}, after a normal one "
                     f"{r.get('skips_clock', '-')}{extra})")
        if "full_expected" in r:
            lines.append(full_line(r))
    return "\n".join(lines)


def full_line(r: dict[str, Any]) -> str:
    """What the full listener (another process, `tracks/**`) received, and the frames."""
    nan = float("nan")
    acc = (r.get("final_status") or {}).get("meas_accepted")
    return (f"    full listener (tracks/**, another process): {r['full_received']} messages, "
            f"{r['full_unique']} (id, t) of {fmt(acc, 'd')} measurements accepted in the "
            f"run; of the window's sampled measurements {r['full_missing']} of "
            f"{r['full_expected']} missing; lat p99 {fmt(r.get('lat_p99_ms'), '.0f')} ms "
            f"max {fmt(r.get('lat_max_ms'), '.0f')} ms; frames on time "
            f"{fmt(100 * r.get('frames_on_time_frac', nan), '.2f')} %, largest gap "
            f"{fmt(r.get('interarrival_max_ms'), '.0f')} ms; listener CPU "
            f"{fmt(r.get('listener_cpu_pct'), '.0f')}%")


def floor_report(results: list[dict[str, Any]]) -> str:
    """Each run's tracks/ latency against the echo floor's right after it."""
    lines = ["latency against the echo floor (bench/echo.py on the same load, right after):"]
    for ours, echo in zip(results[::2], results[1::2], strict=False):
        a, b = ours.get("lat_p99_ms"), echo.get("lat_p99_ms")
        ratio = a / b if a and b else float("nan")
        lines.append(f"  N={ours['n']} {ours['mode']}: p99 {fmt(a, '.0f')} ms, echo "
                     f"{fmt(b, '.0f')} ms, {fmt(ratio, '.2f')} x; p50 "
                     f"{fmt(ours.get('lat_p50_ms'), '.0f')} ms, echo "
                     f"{fmt(echo.get('lat_p50_ms'), '.0f')} ms; CPU "
                     f"{fmt(ours.get('cpu_pct'), '.0f')} %, echo "
                     f"{fmt(echo.get('cpu_pct'), '.0f')} %")
    return "\n".join(lines)


def memory_report(r: dict[str, Any], warmup: float, every: float = 10.0) -> str:
    series = r["rss_series"]
    pts, nxt = [], 0.0
    for t, v in series:
        if t >= nxt:
            pts.append((t, v))
            nxt = (math.floor(t / every) + 1) * every
    after = [(t, v) for t, v in pts if t >= warmup and t <= r["duration"]]
    lines = ["RSS of the service every 10 s (s since scan 0: MB)",
             "  " + "  ".join(f"{t:.0f}:{v:.1f}" for t, v in pts)]
    cpu = r.get("cpu_series", [])
    if cpu:
        per = {}
        for t, c in cpu:
            per.setdefault(int(t // every), []).append(c)
        lines.append("service CPU, mean % of one core per 10 s (s since scan 0: %)")
        lines.append("  " + "  ".join(f"{k * every:.0f}:{np.mean(v):.0f}"
                                      for k, v in sorted(per.items()) if k >= 0))
    if len(after) >= 2:
        t0, v0 = after[0]
        t1, v1 = after[-1]
        slope = np.polyfit([t for t, _ in after], [v for _, v in after], 1)[0] * 60
        lines.append(f"  after warm-up ({t0:.0f} s .. {t1:.0f} s): {v0:.1f} MB -> {v1:.1f} MB, "
                     f"growth {100 * (v1 - v0) / v0:+.2f} %, least-squares slope "
                     f"{slope:+.3f} MB/min; max {max(v for _, v in after):.1f} MB")
    return "\n".join(lines)


def declare_scaling(total: int, step: int, log: Any) -> None:
    """Cost of Session.declare_publisher as publishers accumulate in one session, against
    Session.put on undeclared keys: why the service and the feed put on key expressions
    instead of declaring a publisher per target (O(N^2) to start N tracks)."""
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    s = zenoh.open(conf)
    try:
        pubs, t0 = [], time.perf_counter()
        log("declare_publisher, one session, no peer: microseconds per declaration")
        for i in range(total):
            pubs.append(s.declare_publisher(f"scaling/tracks/swarm-{i:05d}"))
            if (i + 1) % step == 0:
                now = time.perf_counter()
                log(f"  publishers {i + 1 - step:>6} .. {i + 1:>6}: "
                    f"{(now - t0) / step * 1e6:8.0f} us")
                t0 = now
        t0 = time.perf_counter()
        for i in range(step):
            s.put(f"scaling/other/swarm-{i:05d}", b"x" * 600)
        log(f"Session.put on {step} undeclared keys: "
            f"{(time.perf_counter() - t0) / step * 1e6:.1f} us per put")
    finally:
        s.close()


# ---------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[1000, 5000, 10000])
    p.add_argument("--modes", nargs="+", choices=("frame", "display"),
                   default=["frame", "display"],
                   help="frame: --no-display-keys; display: per-target display/ keys too")
    p.add_argument("--duration", type=float, default=60.0, help="feed duration per run, s")
    p.add_argument("--warmup", type=float, default=6.0, help="s after scan 0 not measured")
    p.add_argument("--filter", default=None,
                   help="the service's --filter (default: none given, the service's IMM)")
    p.add_argument("--tuned", action="store_true",
                   help="the tuned flags: --filter cv and, in mode frame, --no-display-keys")
    p.add_argument("--sectors", type=int, default=32,
                   help="feed reports per radar turn: 32 (sector reporting) or 1 (each "
                        "second's measurements in one burst)")
    p.add_argument("--batched", action="store_true",
                   help="the feed sends each sector as one batched scan (scan/<sensor>)")
    p.add_argument("--throughput", type=int, default=0, metavar="N",
                   help="instead of the sweep: measurements per second answered when a feed "
                        "of N targets sends as fast as it can, for the echo floor "
                        "(bench/echo.py) and the service with no flags and tuned, same run")
    p.add_argument("--echo-body", action="store_true",
                   help="--throughput: also the echo with replies of a tracks/ body's size")
    p.add_argument("--repeat", type=int, default=1, metavar="R",
                   help="--throughput: the contenders in turn R times, medians printed")
    p.add_argument("--scaleout", type=int, default=0, metavar="N",
                   help="instead of the sweep: the --throughput flood through a router, one "
                        "service against two shards (bench/throughput.py)")
    p.add_argument("--encode", type=int, nargs="*", default=None, metavar="N",
                   help="instead of the sweep: the worker's CPU per frame (empty step, "
                        "snapshot, Publisher.frame) at N IMM tracks, without and with a "
                        "subscriber of frame (default 10,000 and 100,000)")
    p.add_argument("--scan-cost", type=int, nargs="*", default=None, metavar="N",
                   help="instead of the sweep: CPU per row of batched scans of 10,000 rows "
                        "(check, one-pass apply) against the filter core, and the frame, at "
                        "N tracks (default 10,000 and 100,000; bench/throughput.py)")
    p.add_argument("--single-cost", type=int, nargs="*", default=None, metavar="N",
                   help="instead of the sweep: the worker's CPU per single labelled message "
                        "at N targets, against the echo's, in one process (default 5,000 "
                        "and 10,000; bench/single_cost.py)")
    p.add_argument("--pass-cost", type=int, nargs="*", default=None, metavar="K",
                   help="instead of the sweep: the worker's CPU per pass of K single messages "
                        "at 10,000 tracks by stage (take, parse, bulk, filter, outputs), the "
                        "fixed and per-row parts (default K = 1 16 64 128 312 1024; "
                        "bench/pass_cost.py)")
    p.add_argument("--full-listener", nargs="?", const="fifo", default=None,
                   choices=("fifo", "callback"),
                   help="a subscriber of <ns>/tracks/** in another process "
                        "(bench/full_listener.py, as a recorder or a gateway): every message "
                        "counted, the missing ones and the latency reported; its samples in "
                        "a FIFO channel (default) or a Python callback on Zenoh's thread")
    p.add_argument("--floor", action="store_true",
                   help="after each run, the same load answered by the echo floor "
                        "(bench/echo.py: decode, put a tracks/ body's size; no tracking, no "
                        "frames) and the latencies' ratio, same listener")
    p.add_argument("--scan-flood", type=int, nargs="*", default=None, metavar="N",
                   help="instead of the sweep: 20 batched scans of N rows (default 10,000) "
                        "put as fast as the service takes them: rows applied per second and "
                        "frames per second meanwhile, --repeat times (bench/scan_flood.py)")
    p.add_argument("--sample", type=int, default=1000,
                   help="at most this many targets' tracks/ and meas/ keys subscribed")
    p.add_argument("--display-sample", type=int, default=10,
                   help="display/ keys of this many targets counted in Python")
    p.add_argument("--tail", type=float, default=3.0, help="s after the feed ends")
    p.add_argument("--feed-timeout", type=float, default=90.0,
                   help="s allowed beyond --duration for the feed to finish")
    p.add_argument("--proc-period", type=float, default=1.0)
    p.add_argument("--minutes", type=float, default=0.0,
                   help="memory-flatness run of this many minutes instead of the sweep")
    p.add_argument("--memory-targets", type=int, default=2000)
    p.add_argument("--memory-mode", choices=("frame", "display"), default="frame")
    p.add_argument("--memory-warmup", type=float, default=60.0)
    p.add_argument("--idle-wait", type=float, default=0.0, metavar="S",
                   help="before each run, wait up to S s for the machine to be less than "
                        "--idle-below busy (other jobs distort the result)")
    p.add_argument("--idle-below", type=float, default=0.25)
    p.add_argument("--declare-scaling", type=int, default=0, metavar="K",
                   help="only time declaring K publishers in one session (in steps of K/8)")
    p.add_argument("--json", metavar="FILE", help="write the raw results here")
    args = p.parse_args(argv)

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # run the finally blocks

    def log(msg: str) -> None:
        print(msg, flush=True)

    log(f"# {datetime.datetime.now().isoformat(timespec='seconds')}; CPython "
        f"{platform.python_version()}, numpy {np.__version__}, eclipse-zenoh "
        f"{importlib.metadata.version('eclipse-zenoh')}, {platform.machine()}, "
        f"{os.cpu_count()} CPUs, "
        f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    results = []
    if args.declare_scaling:
        declare_scaling(args.declare_scaling, max(1, args.declare_scaling // 8), log)
        return
    if args.throughput:
        from throughput import throughput  # bench/throughput.py

        throughput(args, log)
        return
    if args.scaleout:
        from throughput import scaleout  # bench/throughput.py

        scaleout(args, log)
        return
    if args.encode is not None:
        from throughput import frame_cost  # bench/throughput.py

        frame_cost(args.encode or [10_000, 100_000], log)
        return
    if args.single_cost is not None:
        from single_cost import single_cost  # bench/single_cost.py

        single_cost(args.single_cost or [5_000, 10_000], log)
        return
    if args.pass_cost is not None:
        from pass_cost import pass_cost  # bench/pass_cost.py

        pass_cost(args.pass_cost or [1, 16, 64, 128, 312, 1024], log,
                  full=args.full_listener)
        return
    if args.scan_flood is not None:
        from scan_flood import scan_flood  # bench/scan_flood.py

        scan_flood(args, log)
        return
    if args.scan_cost is not None:
        from throughput import scan_cost  # bench/throughput.py

        scan_cost(args.scan_cost or [10_000, 100_000], log)
        return
    if args.minutes:
        d = args.minutes * 60
        log(f"# memory run: N={args.memory_targets} {args.memory_mode}, {d:.0f} s")
        if args.idle_wait:
            wait_idle(args.idle_below, args.idle_wait, log)
        r = run_one(args.memory_targets, args.memory_mode == "display", args, d,
                    args.memory_warmup, log)
        results.append(r)
        log(table(results))
        log(memory_report(r, args.memory_warmup))
    else:
        progress = bar(total=len(args.sizes) * len(args.modes), desc="service runs",
                       unit=" run", leave=False)
        for n in args.sizes:
            for mode in args.modes:
                if args.idle_wait:
                    wait_idle(args.idle_below, args.idle_wait, log)
                r = run_one(n, mode == "display", args, args.duration, args.warmup, log)
                results.append(r)
                log(f"# N={n} {mode}: {r.get('verdict', r.get('error'))}")
                if args.floor:  # the echo floor on the same load, right after
                    results.append(run_one(n, False, args, args.duration, args.warmup, log,
                                           floor=True))
                progress.update(1)
        progress.close()
        log(table(results))
        if args.floor:
            log(floor_report(results))
        if args.batched:  # scans: memory over the run too
            for r in results:
                if "rss_series" in r:
                    log(f"N={r['n']} {r['mode']} (load average at the end "
                        f"{' '.join(f'{x:.2f}' for x in r['loadavg_end'])}): "
                        + memory_report(r, args.warmup))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str))


if __name__ == "__main__":
    main()
