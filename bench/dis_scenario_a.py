"""Scenario A through DIS, end to end, beside the same positions fed on Zenoh directly.

A lockstep service with a geodetic origin; `track-dis send display` publishes the body's
exact 1 Hz positions as Entity State PDUs (relative timestamps: the scenario runs
`--speed` times real time); `track-dis` takes them in and sends the service's tracks back
out as PDUs to a UDP socket of this script, which dead-reckons them at every frame
instant as a DIS receiver does. Printed: the service's 30 Hz frames against the truth,
through DIS and through Zenoh; the receiver's picture against the service's frames and
against the truth; the PDUs out per phase of the flight.

    python bench/dis_scenario_a.py [--speed 10]
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from zenoh_track.clients.dis import pdu  # noqa: E402
from zenoh_track.clients.dis.geodesy import EnuFrame  # noqa: E402
from zenoh_track.clients.dis.inbound import Clocks  # noqa: E402
from zenoh_track.clients.dis.outbound import DeadReckoner  # noqa: E402
from zenoh_track.clients.feeds.scenarios import FlightA  # noqa: E402
from zenoh_track.clients.lib import Frame, ServiceProcess  # noqa: E402
from zenoh_track.clients.lib.process import stop  # noqa: E402
from zenoh_track.wire import Origin, unpack  # noqa: E402

ORIGIN = Origin(43.1, 5.9, 0.0)  # a naval visual simulation's harbour
TARGET = "display-000"
DIS_TARGET = "1-1-1"  # site 1, application 1, entity 1 of `track-dis send`
START = 3.0  # s: frames compared from here (after initiation, as track-eval display)
END = 56.0  # s: the last scan; lockstep frames before it are published


@dataclass
class Run:
    """What one run gave: the service's frames of the target (t, pos), in scenario time,
    and for DIS the PDUs out (scenario time of their timestamp, the PDU)."""

    t: np.ndarray
    pos: np.ndarray
    pdus: list[tuple[float, np.void]]


def frames_of(frames: list[Frame], target: str, hour: float) -> tuple[np.ndarray, np.ndarray]:
    ts, ps = [], []
    for f in frames:
        row = f.track(target)
        if row is not None:
            ts.append(f.t - hour)
            ps.append(row["pos"])
    return np.array(ts), np.array(ps).reshape(-1, 3)


def via_zenoh() -> Run:
    """The scenario fed on Zenoh directly (`meas/`, sigma 0), as track-feed display does."""
    with ServiceProcess("--origin", ORIGIN.text(), clock="lockstep") as svc:
        client = svc.wait()
        picture = client.picture(maxlen=100_000)
        feed = client.feed("feed")
        flight = FlightA()
        for k in range(int(END) + 1):
            p = flight.state(float(k))[0][0]
            feed.measure(TARGET, t=float(k), pos=p, sigma=0.0)
        feed.clock(END)
        picture.wait_for(lambda f: f.t >= END - 1.5 / 30, timeout=60)
        frames = list(picture.queue)
    t, pos = frames_of(frames, TARGET, 0.0)
    return Run(t, pos, [])


def via_dis(speed: float, gateway_args: tuple[str, ...] = ()) -> tuple[Run, dict]:
    """The scenario as PDUs through track-dis, both ways; the gateway's status at the end."""
    with ServiceProcess("--origin", ORIGIN.text(), clock="lockstep") as svc:
        client = svc.wait()
        picture = client.picture(maxlen=100_000)
        rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(0.2)
        inbox = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        inbox.bind(("127.0.0.1", 0))
        port = inbox.getsockname()[1]
        inbox.close()
        received: list[tuple[float, bytes]] = []
        done = threading.Event()

        def listen() -> None:
            while not done.is_set():
                try:
                    received.append((time.time(), rx.recv(2048)))
                except TimeoutError:
                    continue

        listener = threading.Thread(target=listen, daemon=True)
        listener.start()
        base = [sys.executable, "-m", "zenoh_track.clients.dis.gateway"]
        gw = subprocess.Popen([*base, "-e", svc.endpoint, "--port", str(port), "--send-to",
                               f"127.0.0.1:{rx.getsockname()[1]}", *gateway_args],
                              stderr=subprocess.PIPE, text=True)
        try:
            wait_gateway(client, gw)
            subprocess.run([*base, "send", "display", "-e", svc.endpoint, "--to",
                            f"127.0.0.1:{port}", "--speed", str(speed)], check=True,
                           capture_output=True, text=True, timeout=120)
            last = picture.wait_for(lambda f: f.t % 3600.0 >= END - 1.5 / 30, timeout=60)
            hour = round((last.t - END) / 3600.0) * 3600.0
            frames = [f for f in picture.queue if f.t - hour < END]
            status = gateway_status(client, lambda s: s["out"]["frames"] >= len(frames))
            time.sleep(0.3)  # the last PDUs' way to the receiver's socket
        finally:
            stop(gw)
            done.set()
            listener.join()
    t, pos = frames_of(frames, DIS_TARGET, hour)
    pdus = []
    for _, data in received:
        if len(data) >= 144 and data[2] == pdu.ENTITY_STATE:
            es = np.frombuffer(data[:144], pdu.ENTITY_STATE_PDU)[0]
            past = pdu.seconds_past_hour(np.array([es["timestamp"]]))
            stamp = float(Clocks.nearest_hour(past, np.array([hour + END / 2]))[0])
            pdus.append((stamp - hour, es))
    return Run(t, pos, pdus), status


def wait_gateway(client: object, gw: subprocess.Popen) -> None:
    """Until the gateway answers its status (it has its origin and its sockets)."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if gw.poll() is not None:
            raise RuntimeError(f"track-dis exited: {gw.stderr.read() if gw.stderr else ''}")
        for r in client.session.get("track/gateway/dis/status", timeout=1.0):  # type: ignore
            if r.ok is not None:
                return
        time.sleep(0.1)
    raise RuntimeError("track-dis did not answer its status")


def gateway_status(client: object, ready: object, timeout: float = 30.0) -> dict:
    deadline = time.monotonic() + timeout
    status: dict = {}
    while time.monotonic() < deadline:
        for r in client.session.get("track/gateway/dis/status", timeout=2.0):  # type: ignore
            if r.ok is not None:
                status = unpack(r.ok.payload.to_bytes())
        if status and ready(status):  # type: ignore[operator]
            return status
        time.sleep(0.1)
    return status


def truth(t: np.ndarray) -> np.ndarray:
    return FlightA().state(t)[0]


def frame_errors(run: Run) -> np.ndarray:
    keep = (run.t >= START - 1e-6) & (run.t < END - 1e-6)
    return np.linalg.norm(run.pos[keep] - truth(run.t[keep]), axis=1)


def receiver_picture(run: Run) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At each frame instant from the first PDU on: the receiver's dead-reckoned position
    (ENU) from the PDUs stamped at or before it; the instants and the frames' positions."""
    enu = EnuFrame(ORIGIN)
    order = sorted(run.pdus, key=lambda p: p[0])
    dr, k = DeadReckoner(), 0
    ts, got, want = [], [], []
    for t, p in zip(run.t, run.pos, strict=True):
        while k < len(order) and order[k][0] <= t + 1e-5:
            dr.take(order[k][0], order[k][1])
            k += 1
        if t >= END or not dr.latest:
            continue
        key = next(iter(dr.latest))
        ecef = dr.position(key, t)
        ts.append(t)
        got.append(enu.to_enu(ecef[None])[0])
        want.append(p)
    return np.array(ts), np.array(got), np.array(want)


def phases(run: Run) -> list[tuple[str, float, float, int]]:
    out = []
    stamps = np.array([t for t, _ in run.pdus])
    for name, t0, t1 in FlightA.phases:
        out.append((name, t0, t1, int(np.count_nonzero((stamps >= t0) & (stamps < t1)))))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--speed", type=float, default=10.0, help="times real time")
    args = p.parse_args()
    zen = via_zenoh()
    dis, status = via_dis(args.speed)
    ez, ed = frame_errors(zen), frame_errors(dis)
    rms_z, rms_d = float(np.sqrt(np.mean(ez**2))), float(np.sqrt(np.mean(ed**2)))
    print(f"Scenario A, {len(ed)} frames from {START:g} s to {END:g} s, lockstep service, "
          f"origin {ORIGIN.text()}")
    print(f"{'service frames vs truth':<34}{'RMS m':>10}{'max m':>10}")
    print(f"{'  fed on Zenoh (meas/, sigma 0)':<34}{rms_z:>10.4f}{ez.max():>10.4f}")
    print(f"{'  through DIS (track-dis in)':<34}{rms_d:>10.4f}{ed.max():>10.4f}")
    print(f"  DIS / Zenoh RMS: {rms_d / rms_z:.6f}")
    ts, got, want = receiver_picture(dis)
    off = np.linalg.norm(got - want, axis=1)
    to_truth = np.linalg.norm(got - truth(ts), axis=1)
    print(f"receiver's dead-reckoned picture (PDUs out, FVW), {len(ts)} frame instants "
          f"from {ts[0]:.3f} s:")
    print(f"  vs the service's frames: max {off.max():.4f} m (threshold 1 m), "
          f"RMS {np.sqrt(np.mean(off**2)):.4f} m")
    print(f"  vs the truth:            max {to_truth.max():.4f} m, "
          f"RMS {np.sqrt(np.mean(to_truth**2)):.4f} m (frames: RMS {rms_d:.4f} m)")
    print(f"PDUs out: {len(dis.pdus)} over {END:g} s ({status['out']['sent']})")
    for name, t0, t1, n in phases(dis):
        print(f"  {name:<14}{t0:>5g}-{t1:<5g} s {n:>4} PDUs, {n / (t1 - t0):.2f} per s")
    print(f"gateway in: {status['in']}")


if __name__ == "__main__":
    main()
