"""`track-display`: the live track table in a terminal, updated in place.

Subscribes `<ns>/display/**`; a Zenoh delete on a track's key removes its row. At start it
asks the service for the latest instant (`get <ns>/display/**`), so the table is full at
once even when the picture is paused.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from typing import Any

import zenoh

from service.wire import Keys, add_zenoh_args, open_session, unpack

HEADER = f"{'id':<16}{'x m':>11}{'y m':>11}{'z m':>9}{'speed m/s':>11}{'sigma m':>9}" \
         f"  {'status':<10}{'age s':>6}"


def render(rows: dict[str, dict[str, Any]], ns: str, now_t: float | None) -> str:
    lines = [f"track-display  ns={ns}  t={now_t if now_t is not None else '-':}  "
             f"tracks={len(rows)}", HEADER]
    for tid in sorted(rows):
        m = rows[tid]
        x, y, z = m["pos"]
        speed = math.sqrt(sum(v * v for v in m["vel"]))
        lines.append(f"{tid:<16.16}{x:>11.1f}{y:>11.1f}{z:>9.1f}{speed:>11.1f}"
                     f"{m['sigma']:>9.1f}  {m['status']:<10}{m['age']:>6.1f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="track-display", description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--hz", type=float, default=4.0, help="screen refresh rate")
    p.add_argument("--max-rows", type=int, default=40)
    args = p.parse_args(argv)
    keys = Keys(args.ns)
    rows: dict[str, dict[str, Any]] = {}
    lock = threading.Lock()

    def on_sample(s: Any) -> None:
        tid = str(s.key_expr).rsplit("/", 1)[-1]
        with lock:
            if s.kind == zenoh.SampleKind.DELETE:
                rows.pop(tid, None)
                return
            try:
                msg = unpack(s.payload.to_bytes())
                if tid in rows and msg["t"] < rows[tid]["t"]:
                    return  # a query's answer older than what the subscription brought
                rows[tid] = {k: msg[k] for k in ("t", "pos", "vel", "sigma", "status", "age")}
            except (ValueError, KeyError, TypeError):
                return

    def catch_up() -> None:
        """The latest instant at once, without waiting for the next one (a paused
        lockstep picture may have none for long): the service answers display/**."""
        for reply in session.get(keys.space("display"), target=zenoh.QueryTarget.ALL,
                                 timeout=5):
            if reply.ok is not None:
                on_sample(reply.ok)

    session = open_session(args)
    sub = session.declare_subscriber(keys.display("*"), on_sample)
    threading.Thread(target=catch_up, daemon=True).start()
    try:
        while True:
            with lock:
                shown = dict(sorted(rows.items())[: args.max_rows])
                t = max((r["t"] for r in rows.values()), default=None)
            sys.stdout.write("\x1b[H\x1b[2J" + render(shown, args.ns, t) + "\n")
            sys.stdout.flush()
            time.sleep(1.0 / args.hz)
    except KeyboardInterrupt:
        pass
    finally:
        sub.undeclare()
        session.close()


if __name__ == "__main__":
    main()
