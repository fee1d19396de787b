"""`track-dis send display`: scenario A's body as a DIS simulation would publish it (1 Hz
exact positions as Entity State PDUs); `track-dis receive`: a DIS receiver that
dead-reckons the entities it hears at 30 Hz, as a viewer draws them, and prints a line a
second."""

from __future__ import annotations

import argparse
import functools
import math
import socket
import sys
import time

import numpy as np

from zenoh_track.clients.dis import pdu, standard
from zenoh_track.clients.dis.geodesy import EnuFrame, body_axes, euler_of, pymap3d
from zenoh_track.clients.dis.inbound import Clocks, open_socket
from zenoh_track.clients.dis.outbound import DeadReckoner
from zenoh_track.clients.feeds.scenarios import FlightA
from zenoh_track.clients.lib import Client
from zenoh_track.wire import add_zenoh_args, fail, on_signals, open_session

PROG = "track-dis"
SENDER = (1, 1)  # site:application of `send`


def scenario_pdus(frame: EnuFrame, t: float, runs: int, stamp: float, absolute: bool,
                  exercise: int) -> np.ndarray:
    """Scenario A's `runs` bodies at scenario time `t` as Entity State PDUs (FVW, exact
    position, the true velocity and acceleration, orientation along the velocity)."""
    p, v, a = flight().state(t)
    pos = frame.to_ecef(np.repeat(p, runs, 0))
    vel, acc = frame.vectors_to_ecef(np.repeat(v, runs, 0)), \
        frame.vectors_to_ecef(np.repeat(a, runs, 0))
    out = pdu.entity_state(runs)
    pdu.header(out, pdu.ENTITY_STATE, pdu.FAMILY_ENTITY_INFO, exercise,
               pdu.timestamp(np.full(runs, stamp), absolute))
    out["site"], out["application"], out["entity"] = *SENDER, np.arange(1, runs + 1)
    out["entity_type"]["kind"], out["entity_type"]["domain"] = 1, 2
    out["location"], out["velocity"], out["acceleration"] = pos, vel, acc
    out["orientation"] = euler_of(body_axes(pos, vel))
    out["dr_algorithm"] = standard.DR_ALGORITHMS["fvw"][0]
    out["marking_set"] = pdu.MARKING_ASCII
    out["marking"] = pdu.markings([f"display-{i:03d}" for i in range(runs)])
    return out


@functools.cache
def flight() -> FlightA:
    return FlightA()


def send(args: argparse.Namespace) -> None:
    from zenoh_track.clients.dis.gateway import origin_option, resolve_origin

    given = origin_option(args.origin)
    session = open_session(args, log=True)
    with Client(session, args.ns) as client:
        frame = EnuFrame(resolve_origin(client, given, wait=args.wait))
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
    absolute = args.speed == 1.0  # real time: UTC; faster: the scenario's own clock
    start = math.ceil(time.time()) + 1.0
    for k in range(int(FlightA.duration) + 1):
        wall = start + k / args.speed
        time.sleep(max(0.0, wall - time.time()))
        stamp = start + k if absolute else float(k)
        for row in scenario_pdus(frame, float(k), args.runs, stamp, absolute, args.exercise):
            sock.sendto(row.tobytes(), args.to)
    print(f"{PROG} send: {int(FlightA.duration) + 1} scans of {args.runs} entities to "
          f"{args.to[0]}:{args.to[1]}", file=sys.stderr, flush=True)


def receive(args: argparse.Namespace) -> None:
    try:
        sock = open_socket(args.bind, args.port, args.group)
    except OSError as exc:
        fail(f"cannot receive on udp/{args.bind}:{args.port}: {exc.strerror or exc}", PROG)
    sock.settimeout(1.0 / args.rate)
    picture = DeadReckoner()
    count, next_print, end = 0, time.monotonic() + 1.0, time.monotonic() + args.seconds
    while time.monotonic() < end:
        try:
            data = sock.recv(2048)
        except TimeoutError:
            data = b""
        if len(data) >= 144 and data[0] == pdu.VERSION and data[2] == pdu.ENTITY_STATE \
                and data[1] == args.exercise:
            es = np.frombuffer(data[:144], pdu.ENTITY_STATE_PDU)[0]
            past = pdu.seconds_past_hour(np.array([es["timestamp"]]))
            picture.take(float(Clocks.nearest_hour(past, np.array([time.time()]))[0]), es)
            count += 1
        if time.monotonic() >= next_print:
            next_print += 1.0
            line = f"{time.strftime('%H:%M:%S')} entities {len(picture.latest)} PDUs {count}"
            for key in sorted(picture.latest)[:1]:
                p = picture.position(key, time.time())
                if p is not None:
                    lat, lon, alt = pymap3d.ecef2geodetic(*p)
                    line += f" {key}: {lat:.6f} {lon:.6f} {alt:.1f} m"
            print(line, flush=True)
            count = 0


def main(argv: list[str]) -> None:
    on_signals(interrupt=True)
    p = argparse.ArgumentParser(prog=f"{PROG} {argv[0]}", description=__doc__)
    if argv[0] == "send":
        from zenoh_track.clients.dis.gateway import address

        add_zenoh_args(p)
        p.add_argument("scenario", choices=("display",), help="scenario A (1 Hz, exact)")
        p.add_argument("--to", type=address, default=("127.0.0.1", standard.PORT),
                       metavar="HOST:PORT", help="destination (default 127.0.0.1:3000)")
        p.add_argument("--origin", metavar="LAT,LON,ALT",
                       help="where the scenario is (default: the service's origin)")
        p.add_argument("--runs", type=int, default=1, help="identical bodies (default 1)")
        p.add_argument("--speed", type=float, default=1.0,
                       help="times real time (default 1: absolute timestamps; otherwise "
                            "relative, the scenario's own clock)")
        p.add_argument("--exercise", type=int, default=standard.EXERCISE)
        p.add_argument("--wait", type=float, default=10.0, help=argparse.SUPPRESS)
        send(p.parse_args(argv[1:]))
    else:
        p.add_argument("--port", type=int, default=standard.PORT)
        p.add_argument("--bind", default="127.0.0.1")
        p.add_argument("--group", metavar="ADDRESS")
        p.add_argument("--exercise", type=int, default=standard.EXERCISE)
        p.add_argument("--rate", type=float, default=30.0, help="dead-reckoning rate, Hz")
        p.add_argument("--seconds", type=float, default=math.inf, help="stop after this")
        receive(p.parse_args(argv[1:]))
