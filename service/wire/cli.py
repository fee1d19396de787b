"""Operator mistakes get one clear line on stderr and exit status 2, never a traceback:
an unreadable file, a listening port already taken, a router that cannot be reached or
that refuses the session (TLS, authentication: `refusal.py` names which).
Shared by the service and every client (stdlib only; Zenoh imported when opening)."""

from __future__ import annotations

import argparse
import os
import re
import sys
from collections.abc import Callable
from typing import Any, NoReturn

CONNECT_TIMEOUT = 5.0  # s: how long a program keeps trying to reach its router or peer
EXIT_USAGE = 2  # exit status of an operator mistake
ENDPOINT = r"(?:tcp|udp|tls|quic|ws|unixsock-stream)/[^\s\)\]\,]+"


def prog_name() -> str:
    """The program's name as the operator typed it (`python -m zenoh_track`: track-service)."""
    stem = os.path.splitext(os.path.basename(sys.argv[0]))[0]
    if stem in ("__main__", "", "-c"):
        return "track-service"
    return stem if stem.startswith("track") else f"track-{stem}"


def fail(message: str, prog: str | None = None) -> NoReturn:
    """Print `<prog>: <message>` on stderr and exit with status 2."""
    print(f"{prog or prog_name()}: {message}", file=sys.stderr, flush=True)
    raise SystemExit(EXIT_USAGE)


def missing_extra(exc: ImportError, extra: str, prog: str | None = None) -> NoReturn:
    """An optional dependency that is not installed: one line naming the extra, exit 2."""
    what = exc.name or str(exc)
    fail(f"needs {what}, from the '{extra}' extra: pip install 'zenoh-track-service[{extra}]'"
         f" (in a clone: pip install -e '.[{extra}]')", prog)


def need(module: str, extra: str, prog: str | None = None) -> None:
    """Check before the work starts that an optional dependency is there (else
    `missing_extra`)."""
    import importlib

    try:
        importlib.import_module(module)
    except ImportError as exc:
        missing_extra(exc, extra, prog)


def add_version(parser: argparse.ArgumentParser) -> None:
    """`--version`: the installed product's version (whose one source is
    `zenoh_track.__version__`, read by the build)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        mine = version("zenoh-track-service")
    except PackageNotFoundError:
        mine = "(not installed)"
    parser.add_argument("--version", action="version",
                        version=f"%(prog)s {mine} (zenoh-track-service)")


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


def open_or_exit(make_config: Callable[[], Any], retry: float | None = None,
                 prog: str | None = None, what: str = "", log: bool = False) -> Any:
    """`zenoh.open` on the config from `make_config`, or one line and exit 2.

    A session that connects somewhere (not a router) waits at most `retry` seconds for
    its endpoints (None: the config's `connect/timeout_ms` when bounded, else
    CONNECT_TIMEOUT), Zenoh retrying meanwhile; then the endpoints are probed once to
    name the cause (`refusal.why_refused`: unreachable, TLS refused by the router,
    authentication refused). A listening port already taken, or a config that does not
    load, fails at once. `log`: Zenoh's error log on stderr once the session is open
    (from the start when RUST_LOG is set), not its retries' errors before the one line."""
    import zenoh

    if log and os.environ.get("RUST_LOG"):
        zenoh.init_log_from_env_or("error")
    try:
        conf = make_config()
    except zenoh.ZError as exc:
        fail(f"cannot load the Zenoh configuration{what}: {zenoh_reason(exc)}", prog)
    readable_files(conf, prog)
    wait = bound_connect(conf, retry)
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        reason = zenoh_reason(exc)
        if "already in use" in reason:
            m = re.search(r"bound to (\S+?):?\s*\[", reason)
            where = m.group(1) if m else "the listening endpoint"
            fail(f"cannot listen on {where}: address already in use (another instance "
                 "running? choose another endpoint with -l)", prog)
        if "Unable to connect" not in reason:
            fail(f"cannot open the Zenoh session: {reason}", prog)
        fail(refused_line(conf, reason, wait), prog)
    if log:
        zenoh.init_log_from_env_or("error")
    return session


def _json(conf: Any, path: str) -> Any:
    import json

    try:
        return json.loads(conf.get_json(path))
    except Exception:  # noqa: BLE001 - a key this Zenoh does not know
        return None


def readable_files(conf: Any, prog: str | None) -> None:
    """Every certificate, key and password file the config names is readable, or one line
    naming it (Zenoh's own error does not say which file)."""
    tls = _json(conf, "transport/link/tls") or {}
    files = [(f"TLS {k}", v) for k, v in tls.items()
             if k.endswith(("_certificate", "_private_key")) and isinstance(v, str) and v]
    users = _json(conf, "transport/auth/usrpwd/dictionary_file")
    files += [("user/password dictionary_file", users)] if isinstance(users, str) else []
    for what, path in files:
        read_file(path, f"the {what}", binary=True, prog=prog)


def bound_connect(conf: Any, retry: float | None) -> float | None:
    """Make a connecting session give up after `retry` s (see `open_or_exit`) instead of
    waiting for ever (`timeout_ms: -1`) or in the background (a peer's default); the
    wait in s, None for a router or a session that connects nowhere."""
    mode = _json(conf, "mode") or "peer"
    endpoints = _json(conf, "connect/endpoints")
    if isinstance(endpoints, dict):
        endpoints = endpoints.get(mode)
    if mode == "router" or not endpoints:
        return None
    if retry is None:
        ms = _json(conf, "connect/timeout_ms")
        if isinstance(ms, dict):
            ms = ms.get(mode)
        retry = ms / 1000 if isinstance(ms, (int, float)) and ms >= 0 else CONNECT_TIMEOUT
    conf.insert_json5("connect/timeout_ms", str(int(retry * 1000)))
    conf.insert_json5("connect/exit_on_failure", "true")
    return retry


def refused_line(conf: Any, reason: str, wait: float | None) -> str:
    """The one line for a session that did not connect: where, how long, and why."""
    from .refusal import why_refused

    mode = _json(conf, "mode") or "peer"
    listed = _json(conf, "connect/endpoints")
    if isinstance(listed, dict):
        listed = listed.get(mode)
    endpoints = [str(e) for e in listed or []] or re.findall(ENDPOINT, reason)
    where = ", ".join(endpoints) or "the connect endpoints"
    reached, cause = why_refused(conf, endpoints)
    tried = f" after {wait:g} s of retries" if wait is not None else ""
    if reached:
        return f"cannot connect to {where}{tried}: {cause}"
    return f"cannot reach {where}{tried}: {cause}"
