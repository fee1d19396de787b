"""Record and replay a long session: nothing lost, the replay byte-identical.

    python bench/bench_record.py                       # 1,000 targets, 600 s simulated
    python bench/bench_record.py --targets 100 --duration 60 --keep /tmp/rec

1. A lockstep service (`--no-display-keys`) is fed `track-feed swarm --targets N
   --duration D` as fast as it takes it, while `track-record --mode client` records the
   feed's keys (`meas/**`, `clock`) and the service's `tracks/**`.
2. Counts: measurements the feed sent = `meas/` samples recorded = `meas_accepted` of
   the service; `tracks/` samples recorded = the service's `tracks_puts`; the recorder's
   received = written.
3. A fresh lockstep service in namespace `replay` gets `track-replay --feed --remap
   track=replay --fast` of that file while a second recorder records its `tracks/**`;
   every track's `tracks/` messages are compared byte for byte with the first run's.
4. Baseline (unless --no-baseline): the same feed into a third lockstep service with no
   recorder, for the recorder's cost as a ratio.

Prints the figures and exits non-zero when a count or a byte differs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from zenoh_track.clients.lib.process import stop  # noqa: E402
from zenoh_track.clients.record.files import Recording  # noqa: E402
from zenoh_track.wire import Keys, free_port, peer_config, unpack, wait_for_tracker  # noqa: E402

PY = sys.executable


def log(msg: str) -> None:
    print(msg, flush=True)


class Service:
    def __init__(self, ns: str, logdir: str) -> None:
        self.ns, self.endpoint = ns, f"tcp/127.0.0.1:{free_port()}"
        self.log = os.path.join(logdir, f"service-{ns}.log")
        with open(self.log, "w") as log_file:  # a pipe nobody reads would fill and block it
            self.proc = subprocess.Popen([PY, "-m", "zenoh_track", "--clock", "lockstep",
                                          "--no-display-keys", "-l", self.endpoint, "--ns",
                                          ns], stdout=log_file, stderr=subprocess.STDOUT)
        self.session = zenoh.open(peer_config(self.endpoint))
        if not wait_for_tracker(self.session, Keys(ns), 1, timeout=60):
            stop(self.proc)
            sys.exit(f"service {ns} did not start: see {self.log}")

    def status(self) -> dict:
        for reply in self.session.get(f"{self.ns}/status", timeout=30):
            if reply.ok is not None:
                return unpack(reply.ok.payload.to_bytes())
        raise RuntimeError("no status reply")

    def close(self) -> None:
        self.session.close()
        stop(self.proc)


def recorder(svc: Service, path: str, *keyexprs: str) -> subprocess.Popen:
    proc = subprocess.Popen([PY, "-m", "zenoh_track.clients.record.record", "-o", path, "--mode",
                            "client",
                             "-e", svc.endpoint, "--ns", svc.ns, "--idle", "20", "--quiet",
                             *keyexprs], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    line = proc.stderr.readline()
    if not line.startswith("track-record: recording"):
        sys.exit(f"recorder did not start: {line}{proc.stderr.read()}")
    return proc


def finish(proc: subprocess.Popen) -> tuple[int, int, str]:
    """Wait for a recorder; its received and written counts and summary line."""
    out, err = proc.communicate(timeout=3600)
    if proc.returncode != 0:
        sys.exit(f"recorder failed: {err}")
    line = out.strip().splitlines()[-1]
    received = int(line.split("track-record: ")[1].split()[0])
    written = int(line.split(" samples received, ")[1].split()[0])
    return received, written, line


def feed(svc: Service, args: argparse.Namespace) -> tuple[int, float]:
    start = time.monotonic()
    out = subprocess.run([PY, "-m", "zenoh_track.clients.feeds.feed", "swarm", "--targets",
                          str(args.targets),
                          "--duration", str(args.duration), "-e", svc.endpoint,
                          "--ns", svc.ns, "--receipt-timeout", "7200"],
                         capture_output=True, text=True, timeout=7200)
    if out.returncode != 0:
        sys.exit(f"feed failed: {out.stderr} (service log: {svc.log})")
    return int(out.stdout.split(": ")[2].split()[0]), time.monotonic() - start


def contents(path: str, ns: str) -> tuple[Counter, dict[str, list]]:
    """Puts per kind of key (deletes as "<kind> deletes"), and each track's tracks/
    samples (kind, payload)."""
    kinds: Counter = Counter()
    tracks: dict[str, list] = defaultdict(list)
    with open(path, "rb") as f:
        rec = Recording(f)
        for ch, s in rec.samples(set(rec.channels)):
            what = ch.key.split("/")[1]
            kinds[what if s.kind == "put" else what + " deletes"] += 1
            if what == "tracks":  # puts and deletes, in order
                tracks[ch.key.split("/", 1)[1]].append((s.kind, s.payload))
    return kinds, tracks


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--targets", type=int, default=1000)
    p.add_argument("--duration", type=float, default=600.0, help="simulated seconds")
    p.add_argument("--keep", metavar="DIR", help="keep the recordings in DIR")
    p.add_argument("--no-baseline", action="store_true")
    args = p.parse_args(argv)
    tmp = args.keep or tempfile.mkdtemp(prefix="bench_record_")
    os.makedirs(tmp, exist_ok=True)
    first, second = os.path.join(tmp, "session.mcap"), os.path.join(tmp, "replayed.mcap")
    failures: list[str] = []
    log(f"swarm of {args.targets} targets over {args.duration:g} s simulated, lockstep; "
        f"files in {tmp}")

    svc = Service("track", tmp)
    try:
        rec = recorder(svc, first, "track/meas/**", "track/clock", "track/tracks/**")
        sent, t_feed = feed(svc, args)
        status = svc.status()
        received, written, line = finish(rec)
    finally:
        svc.close()
    log(f"1. recorded run: feed {sent:,} measurements in {t_feed:.1f} s; {line}")
    t0 = time.monotonic()
    kinds, tracks1 = contents(first, "track")
    t_read = time.monotonic() - t0
    counts = [("meas/ samples recorded = measurements sent", kinds["meas"], sent),
              ("meas/ samples recorded = service meas_accepted", kinds["meas"],
               status["meas_accepted"]),
              ("clock samples recorded = 1", kinds["clock"], 1),
              ("tracks/ samples recorded = service tracks_puts", kinds["tracks"],
               status.get("tracks_puts", kinds["tracks"])),
              ("recorder received = written", received, written)]
    log("2. counts")
    for what, got, want in counts:
        ok = got == want
        log(f"   {'ok  ' if ok else 'FAIL'} {what}: {got:,} / {want:,}")
        if not ok:
            failures.append(what)
    size = os.path.getsize(first) / 1e6
    log(f"   tracks deleted (announced on tracks/): {kinds['tracks deletes']:,}; service "
        f"status: rejected {status.get('meas_rejected', 0):,} "
        f"{status.get('rejected_by_reason', {})}, lost (seq gaps) {status.get('meas_lost', 0):,}")
    log(f"   file {size:,.1f} MB, {sum(kinds.values()):,} samples, read back in {t_read:.1f} s "
        f"({sum(kinds.values()) / t_read:,.0f} samples/s)")

    svc2 = Service("replay", tmp)
    try:
        rec2 = recorder(svc2, second, "replay/tracks/**")
        t0 = time.monotonic()
        out = subprocess.run([PY, "-m", "zenoh_track.clients.feeds.replay", first, "--feed",
                             "--remap",
                              "track=replay", "--fast", "-e", svc2.endpoint,
                              "--receipt-timeout", "7200"],
                             stdout=subprocess.PIPE, text=True, timeout=7200)
        t_replay = time.monotonic() - t0
        if out.returncode != 0:
            sys.exit("replay failed")
        status2 = svc2.status()
        _, _, line2 = finish(rec2)
    finally:
        svc2.close()
    log(f"3. replay into a fresh lockstep service: {out.stdout.strip()} ({t_replay:.1f} s "
        f"with start-up); {line2}")
    kinds2, tracks2 = contents(second, "replay")
    same = sum(1 for k, msgs in tracks1.items() if tracks2.get(k) == msgs)
    msgs_same = sum(len(m) for k, m in tracks1.items() if tracks2.get(k) == m)
    log(f"   tracks byte-identical: {same:,} of {len(tracks1):,} tracks "
        f"({msgs_same:,} of {kinds['tracks'] + kinds['tracks deletes']:,} messages); "
        "replayed service accepted "
        f"{status2['meas_accepted']:,}")
    if same != len(tracks1) or tracks2.keys() != tracks1.keys():
        failures.append("replayed tracks/ differ")

    if not args.no_baseline:
        svc3 = Service("base", tmp)
        try:
            _, t_base = feed(svc3, args)
        finally:
            svc3.close()
        log(f"4. same feed, no recorder: {t_base:.1f} s; with the recorder "
            f"{t_feed / t_base:.2f} x as long; replay --fast {t_replay / t_base:.2f} x "
            "the feed's time")
    if not args.keep:
        for f in (first, second):
            os.remove(f)
    if failures:
        sys.exit("FAILED: " + "; ".join(failures))
    log("all counts equal, every track byte-identical")


if __name__ == "__main__":
    main()
