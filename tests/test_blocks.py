"""A pass of rows over threads (`estimation.blocks`): parts taken by whichever thread is
free, each once."""

from __future__ import annotations

import threading

from zenoh_track import defaults
from zenoh_track.estimation import blocks


def test_a_thread_held_back_leaves_the_other_parts_to_the_caller(monkeypatch):
    monkeypatch.setattr(defaults, "PARALLEL_ROWS", 10)
    k, block, main = 400, 10, threading.get_ident()
    expected = blocks.parts(k, block, 2 * blocks.SHARES)
    assert len(expected) > 2  # more parts than threads
    done: list[tuple[int, int, bool]] = []
    lock, held, release = threading.Lock(), threading.Event(), threading.Event()

    def work(lo: int, hi: int) -> None:
        mine = threading.get_ident() == main
        if not mine and not held.is_set():
            held.set()  # the helper's first part waits until the caller did the rest
            assert release.wait(10)
        with lock:
            done.append((lo, hi, mine))
            if len(done) == len(expected) - 1:
                release.set()

    blocks.over_rows(k, block, work, threads=2)
    assert sorted((lo, hi) for lo, hi, _ in done) == expected  # each part once
    by_caller = sum(mine for _, _, mine in done)
    assert by_caller >= len(expected) - 1  # not a fixed half: the caller took the rest


def test_one_thread_does_the_pass_in_one_call():
    calls: list[tuple[int, int]] = []
    blocks.over_rows(100_000, 40, lambda lo, hi: calls.append((lo, hi)), threads=1)
    assert calls == [(0, 100_000)]
