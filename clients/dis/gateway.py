"""`track-dis`: connect DIS simulations (IEEE 1278.1, version 7, Entity State PDUs on UDP)
to the track service, both ways, in one command (docs/gateways.md).

    track-dis                       # in: PDUs on udp/127.0.0.1:3000 -> scan/dis
                                    # out: the service's tracks -> PDUs to 127.0.0.1:3000
    track-dis send display          # scenario A's body as PDUs (a simulation to try it with)
    track-dis receive --port 3001   # a DIS receiver: the entities it dead-reckons, each second
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import threading
import time
from typing import Any

import numpy as np
import zenoh

from zenoh_track.clients.dis import pdu, standard
from zenoh_track.clients.dis.geodesy import EnuFrame
from zenoh_track.clients.dis.inbound import Inbound, InConfig, kernel_drops, open_socket
from zenoh_track.clients.dis.outbound import Outbound, OutConfig
from zenoh_track.clients.lib import Client
from zenoh_track.clients.lib.origin import OriginConflict, agreed_origin
from zenoh_track.wire import (
    CHUNK,
    MSGPACK_ENCODING,
    Origin,
    Rejected,
    add_zenoh_args,
    decode_map,
    fail,
    on_signals,
    open_session,
    pack,
    parse_origin,
)

PROG = "track-dis"
REPORT_PERIOD = 1.0  # s: at most one errors/ message per reason in this time


def address(text: str) -> tuple[str, int]:
    """`HOST:PORT` -> (host, port)."""
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host, int(port)


def site_app(text: str) -> tuple[int, int]:
    """`SITE:APPLICATION` -> (site, application), each 0..65535."""
    try:
        site, app = (int(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SITE:APPLICATION, got {text!r}") from None
    if not (0 <= site < 65536 and 0 <= app < 65536):
        raise argparse.ArgumentTypeError(f"site and application are 0..65535: {text!r}")
    return site, app


def uint16(text: str) -> int:
    """An option's number 1..65534 (a site or application id)."""
    value = int(text)
    if not 0 < value < 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: a number 1..65534")
    return value


def octet(text: str) -> int:
    """An option's number 0..255 (a DIS enumeration of one octet)."""
    value = int(text)
    if not 0 <= value <= 255:
        raise argparse.ArgumentTypeError(f"{text!r}: a number 0..255")
    return value


def origin_option(text: str | None) -> Origin | None:
    """`--origin`, or one line and exit 2."""
    try:
        return None if text is None else parse_origin(text)
    except Rejected as exc:
        fail(f"--origin {text}: {exc}", PROG)


def entity_type(text: str) -> tuple[int, ...]:
    try:
        return pdu.parse_entity_type(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_zenoh_args(p)
    p.add_argument("--origin", metavar="LAT,LON,ALT",
                   help="the deployment's geodetic origin; default and normally: the "
                        "service's (track-service --origin); one that differs is refused")
    p.add_argument("--name", default="dis",
                   help="the gateway's name: its sensor (scan/<name>), errors/<name> and "
                        "<ns>/gateway/<name>/status (default %(default)s)")
    p.add_argument("--exercise", type=octet, default=standard.EXERCISE,
                   help="DIS exercise id, both ways (default %(default)s)")
    g = p.add_argument_group("in: Entity State PDUs -> the service")
    g.add_argument("--no-in", action="store_true", help="do not take PDUs in")
    g.add_argument("--port", type=int, default=standard.PORT, help="UDP port (default 3000)")
    g.add_argument("--bind", default="127.0.0.1",
                   help="address to receive on (default %(default)s: this machine only; "
                        "0.0.0.0 for every interface, broadcasts included)")
    g.add_argument("--group", metavar="ADDRESS", help="join this multicast group")
    g.add_argument("--accept", type=site_app, action="append", metavar="SITE:APP",
                   help="take only PDUs of these site:application pairs (repeatable)")
    g.add_argument("--sigma", type=float, default=0.0,
                   help="position noise per axis, m (default 0: exact, as a simulation "
                        "states its own truth)")
    g.add_argument("--time", choices=("pdu", "arrival"), default="pdu",
                   help="a measurement's time: the PDU's timestamp (default) or its arrival")
    g.add_argument("--time-window", type=float, default=standard.TIMESTAMP_WINDOW,
                   metavar="SECONDS", help="refuse absolute timestamps farther than this "
                                           "from the arrival (default %(default)s; 0: none)")
    g.add_argument("--window", type=float, default=0.02, metavar="SECONDS",
                   help="one scan/ message per window at most (default %(default)s)")
    o = p.add_argument_group("out: the service's tracks -> Entity State PDUs")
    o.add_argument("--no-out", action="store_true", help="do not send tracks out")
    o.add_argument("--send-to", type=address, metavar="HOST:PORT",
                   help="destination (default: --bind or 127.0.0.1, --port; a broadcast or "
                        "multicast address works)")
    o.add_argument("--site", type=uint16, default=standard.OWN_SITE,
                   help="site id of the gateway's entities (default %(default)s)")
    o.add_argument("--application", type=uint16, default=standard.OWN_APPLICATION,
                   help="application id of the gateway's entities (default %(default)s); "
                        "PDUs of this site:application are never taken in")
    o.add_argument("--entity-type", type=entity_type, default=standard.ENTITY_TYPE,
                   metavar="K.D.C.C.S.S.E", help="entity type (default %(default)s)")
    o.add_argument("--force", type=octet, default=standard.FORCE, metavar="ID",
                   help="force id (default %(default)s: other)")
    o.add_argument("--dr", choices=tuple(standard.DR_ALGORITHMS), default="fvw",
                   help="dead-reckoning algorithm (default %(default)s)")
    o.add_argument("--pos-threshold", type=float, default=standard.DRA_POS_THRSH,
                   metavar="M", help="send when a receiver's dead-reckoned position is off "
                                     "by more than this (default %(default)s)")
    o.add_argument("--orient-threshold", type=float, default=3.0, metavar="DEG",
                   help="... or its orientation by more than this (default %(default)s)")
    o.add_argument("--heartbeat", type=float, default=standard.HBT_ESPDU, metavar="SECONDS",
                   help="... or its last PDU is this old (default %(default)s)")
    o.add_argument("--relative", action="store_true",
                   help="relative timestamps (default absolute: the service's clock is UTC)")
    g.add_argument("--timeout", type=float, default=standard.TIMEOUT, metavar="SECONDS",
                   help="an entity without a PDU this long is gone (default %(default)s: "
                        "HBT_TIMEOUT_MPLIER x the 5 s heartbeat)")
    g.add_argument("--max-entities", type=int, default=InConfig.max_entities, metavar="N",
                   help="entities held at most; PDUs of further ones are refused "
                        "(default %(default)s)")
    o.add_argument("--tentative", action="store_true",
                   help="send tentative tracks too (default: confirmed and coasting)")
    return p


class Reporter:
    """`errors/<name>` messages, at most one per reason and REPORT_PERIOD, each with the
    count since the last: a flood cannot become a flood of reports."""

    def __init__(self, session: Any, key: str, source: str) -> None:
        self.session, self.key, self.source = session, key, source
        self.last: dict[str, float] = {}
        self.held: dict[str, tuple[str, int]] = {}
        self.lock = threading.Lock()

    def __call__(self, code: str, reason: str, count: int) -> None:
        with self.lock:
            held = self.held.get(code, (reason, 0))[1] + count
            self.held[code] = (reason, held)
        self.flush(code)

    def flush(self, only: str | None = None) -> None:
        now = time.monotonic()
        with self.lock:
            due = [(c, r, n) for c, (r, n) in self.held.items() if (only is None or c == only)
                   and now - self.last.get(c, -1e9) >= REPORT_PERIOD]
            for code, _, _ in due:
                del self.held[code]
                self.last[code] = now
        for code, reason, count in due:
            self.session.put(self.key, pack({"key": self.source, "reason": reason,
                                             "code": code, "count": count,
                                             "t_wall": time.time()}),
                             encoding=MSGPACK_ENCODING)


class Gateway:
    """The two directions on one Zenoh session and the gateway's status queryable."""

    def __init__(self, args: argparse.Namespace, client: Client, frame: EnuFrame,
                 stop: threading.Event | None = None) -> None:
        self.args, self.client, self.stop = args, client, stop or threading.Event()
        keys, session = client.keys, client.session
        self.threads: list[threading.Thread] = []
        self.inbound: Inbound | None = None
        self.outbound: Outbound | None = None
        self.sock: socket.socket | None = None
        self.out_sock: socket.socket | None = None
        own = (args.site, args.application)
        if not args.no_in:
            try:
                self.sock = open_socket(args.bind, args.port, args.group)
            except OSError as exc:
                fail(f"cannot receive on udp/{args.group or args.bind}:{args.port}: "
                     f"{exc.strerror or exc} (another DIS program on that port? choose "
                     "another with --port)", PROG)
            feed = client.feed(args.name, check=False)
            config = InConfig(args.exercise, frozenset(args.accept) if args.accept else None,
                              own, args.sigma, args.time, args.time_window, args.window,
                              args.timeout, args.max_entities)
            self.report = Reporter(session, keys.errors(args.name),
                                   f"udp/{args.group or args.bind}:{args.port}")
            self.inbound = Inbound(self.sock, frame, config,
                                   lambda t, ids, enu: feed.scan(t, ids, pos=enu,
                                                                 sigma=args.sigma),
                                   self.report)
            self.threads.append(threading.Thread(target=self.inbound.run,
                                                 args=(self.stop.is_set,), daemon=True))
        if not args.no_out:
            self._out(args, frame, own)
        self.status_q = session.declare_queryable(keys.gateway(args.name), self._status)

    def _out(self, args: argparse.Namespace, frame: EnuFrame, own: tuple[int, int]) -> None:
        dest = args.send_to or (args.bind if args.bind != "0.0.0.0" else "127.0.0.1",
                                args.port)
        out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        out.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
        if args.bind not in ("", "0.0.0.0"):  # multicast out on the interface of --bind
            out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(args.bind))
        config = OutConfig(args.exercise, *own, args.entity_type, args.force, args.dr,
                           args.pos_threshold, np.radians(args.orient_threshold),
                           args.heartbeat, not args.relative,
                           ("tentative", "confirmed", "coasting") if args.tentative
                           else ("confirmed", "coasting"))
        self.out_sock = out
        self.outbound = Outbound(frame, config, lambda data: out.sendto(data, dest))
        # about 2 s of frames: a lockstep burst fits, a late gateway takes the newest
        self.picture = self.client.picture(maxlen=64)
        self.states = self.client.session.declare_subscriber(self.client.keys.states,
                                                             self._states)
        self.threads.append(threading.Thread(target=self._frames, daemon=True))

    def _states(self, sample: zenoh.Sample) -> None:
        """The filtered accelerations of 3-D models with one (state size 9)."""
        try:
            msg = decode_map(sample.payload.to_bytes())
            n, ids = int(msg["n"]), msg["ids"]
            if n == 9 and isinstance(ids, list) and self.outbound is not None:
                x = np.frombuffer(msg["x"], "<f8").reshape(len(ids), n)
                self.outbound.accelerations(ids, x[:, 6:9].copy())
        except (Rejected, ValueError, KeyError, TypeError):
            return

    def _frames(self) -> None:
        assert self.outbound is not None
        while not self.stop.is_set():
            try:
                frame = self.picture.next(timeout=0.5)
            except TimeoutError:
                continue
            except StopIteration:
                return
            self.outbound.on_frame(frame)

    def status(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.args.name, "protocol": "DIS 7",
                               "exercise": self.args.exercise}
        if self.inbound is not None:
            c = self.inbound.counts
            out["in"] = {"datagrams": c.datagrams, "accepted": c.accepted, "scans": c.scans,
                         "own": c.own, "ended": c.ended,
                         "entities": len(self.inbound.seen),
                         "removed": c.removed, "timed_out": c.timed_out,
                         "rejected": dict(c.rejected),
                         "kernel_dropped": kernel_drops(self.inbound.sock)}
        if self.outbound is not None:
            o = self.outbound.counts
            out["out"] = {"frames": o.frames, "frames_dropped": self.picture.dropped,
                          "sent": dict(o.sent), "removed": o.removed,
                          "entities": len(self.outbound.table.index),
                          "no_number": o.no_number, "dr": self.args.dr}
        return out

    def _status(self, query: zenoh.Query) -> None:
        key = self.client.keys.gateway(self.args.name)
        if query.parameters.get("format") == "json":
            query.reply(key, json.dumps(self.status()),
                        encoding=zenoh.Encoding.APPLICATION_JSON)
        else:
            query.reply(key, pack(self.status()), encoding=MSGPACK_ENCODING)

    def run(self) -> None:
        for t in self.threads:
            t.start()
        while not self.stop.wait(REPORT_PERIOD):
            if self.inbound is not None:
                self.report.flush()

    def close(self) -> None:
        self.stop.set()
        for t in self.threads:
            t.join(timeout=2.0)
        self.status_q.undeclare()
        for sock in (self.sock, self.out_sock):
            if sock is not None:
                sock.close()


def resolve_origin(client: Client, given: Origin | None, wait: float = 10.0) -> Origin:
    """The deployment's origin, or one line and exit 2 (a service that is not up within
    `wait` s cannot be asked: then --origin alone)."""
    try:
        client.wait_for_service(timeout=wait)
    except TimeoutError:
        print(f"{PROG}: no track service alive on {client.keys.alive()} after {wait:g} s",
              file=sys.stderr, flush=True)
    try:
        origin, _ = agreed_origin(client, given)
    except OriginConflict as exc:
        fail(str(exc), PROG)
    if origin is None:
        fail("no geodetic origin: start track-service with --origin LAT,LON,ALT (or give "
             "--origin here for a service with a local frame)", PROG)
    return origin


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] in (["send"], ["receive"]):
        from zenoh_track.clients.dis import tools

        return tools.main(argv)
    args = parser().parse_args(argv)
    stop = on_signals()
    if not CHUNK.fullmatch(args.name):
        fail(f"--name {args.name!r}: letters, digits, '-' or '_'", PROG)
    given = origin_option(args.origin)
    session = open_session(args, log=True)
    client = Client(session, args.ns)
    origin = resolve_origin(client, given)
    gateway = Gateway(args, client, EnuFrame(origin), stop.event)
    print(f"{PROG}: ns {args.ns}, origin {origin.text()}, in: "
          f"{'off' if args.no_in else f'udp/{args.group or args.bind}:{args.port}'}, out: "
          f"{'off' if args.no_out else 'on'}", file=sys.stderr, flush=True)
    try:
        gateway.run()
    finally:
        gateway.close()
        client.close()


if __name__ == "__main__":
    main()
