"""Start-up: seconds from `track-service` to its liveliness token, on a machine's first
start (Numba's cache empty: a fresh directory in NUMBA_CACHE_DIR) and on a warm one (the
cache filled), and how long the first 1,000 measurements after a first start take to
come back on `tracks/` (one burst of 1,000 labelled positions, one per target, put as
soon as the token is seen: the backlog is the time from the first put to the last
`tracks/` sample). A second tree (`--before PATH`, e.g. a `git worktree` of an earlier
commit) is measured in the same run, alternately, for the ratio.

`--through SECONDS`: a first start fed from its token on, a burst of `--burst` positions
each second for SECONDS (long enough for the kernels' compile, ~25 s here, and their
swap in): the backlog of every second's burst, its worst and when, so a stall of the
worker at the swap shows.

    python bench/bench_start.py --runs 3 --before /tmp/before
    python bench/bench_start.py --runs 1 --through 45
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import msgpack
import zenoh

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from zenoh_track.clients.lib.process import stop  # noqa: E402
from zenoh_track.wire import Keys, free_port, pack  # noqa: E402


def how(tree: Path, cache: str) -> tuple[dict[str, str], str, str]:
    """The environment, working directory and import name that run `tree`'s service: this
    tree as installed (`zenoh_track`), an earlier one from its folders (`service`, the
    import name before the rename; its own folder first on the path)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": cache}
    if tree == ROOT:
        return env, tempfile.gettempdir(), "zenoh_track"
    name = "zenoh_track" if (tree / "service" / "adapter").is_dir() and \
        "zenoh_track" in (tree / "pyproject.toml").read_text() else "service"
    return {**env, "PYTHONPATH": str(tree)}, str(tree), name


def listening(here: str) -> zenoh.Session:
    """A session listening on `here`: the service connects to it, so its token is seen
    as soon as it is declared (a session connecting to a service not yet listening would
    retry)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([here]))
    return zenoh.open(conf)


def serve(tree: Path, cache: str, endpoint: str, here: str) -> subprocess.Popen:
    """`tree`'s service with the kernel cache `cache`, listening on `endpoint` and
    connecting to `here`."""
    env, cwd, name = how(tree, cache)
    return subprocess.Popen([sys.executable, "-m", name, "-l", endpoint, "-e", here],
                            env=env, cwd=cwd,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def start(tree: Path, cache: str, burst: int) -> tuple[float, float]:
    """(seconds to the liveliness token, seconds from the burst's first put to its last
    `tracks/` sample; nan without a burst)."""
    endpoint, here = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    session = listening(here)
    alive, done = threading.Event(), threading.Event()
    got = [0]

    def on_tracks(_sample: zenoh.Sample) -> None:
        got[0] += 1
        if got[0] >= burst:
            done.set()

    token = session.liveliness().declare_subscriber(
        Keys("track").alive("**"), lambda s: alive.set(), history=True)
    sub = session.declare_subscriber("track/tracks/**", on_tracks)
    t0 = time.perf_counter()
    proc = serve(tree, cache, endpoint, here)
    try:
        if not alive.wait(300):
            raise SystemExit(f"no liveliness: {stop(proc)[-2000:]}")
        up = time.perf_counter() - t0
        backlog = float("nan")
        if burst:
            t1 = time.perf_counter()
            for k in range(burst):
                session.put(f"track/meas/r1/b{k}", pack({
                    "t": 0.0, "pos": [100.0 * k, 50.0, 10.0], "sigma": 10.0}))
            if not done.wait(120):
                raise SystemExit(f"{got[0]} of {burst} tracks/ samples")
            backlog = time.perf_counter() - t1
        return up, backlog
    finally:
        sub.undeclare()
        token.undeclare()
        session.close()
        stop(proc)


def through(tree: Path, cache: str, burst: int, seconds: int) -> list[float]:
    """A first start fed a burst a second for `seconds` from its token on: each burst's
    backlog (s, its first put to its last `tracks/` sample; nan if it was not all back
    within 30 s)."""
    endpoint, here = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    session = listening(here)
    alive = threading.Event()
    back: dict[int, int] = {}  # second -> tracks/ samples of its burst
    last: dict[int, float] = {}

    def on_tracks(sample: zenoh.Sample) -> None:
        k = int(round(msgpack.unpackb(sample.payload.to_bytes())["t"]))
        back[k] = back.get(k, 0) + 1
        last[k] = time.perf_counter()

    token = session.liveliness().declare_subscriber(
        Keys("track").alive("**"), lambda s: alive.set(), history=True)
    sub = session.declare_subscriber("track/tracks/**", on_tracks)
    proc = serve(tree, cache, endpoint, here)
    first: dict[int, float] = {}
    try:
        if not alive.wait(300):
            raise SystemExit(f"no liveliness: {stop(proc)[-2000:]}")
        t0 = time.perf_counter()
        for sec in range(seconds):
            time.sleep(max(0.0, t0 + sec - time.perf_counter()))
            first[sec] = time.perf_counter()
            for k in range(burst):
                session.put(f"track/meas/r1/b{k}", pack({
                    "t": float(sec), "pos": [100.0 * k + 150.0 * sec, 50.0, 10.0],
                    "sigma": 10.0}))
        end = time.perf_counter() + 30
        while back.get(seconds - 1, 0) < burst and time.perf_counter() < end:
            time.sleep(0.05)
        return [last[k] - first[k] if back.get(k, 0) >= burst else float("nan")
                for k in range(seconds)]
    finally:
        sub.undeclare()
        token.undeclare()
        session.close()
        stop(proc)


def fill(tree: Path, cache: str) -> None:
    """Compile the kernels of `tree` into `cache` (a warm machine)."""
    env, cwd, name = how(tree, cache)
    code = (f"from {name}.estimation import imm_jit; imm_jit.warm()\n"
            f"try:\n    from {name}.tracking import frame; frame.warm()\n"
            "except AttributeError:\n    pass\n")  # a tree before frame.warm existed
    subprocess.run([sys.executable, "-c", code], env=env, cwd=cwd, check=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--burst", type=int, default=1000)
    p.add_argument("--before", type=Path, help="an earlier tree, measured alternately")
    p.add_argument("--through", type=int, default=0, metavar="SECONDS",
                   help="a first start fed a burst a second for SECONDS instead")
    args = p.parse_args()
    trees = {"this": ROOT} | ({"before": args.before} if args.before else {})
    if args.through:
        for run in range(args.runs):
            for name, tree in trees.items():
                with tempfile.TemporaryDirectory() as cache:
                    got = through(tree, cache, args.burst, args.through)
                worst = max(range(len(got)), key=lambda k: got[k] if got[k] == got[k]
                            else float("inf"))
                print(f"run {run + 1}: {name}: {args.through} bursts of {args.burst} from "
                      f"a first start: backlog median {statistics.median(got):.3f} s, "
                      f"worst {got[worst]:.3f} s at second {worst}; per second: "
                      + " ".join(f"{g:.2f}" for g in got), flush=True)
        return
    rows: dict[str, dict[str, list[float]]] = {k: {"cold": [], "backlog": [], "warm": []}
                                               for k in trees}
    for run in range(args.runs):
        for name, tree in trees.items():
            with tempfile.TemporaryDirectory() as cache:
                up, backlog = start(tree, cache, args.burst)
                rows[name]["cold"].append(up)
                rows[name]["backlog"].append(backlog)
                fill(tree, cache)
                rows[name]["warm"].append(start(tree, cache, 0)[0])
            print(f"run {run + 1}: {name}: first start {up:.2f} s (first {args.burst} "
                  f"measurements back in {backlog:.2f} s), warm start "
                  f"{rows[name]['warm'][-1]:.2f} s", flush=True)
    print(f"\nmedian of {args.runs} runs, {os.cpu_count()} cores")
    print(f"{'tree':8} {'first start s':>14} {'first 1,000 s':>14} {'warm start s':>13}")
    for name, r in rows.items():
        print(f"{name:8} {statistics.median(r['cold']):14.2f} "
              f"{statistics.median(r['backlog']):14.2f} {statistics.median(r['warm']):13.2f}")
    if args.before:
        a, b = rows["this"], rows["before"]
        for what in ("cold", "warm"):
            print(f"{what} start: this / before = "
                  f"{statistics.median(a[what]) / statistics.median(b[what]):.2f}")


if __name__ == "__main__":
    main()
