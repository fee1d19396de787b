"""Where the service's CPU goes in the single-message flood of `--throughput`: each
thread's CPU and the worker's stages, per message, from the feed's start to the last
reply (diagnosis; docs/performance.md, "Single messages against the echo floor").

    python bench/flood_stages.py [--targets 5000] [--duration 20]

Runs `bench/throughput.one` (the same flood, feed and counting subscriber) against the
service with no flags, started through this file (`--serve`): the worker's stages are
wrapped with thread-CPU counters here, in the benchmark's process of the service, not in
the service's code, and the cyclic collector's pauses are counted from `gc.callbacks`.
SIGUSR1 (sent before the feed and after the last reply) appends a snapshot to a file;
the difference is printed. The counters cost ~1 us a wrapped call (a few per pass of
1,024 messages). Linux only (/proc).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
STAGES = [  # (module, class or None, name, label): nested labels are indented
    ("ingest", "Ingest", "next_batch", "ingest.next_batch"),
    ("worker", "TrackService", "_process", "worker._process"),
    ("worker", "TrackService", "_take_singles", "  _take_singles"),
    ("decode", "Decoder", "singles", "    Decoder.singles"),
    ("steps", "TrackerCalls", "rows", "  TrackerCalls.rows (Tracker.step)"),
    ("imm", "IMM", "update", "    IMM.update (the compiled kernel)"),
    ("label_association", "LabelAssociator", "associate", "    LabelAssociator.associate"),
    ("tracker", "Tracker", "_initiate", "    Tracker._initiate"),
    ("publish", "Publisher", "batch", "  Publisher.batch"),
    ("publish", "Publisher", "put_states", "    Publisher.put_states"),
    ("steps", "TrackerCalls", "snapshot", "  TrackerCalls.snapshot (frames)"),
    ("publish", "Publisher", "frame", "  Publisher.frame"),
    ("clocks", "Realtime", "end", "  Realtime.end (the step's end)"),
]


def serve(argv: list[str]) -> None:
    """The service (`python -m zenoh_track` with `argv`) with its stages counted."""
    import gc
    import importlib

    out = os.environ["FLOOD_STAGES_OUT"]
    cpu: collections.Counter = collections.Counter()
    calls: collections.Counter = collections.Counter()  # of each stage
    clock = time.thread_time
    where = {"ingest": "adapter.ingest", "worker": "adapter.worker", "decode": "adapter.decode",
             "steps": "adapter.steps", "publish": "adapter.publish", "imm": "estimation.imm",
             "clocks": "adapter.clocks",
             "label_association": "tracking.label_association", "tracker": "tracking.tracker"}
    for mod, cls, name, label in STAGES:
        owner = getattr(importlib.import_module(f"zenoh_track.{where[mod]}"), cls)
        real = getattr(owner, name)

        def counted(*a: Any, _real: Any = real, _label: str = label, **k: Any) -> Any:
            c0 = clock()
            try:
                return _real(*a, **k)
            finally:
                cpu[_label] += clock() - c0
                calls[_label] += 1
        setattr(owner, name, counted)
    started: dict[int, float] = {}

    def collected(phase: str, info: dict) -> None:
        if phase == "start":
            started[threading.get_ident()] = clock()
        elif (c0 := started.pop(threading.get_ident(), None)) is not None:
            cpu[f"gc (generation {info['generation']})"] += clock() - c0
    gc.callbacks.append(collected)

    def snapshot(*_: Any) -> None:
        names = {str(t.native_id): t.name for t in threading.enumerate()}
        with open(out, "a") as f:
            f.write(json.dumps({"stages": dict(cpu), "calls": dict(calls),
                                "threads": threads(os.getpid(), names)}) + "\n")
    signal.signal(signal.SIGUSR1, snapshot)
    from zenoh_track.__main__ import main
    sys.argv[0] = "track-service"
    main(argv)


def threads(pid: int, names: dict[str, str] | None = None) -> dict[str, float]:
    """CPU seconds of each thread of a process by name (Python's, else the OS's)."""
    from procstat import thread_cpu  # bench/procstat.py

    got: collections.Counter[str] = collections.Counter()
    for tid, (comm, cpu) in thread_cpu(pid).items():
        got[(names or {}).get(str(tid)) or comm] += cpu
    return dict(got)


def main() -> None:
    if sys.argv[1:2] == ["--serve"]:
        serve(sys.argv[2:])
        return
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--targets", type=int, default=5000)
    p.add_argument("--duration", type=int, default=20)
    args = p.parse_args()
    sys.path.insert(0, str(ROOT / "bench"))
    import throughput  # bench/throughput.py

    fd, out = tempfile.mkstemp(suffix=".jsonl")
    os.close(fd)
    os.environ["FLOOD_STAGES_OUT"] = out
    procs: list[Any] = []
    sp = throughput.subprocess
    real_popen, real_run, real_stop = sp.Popen, sp.run, throughput.stop

    def popen(cmd: Any, *a: Any, **k: Any) -> Any:
        proc = real_popen(cmd, *a, **k)
        if "--serve" in cmd:
            procs.append(proc)
        return proc

    def run(cmd: Any, *a: Any, **k: Any) -> Any:  # the feed: a snapshot first
        os.kill(procs[-1].pid, signal.SIGUSR1)
        time.sleep(0.2)
        return real_run(cmd, *a, **k)

    def stop(proc: Any) -> Any:  # after the last reply: a snapshot, then stop
        os.kill(proc.pid, signal.SIGUSR1)
        time.sleep(0.5)
        return real_stop(proc)

    cmd = [sys.executable, str(Path(__file__).resolve()), "--serve", "--clock", "realtime",
           "-l", "ENDPOINT", "--ns", "NS"]
    sp.Popen, sp.run, throughput.stop = popen, run, stop  # type: ignore[misc]
    try:
        got = throughput.one(cmd, args.targets, max(3, args.duration), False, print)
    finally:
        sp.Popen, sp.run, throughput.stop = real_popen, real_run, real_stop  # type: ignore[misc]
    with open(out) as f:
        before, after = (json.loads(line) for line in f.read().split("\n")[:2])
    os.unlink(out)
    n = got["sent"]
    print(f"flood of {n} single messages: {got['answered']} replies, {got['rate']:.0f}/s")
    for part in ("threads", "stages"):
        diff = {k: v - before[part].get(k, 0.0) for k, v in after[part].items()}
        total = sum(diff.values()) if part == "threads" else None
        print(f"{part}: CPU us per message" + (f" (all threads {total / n * 1e6:.1f})"
                                                 if total is not None else
                                                 "; messages per call"))
        keys = sorted(diff, key=lambda k: -diff[k]) if part == "threads" else \
            [label for *_, label in STAGES] + sorted(k for k in diff if k.startswith("gc"))
        for k in keys:
            if diff.get(k, 0.0) / n * 1e6 >= 0.01:
                calls = after.get("calls", {}).get(k, 0) - before.get("calls", {}).get(k, 0)
                per = f"  {n / calls:9.1f}" if part == "stages" and calls else ""
                print(f"  {k:<40} {diff[k] / n * 1e6:7.2f}{per}")


if __name__ == "__main__":
    main()
