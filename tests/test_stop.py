"""Every program stops on the first SIGINT/SIGTERM whatever thread the signal lands on
and whatever it is doing, with the service's state saved; at once on a second signal
(`zenoh_track.wire.stopping`). Real processes, real signals."""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import textwrap
import time

import pytest
from stop_runs import GONE_WITHIN, Start, plan, run_all

from zenoh_track.wire import STOP_GRACE, free_port

# a program that installs the stop, then has a thread of its own take a SIGTERM (the
# case where CPython's handler never runs in a main thread blocked without a timeout)
PROGRAM = textwrap.dedent("""
    import os, signal, sys, threading, time
    from zenoh_track.wire import on_signals
    stop = on_signals(grace={grace})
    def other_thread():
        print("ready", flush=True)
        for _ in range({signals}):
            sys.stdin.readline()
            signal.pthread_kill(threading.get_ident(), signal.SIGTERM)
    threading.Thread(target=other_thread, daemon=True).start()
    if "{main}" == "waits":
        stop.wait()
        print("stopped in order", flush=True)
    else:  # blocked for ever in a lock, never looking at the stop
        lock = threading.Lock()
        lock.acquire()
        lock.acquire()
""")


def signalled(main: str, signals: int, grace: float) -> tuple[int, str, float]:
    proc = subprocess.Popen([sys.executable, "-c", PROGRAM.format(
        main=main, signals=signals, grace=grace)], stdin=subprocess.PIPE,
        stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline() == "ready\n"
    start = time.monotonic()
    for _ in range(signals):
        proc.stdin.write("\n")
        proc.stdin.flush()
    try:
        out, _ = proc.communicate(timeout=grace + 10)
    finally:
        proc.kill()
    return proc.returncode, out, time.monotonic() - start


def test_a_signal_taken_by_another_thread_stops_a_waiting_main_thread():
    code, out, took = signalled("waits", 1, grace=30.0)
    assert (code, out) == (0, "stopped in order\n")
    assert took < 5.0


def test_a_main_thread_that_never_looks_is_ended_by_the_deadline():
    code, out, took = signalled("blocked", 1, grace=1.0)
    assert code == 128 + signal.SIGTERM and out == ""
    assert 1.0 <= took < 6.0


def test_a_second_signal_ends_the_program_at_once():
    code, _, took = signalled("blocked", 2, grace=60.0)
    assert code == 128 + signal.SIGTERM
    assert took < 10.0  # far below the 60 s grace the first signal armed


@pytest.mark.slow
def test_starts_stopped_at_random_moments(tmp_path):
    """A reduced count of bench/bench_stop.py's 200 (the same starts): first starts and
    warm ones, with and without --state, SIGTERM and SIGINT, to the service and to its
    group, and a lockstep first start stopped while it compiles."""
    rng = random.Random(7)
    starts = plan(8, rng) + [Start(first=True, state=True, clock="lockstep", group=True)]
    outcomes = run_all(starts, tmp_path, rng)
    bad = [(o.start, o.delay, o.banner, o.gone, o.problems) for o in outcomes if not o.ok]
    assert not bad, bad
    assert all(o.gone <= GONE_WITHIN for o in outcomes)
    assert any(o.tracks_loaded for o in outcomes), "no start had tracks to keep"
    assert STOP_GRACE < GONE_WITHIN


@pytest.mark.parametrize("mode,words", [
    ("peer", "nothing listens at tcp/127.0.0.1:"),
    ("client", "router unreachable: connection refused at 127.0.0.1:"),
])
def test_an_unreachable_endpoint_is_named_by_the_topology(mode, words):
    port = free_port()
    out = subprocess.run([sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm",
                          "--targets", "1", "-e", f"tcp/127.0.0.1:{port}", "--mode", mode,
                          "--connect-timeout", "0.5"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], out.stderr
    assert ("router" in lines[0]) == (mode == "client")
