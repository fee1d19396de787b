"""Starts of track-service stopped by a signal at a random moment, as a supervisor stops
them (tests/test_stop.py on a few, bench/bench_stop.py on many).

Each start: a fresh kernel cache or the warm one, with or without `--state` (a realtime
feed of labelled targets then gives it tracks), SIGTERM or SIGINT to the service alone or
to its process group, at a uniform moment from the spawn to 2 s after its banner (the
banner's time taken from the previous start of the same kind). A start passes when every
process of its group is gone within `GONE_WITHIN` s of the signal and, with `--state`,
the file loads into a service's tracker with at least every track it had published
before the signal.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from zenoh_track.wire import free_port, peer_config, wait_for_tracker

GONE_WITHIN = 5.0  # s: the target
AFTER_BANNER = 2.0  # s: the latest signal, after the banner
BANNER = b"track-service 0"  # the service's first line on stdout once it serves


@dataclass
class Start:
    first: bool  # an empty kernel cache (a machine's first start)
    state: bool  # --state, and a feed giving it tracks
    clock: str = "realtime"
    group: bool = False  # the signal to the process group, not the service alone
    sig: int = signal.SIGTERM


@dataclass
class Outcome:
    start: Start
    delay: float  # s from the spawn to the signal
    banner: float | None  # s from the spawn to the banner (None: signalled before it)
    gone: float  # s from the signal until every process of the group was gone
    tracks_seen: int = 0  # tracks published before the signal
    tracks_loaded: int | None = None  # tracks in the state file (None: no file)
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def load_state(path: Path) -> set[str]:
    """The ids of the tracks a service with the default options restores from `path`
    (raises CheckpointError when it would refuse the file)."""
    from zenoh_track.__main__ import parser, tracker_config
    from zenoh_track.tracking import checkpoint
    from zenoh_track.tracking.tracker import Tracker

    tracker = Tracker.from_config(tracker_config(parser().parse_args([])))
    checkpoint.load(tracker, path.read_bytes())
    return {tid for lay in tracker.store.layouts.values() for tid in lay.live()[1]}


class Seen:
    """Track ids published on `<ns>/tracks/*`, as a display sees them."""

    def __init__(self, session: zenoh.Session, ns: str) -> None:
        self.ids: set[str] = set()
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber(f"{ns}/tracks/*", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            with self.lock:
                self.ids.add(str(sample.key_expr).rsplit("/", 1)[-1])

    def snapshot(self) -> set[str]:
        with self.lock:
            return set(self.ids)


def run(start: Start, delay_hint: float, warm_cache: str, workdir: Path,
        rng: random.Random) -> Outcome:
    """One start, signalled at U(0, delay_hint + AFTER_BANNER) s after its spawn."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    ns = f"stop{rng.randrange(1 << 30):08x}"
    cache = tempfile.mkdtemp(prefix="kernels-", dir=workdir) if start.first else warm_cache
    state = workdir / f"{ns}.state"
    cmd = [sys.executable, "-m", "zenoh_track", "-l", endpoint, "--ns", ns,
           "--clock", start.clock, *(["--state", str(state)] if start.state else [])]
    env = {**os.environ, "NUMBA_CACHE_DIR": cache, "PYTHONUNBUFFERED": "1"}
    delay = rng.uniform(0.0, delay_hint + AFTER_BANNER)
    session = feed = seen = None
    t0 = time.monotonic()
    # a supervisor's child: SIGINT not ignored, even when this runs as a background job
    # (whose children inherit an ignored SIGINT, which the service then keeps ignoring)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env,
                            start_new_session=True, preexec_fn=default_sigint)
    banner: list[float] = []

    def read_banner() -> None:
        for line in proc.stdout:
            if line.startswith(BANNER) and not banner:
                banner.append(time.monotonic() - t0)

    reader = threading.Thread(target=read_banner, daemon=True)
    reader.start()
    try:
        if start.state:  # a feed and a display of what it publishes, as a user has
            session = zenoh.open(peer_config(endpoint))
            seen = Seen(session, ns)
            feed = subprocess.Popen(
                [sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm", "--targets",
                 "10", "--duration", "600", "--realtime", "-e", endpoint, "--ns", ns],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
        time.sleep(max(0.0, t0 + delay - time.monotonic()))  # the random moment itself
        had = seen.snapshot() if seen is not None else set()
        sent = time.monotonic()
        if start.group:
            os.killpg(proc.pid, start.sig)
        else:
            proc.send_signal(start.sig)
        try:
            proc.wait(timeout=GONE_WITHIN + 5)
        except subprocess.TimeoutExpired:
            pass
        while group_alive(proc.pid) and time.monotonic() - sent < GONE_WITHIN + 5:
            time.sleep(0.01)
        gone = time.monotonic() - sent
        out = Outcome(start, delay, banner[0] if banner else None, gone, len(had))
        if gone > GONE_WITHIN:
            out.problems.append(f"a process of the group alive {gone:.1f} s after the signal")
        if start.state and had:
            try:
                loaded = load_state(state)
            except Exception as exc:  # noqa: BLE001 - any failure to load is the finding
                out.problems.append(f"state file does not load: {exc}")
            else:
                out.tracks_loaded = len(loaded)
                if not had <= loaded:
                    out.problems.append(f"{len(had - loaded)} tracks published before the "
                                        "signal are not in the state file")
        return out
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        if feed is not None:
            feed.kill()
            feed.wait()
        if session is not None:
            session.close()


def warm(workdir: Path) -> str:
    """A kernel cache compiled once (the warm starts'), by a service that waits for it."""
    cache = tempfile.mkdtemp(prefix="kernels-warm-", dir=workdir)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "zenoh_track", "-l", endpoint,
                             "--clock", "lockstep"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env={**os.environ, "NUMBA_CACHE_DIR": cache})
    try:
        with zenoh.open(peer_config(endpoint)) as session:
            from zenoh_track.wire import Keys

            if not wait_for_tracker(session, Keys("track"), 1, timeout=300):
                raise RuntimeError("the warming service did not start")
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    return cache


def plan(n: int, rng: random.Random, clocks: tuple[str, ...] = ("realtime",)) -> list[Start]:
    """`n` starts: half first starts, half with --state (crossed), the signal and its
    target (the service, its group) alternating, clocks in turn."""
    starts = [Start(first=k % 2 == 0, state=(k // 2) % 2 == 0, clock=clocks[k % len(clocks)],
                    group=(k // 4) % 2 == 1,
                    sig=signal.SIGINT if (k // 8) % 2 else signal.SIGTERM) for k in range(n)]
    rng.shuffle(starts)
    return starts


def run_all(starts: list[Start], workdir: Path, rng: random.Random,
            report=None) -> list[Outcome]:
    """Every start in turn; `report(outcome)` after each."""
    cache = warm(workdir)
    hints: dict[tuple[bool, str], float] = {}
    outcomes = []
    for start in starts:
        kind = (start.first, start.clock)
        hint = hints.get(kind, 40.0 if start.first and start.clock == "lockstep" else 2.0)
        out = run(start, hint, cache, workdir, rng)
        if out.banner is not None:
            hints[kind] = out.banner
        outcomes.append(out)
        if report is not None:
            report(out)
    return outcomes
