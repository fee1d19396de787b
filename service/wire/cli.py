"""Operator mistakes get one clear line on stderr and exit status 2, never a traceback:
an unreadable file, a listening port already taken, a router that cannot be reached.
Shared by the service and every client (stdlib only; Zenoh imported when opening)."""

from __future__ import annotations

import os
import re
import sys
import time
from collections.abc import Callable
from typing import Any, NoReturn

CONNECT_TIMEOUT = 10.0  # s: how long a program keeps trying to reach its router or peer
EXIT_USAGE = 2  # exit status of an operator mistake


def prog_name() -> str:
    """The program's name as the operator typed it (`python -m service`: track-service)."""
    stem = os.path.splitext(os.path.basename(sys.argv[0]))[0]
    if stem in ("__main__", "", "-c"):
        return "track-service"
    return stem if stem.startswith("track") else f"track-{stem}"


def fail(message: str, prog: str | None = None) -> NoReturn:
    """Print `<prog>: <message>` on stderr and exit with status 2."""
    print(f"{prog or prog_name()}: {message}", file=sys.stderr, flush=True)
    raise SystemExit(EXIT_USAGE)


def read_file(path: str, what: str, binary: bool = False,
              prog: str | None = None) -> Any:
    """The contents of `path` (str, or bytes with `binary`), or one line and exit 2:
    `cannot read <what> <path>: <why>`."""
    try:
        with open(path, "rb" if binary else "r", encoding=None if binary else "utf-8") as f:
            return f.read()
    except (OSError, UnicodeDecodeError) as exc:
        fail(f"cannot read {what} {path}: {getattr(exc, 'strerror', None) or exc}", prog)


def zenoh_reason(exc: BaseException) -> str:
    """Zenoh's error text without the Rust source locations (' at /…/x.rs:61.')."""
    text = re.sub(r"\s+at \S+\.rs:\d+\.?", "", str(exc)).strip()
    return " ".join(text.split()) or type(exc).__name__


def open_or_exit(make_config: Callable[[], Any], retry: float = CONNECT_TIMEOUT,
                 prog: str | None = None, what: str = "") -> Any:
    """`zenoh.open` on a fresh config from `make_config`, or one line and exit 2.

    An endpoint that cannot be reached (a router or service not up yet) is tried again
    every 0.5 s for up to `retry` seconds; a listening port already taken, or a config
    that does not load, fails at once."""
    import zenoh

    deadline = time.monotonic() + retry
    while True:
        try:
            conf = make_config()
        except zenoh.ZError as exc:
            fail(f"cannot load the Zenoh configuration{what}: {zenoh_reason(exc)}", prog)
        try:
            return zenoh.open(conf)
        except zenoh.ZError as exc:
            reason = zenoh_reason(exc)
            if "already in use" in reason:
                m = re.search(r"bound to (\S+?):?\s*\[", reason)
                where = m.group(1) if m else "the listening endpoint"
                fail(f"cannot listen on {where}: address already in use (another instance "
                     "running? choose another endpoint with -l)", prog)
            if "Unable to connect" not in reason:
                fail(f"cannot open the Zenoh session: {reason}", prog)
            if time.monotonic() >= deadline:
                fail(f"cannot reach {_endpoints(reason)} after {retry:g} s of retries "
                     "(is the router or service running? check -e/--connect)", prog)
        time.sleep(0.5)


def _endpoints(reason: str) -> str:
    found = re.findall(r"(?:tcp|udp|tls|quic|ws|unixsock-stream)/[^\s\)\]\,]+", reason)
    return ", ".join(found) or "the connect endpoints"
