"""Zenoh session options shared by the service and every client, in the style of the
zenoh-python examples (mode, connect, listen, config file; multicast scouting off)."""

from __future__ import annotations

import argparse
import json
import socket
from typing import Any

from .cli import CONNECT_TIMEOUT, add_version, open_or_exit
from .keys import DEFAULT_NS, Keys

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"

# Zenoh's `connect/retry` for every program, unless its config file sets one: after a
# lost router (or peer) a session tries again 0.1 s later, doubling the wait up to 1 s
# (Zenoh's own default: 1 s doubling up to 4 s). A router that comes back is found
# within 1 s plus the handshake, and a waiting client sends one connection attempt a
# second (docs/operations.md, tests/test_router_faults.py).
CONNECT_RETRY = {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}


def add_zenoh_args(parser: argparse.ArgumentParser, ns: bool = True) -> None:
    """Zenoh options in the style of the zenoh-python examples."""
    add_version(parser)
    g = parser.add_argument_group("zenoh")
    g.add_argument("--mode", choices=("peer", "client", "router"), help="session mode")
    g.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to (repeatable)")
    g.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable)")
    g.add_argument("-c", "--config", metavar="FILE.json5", help="Zenoh configuration file")
    g.add_argument("--connect-timeout", type=float, default=None, metavar="SECONDS",
                   help="keep trying to reach the connect endpoints this long, then exit "
                        "naming the cause (default: the config file's connect/timeout_ms, "
                        f"else {CONNECT_TIMEOUT:g})")
    if ns:
        g.add_argument("--ns", default=DEFAULT_NS, help="key namespace (default %(default)s)")


def free_port() -> int:
    """A TCP port that is free on 127.0.0.1 now (bound to port 0, then released), for the
    loopback endpoint `tcp/127.0.0.1:<port>` of a process about to be started."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def zenoh_config(args: argparse.Namespace, serve: bool = False) -> Any:
    """Build a zenoh.Config from parsed options.

    Multicast scouting is off unless the config file turns it on. With no endpoint
    given, a serving process (the tracker) listens on DEFAULT_ENDPOINT and a client
    process connects to it; anything else listens on loopback only.
    """
    import zenoh

    conf = zenoh.Config.from_file(args.config) if args.config else zenoh.Config()
    if not args.config:
        conf.insert_json5("scouting/multicast/enabled", "false")
    quick_retry(conf)
    if args.mode:
        conf.insert_json5("mode", json.dumps(args.mode))
    connect, listen = list(args.connect), list(args.listen)
    if not args.config and not connect and not listen:
        (listen if serve else connect).append(DEFAULT_ENDPOINT)
    if not args.config and not listen and (args.mode or "peer") != "client":
        listen.append("tcp/127.0.0.1:0")
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    return conf


def peer_config(endpoint: str) -> Any:
    """A peer that connects to `endpoint` and listens on loopback only, multicast
    scouting off: the session of a tool or test talking to one known service."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    return quick_retry(conf)


def listen_config(endpoint: str) -> Any:
    """A peer that listens on `endpoint` (others connect to it), multicast scouting off:
    the session of a service or benchmark that others are pointed at."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    return conf


def quick_retry(conf: Any) -> Any:
    """`CONNECT_RETRY` as the config's `connect/retry`, unless the config sets one."""
    if json.loads(conf.get_json("connect/retry")) is None:
        conf.insert_json5("connect/retry", json.dumps(CONNECT_RETRY))
    return conf


BLOCK_WAIT_US = 600_000_000  # 10 minutes


def patient(conf: Any) -> Any:
    """Let BLOCK puts wait for a slow receiver instead of closing its link after Zenoh's
    default 5 s of blocked transmission (which loses data): for lockstep services and
    for feeds, which must drop nothing (docs/protocol.md)."""
    conf.insert_json5("transport/link/tx/queue/congestion_control/block/wait_before_close",
                      str(BLOCK_WAIT_US))
    return conf


def stamping(conf: Any) -> Any:
    """Zenoh timestamps on: the session stamps what it publishes and every sample that
    reaches it without a stamp, on arrival. The service's realtime clock learns from
    arrival times (docs/protocol.md section 6: the worker may take a sample from its
    channel long after); a feed's own stamps give it the time of publication."""
    conf.insert_json5("timestamping/enabled", "true")
    return conf


def stamp_ns(sample: Any) -> int | None:
    """The Zenoh timestamp of a sample in Unix ns, None without one. zenoh-python returns
    an NTP64 object; older versions the 64-bit integer itself (uhlc: 32 bits of seconds
    since the Unix epoch, 32 bits of fraction)."""
    ts = sample.timestamp
    if ts is None:
        return None
    v = ts.get_time_as_ntp64()
    if isinstance(v, int):
        return (v >> 32) * 1_000_000_000 + ((v & 0xFFFFFFFF) * 1_000_000_000 >> 32)
    return int(v.as_nanos())


def open_session(args: argparse.Namespace, serve: bool = False, block: bool = False,
                 stamp: bool = False, log: bool = False) -> Any:
    """The session of a program's options, or one line on stderr and exit 2 (a port
    taken, a config that does not load, a router not reached within --connect-timeout or
    refusing the session: `cli.open_or_exit`, which names the cause). `log`: Zenoh's
    error log on stderr once the session is open.
    `block`: BLOCK puts wait for slow receivers (`patient`) unless a config file is given;
    `stamp`: samples timestamped (`stamping`), each unless a config file is given."""
    def make() -> Any:
        conf = zenoh_config(args, serve)
        if stamp and not args.config:
            stamping(conf)
        return patient(conf) if block and not args.config else conf

    return open_or_exit(make, getattr(args, "connect_timeout", None),
                        what=f" {args.config}" if args.config else "", log=log)


def wait_for_tracker(session: Any, keys: Keys, count: int = 1, timeout: float = 30.0) -> bool:
    """Block until `count` tracker liveliness tokens are alive, or `timeout` s pass."""
    import threading

    import zenoh

    seen: set[str] = set()
    ready = threading.Event()

    def on_token(sample: Any) -> None:
        key = str(sample.key_expr)
        if sample.kind == zenoh.SampleKind.PUT:
            seen.add(key)
        else:
            seen.discard(key)
        if len(seen) >= count:
            ready.set()

    sub = session.liveliness().declare_subscriber(keys.alive("*"), on_token, history=True)
    try:
        return ready.wait(timeout)
    finally:
        sub.undeclare()
