"""`track-record -o FILE [KEYEXPR...]`: record Zenoh samples to an MCAP file.

Records every sample (puts and deletes) of the key expressions (default `<ns>/**`) as it
arrives, payload byte for byte, one MCAP channel per key, with receive and publish times
and a metadata record naming the namespace and protocol version; `frame` samples also
give a display channel (foxglove.SceneUpdate, JSON) that Foxglove and Lichtblick draw.
Stops on Ctrl-C or SIGTERM, after `--duration` seconds, or once no sample has come for
`--idle` seconds; then writes the file's summary and prints the counts. Nothing is
dropped: Zenoh's receive thread only appends each sample to an unbounded queue, which
the main thread writes out. Run it as a Zenoh client of the service (`--mode client -e
ENDPOINT`) to receive every publisher's samples over one link, in the order the service
sees them (docs/clients.md).
"""

from __future__ import annotations

import argparse
import os
import queue
import sys
import threading
import time
from typing import Any

import zenoh

from zenoh_track.clients.evaluation.progress import add_quiet_arg, bar
from zenoh_track.clients.record.files import RecordingWriter
from zenoh_track.wire import Keys, Stop, add_zenoh_args, on_signals, open_session, stamp_ns

POLL = 0.2  # s: how often the writer looks at the stop conditions when no sample comes


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-record", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("keyexprs", nargs="*", metavar="KEYEXPR",
                   help="key expressions to record (default: <ns>/**)")
    p.add_argument("-o", "--output", required=True, metavar="FILE.mcap")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after this many seconds")
    p.add_argument("--idle", type=float, default=None, metavar="S",
                   help="stop once no sample has come for this many seconds (counted from "
                        "the first sample)")
    p.add_argument("--scene-hz", type=float, default=2.0, metavar="HZ",
                   help="display channel: scene updates per simulated second, from the "
                        "frame key (0: none; default %(default)s)")
    p.add_argument("--scene-marker", type=float, default=100.0, metavar="M",
                   help="display channel: smallest drawn sphere diameter, m")
    add_quiet_arg(p)
    add_zenoh_args(p)
    return p


def distinct(keyexprs: list[str]) -> list[str]:
    """The key expressions without those another one includes (each sample once)."""
    kes = [zenoh.KeyExpr(k) for k in dict.fromkeys(keyexprs)]
    return [str(k) for i, k in enumerate(kes)
            if not any(j != i and o.includes(k) and not (k.includes(o) and j > i)
                       for j, o in enumerate(kes))]


class Recorder:
    """Subscribes the key expressions; samples wait in a queue for `drain`."""

    def __init__(self, session: zenoh.Session, keyexprs: list[str]) -> None:
        self.items: queue.SimpleQueue[tuple] = queue.SimpleQueue()
        self.received = 0
        lock = threading.Lock()  # callbacks of several links may run at once
        put = self.items.put
        delete = zenoh.SampleKind.DELETE

        def on_sample(s: zenoh.Sample) -> None:
            put((str(s.key_expr), "delete" if s.kind == delete else "put", str(s.encoding),
                 s.payload.to_bytes(), time.time_ns(), stamp_ns(s)))
            with lock:
                self.received += 1

        # on Zenoh's receive thread (indirect=False): samples keep the order they arrive in
        self.subs = [session.declare_subscriber(k, zenoh.handlers.Callback(
            on_sample, indirect=False)) for k in keyexprs]

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()


def record(args: argparse.Namespace, out: Any, stop: Stop) -> tuple[int, RecordingWriter]:
    keys = Keys(args.ns)
    keyexprs = distinct(args.keyexprs or [f"{keys.ns}/**"])
    writer = RecordingWriter(out, keys.ns, keyexprs, args.scene_hz, args.scene_marker)
    with open_session(args, log=True) as session:
        rec = Recorder(session, keyexprs)
        print(f"track-record: recording {' '.join(keyexprs)} to {args.output} "
              "(Ctrl-C to stop)", file=sys.stderr, flush=True)
        start = time.monotonic()
        last = None
        progress = bar(desc="recording", unit=" samples", quiet=args.quiet)
        try:
            while not stop.is_set():
                try:
                    item = rec.items.get(timeout=POLL)
                except queue.Empty:
                    now = time.monotonic()
                    if args.duration is not None and now - start >= args.duration:
                        break
                    if args.idle is not None and last is not None and now - last >= args.idle:
                        break
                    continue
                writer.write(*item)
                n = 1
                while n < 4096:  # what else waits, without a timeout per sample
                    try:
                        writer.write(*rec.items.get_nowait())
                    except queue.Empty:
                        break
                    n += 1
                last = time.monotonic()
                progress.update(n)
                if args.duration is not None and last - start >= args.duration:
                    break
        finally:
            rec.close()  # no callback after this: what is queued is all there is
            while True:
                try:
                    writer.write(*rec.items.get_nowait())
                except queue.Empty:
                    break
                progress.update(1)
            progress.close()
    received = rec.received
    return received, writer


def main(argv: list[str] | None = None) -> None:
    args = parser().parse_args(argv)
    stop = on_signals()  # the file is finished on the way out
    start = time.monotonic()
    with open(args.output, "wb") as out:
        received, writer = record(args, out, stop)
        writer.finish(received)
    size = os.path.getsize(args.output) / 1e6
    print(f"track-record: {received} samples received, {writer.written} written on "
          f"{len(writer.channels)} channels (+{writer.scenes} scene updates) to "
          f"{args.output} ({size:.1f} MB, {time.monotonic() - start:.1f} s)", flush=True)
    if received != writer.written:
        sys.exit(f"track-record: {received - writer.written} samples received but not "
                 "written")


if __name__ == "__main__":
    main()
