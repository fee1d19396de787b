"""10,000 DIS entities at 1 Hz through `track-dis` into a realtime service, and the
service's 10,000 tracks back out as PDUs with the standard's thresholds.

This script is the simulation: N entities flying straight (1 Hz Entity State PDUs,
absolute timestamps), each PDU sent both to `track-dis --no-out` and to a plain Python UDP
receive loop (`recv_into`, a count: the least any Python receiver spends) in another
process. A second `track-dis --no-in` sends the tracks out to this script's receiver.
Printed: every PDU accounted for (sent = taken + refused + dropped by the kernel), the CPU
per PDU of the gateway's in side against the plain loop's in the same run, and the PDUs out
per second.

    python bench/dis_capacity.py --entities 10000 --seconds 30
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from procstat import cpu_seconds  # noqa: E402

from zenoh_track.clients.dis import pdu  # noqa: E402
from zenoh_track.clients.dis.geodesy import EnuFrame, body_axes, euler_of  # noqa: E402
from zenoh_track.clients.lib import ServiceProcess  # noqa: E402
from zenoh_track.clients.lib.process import stop  # noqa: E402
from zenoh_track.wire import Origin, unpack  # noqa: E402

ORIGIN = Origin(43.1, 5.9, 0.0)
PLAIN = """
import socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
s.bind(("127.0.0.1", int(sys.argv[1])))
buf = memoryview(bytearray(1536))
n = 0
print("ready", flush=True)
while True:
    s.recv_into(buf)
    n += 1
"""


def free_udp() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Simulation:
    """N straight flyers within 50 km of the origin, 100-300 m/s, 1-10 km up."""

    def __init__(self, n: int, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        self.frame = EnuFrame(ORIGIN)
        self.p0 = np.c_[rng.uniform(-5e4, 5e4, (n, 2)), rng.uniform(1e3, 1e4, n)]
        heading = rng.uniform(0, 2 * np.pi, n)
        speed = rng.uniform(100, 300, n)
        self.v = np.c_[speed * np.sin(heading), speed * np.cos(heading), np.zeros(n)]
        self.n = n

    def pdus(self, t: float, t0: float) -> np.ndarray:
        pos = self.frame.to_ecef(self.p0 + self.v * (t - t0))
        vel = self.frame.vectors_to_ecef(self.v)
        out = pdu.entity_state(self.n)
        pdu.header(out, pdu.ENTITY_STATE, pdu.FAMILY_ENTITY_INFO, 1,
                   pdu.timestamp(np.full(self.n, t), True))
        out["site"], out["application"] = 7, 1
        out["entity"] = np.arange(1, self.n + 1)
        out["location"], out["velocity"] = pos, vel
        out["orientation"] = euler_of(body_axes(pos, vel))
        out["dr_algorithm"] = 2
        out["marking_set"] = pdu.MARKING_ASCII
        return out


def status(client: object, name: str) -> dict:
    for r in client.session.get(f"track/gateway/{name}/status", timeout=3.0):  # type: ignore
        if r.ok is not None:
            return unpack(r.ok.payload.to_bytes())
    return {}


def wait_status(client: object, name: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not status(client, name):
        if time.monotonic() > deadline:
            raise RuntimeError(f"track-dis {name} did not answer")
        time.sleep(0.2)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--entities", type=int, default=10_000)
    p.add_argument("--seconds", type=float, default=30.0, help="measured, after a warm-up")
    p.add_argument("--warmup", type=float, default=8.0)
    args = p.parse_args()
    sim = Simulation(args.entities)
    gw_port, plain_port = free_udp(), free_udp()
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.2)
    out_times: list[float] = []
    done = threading.Event()

    def listen() -> None:
        while not done.is_set():
            try:
                rx.recv(2048)
                out_times.append(time.monotonic())
            except TimeoutError:
                continue

    with ServiceProcess("--origin", ORIGIN.text(), clock="realtime") as svc:
        client = svc.wait(timeout=120)
        base = [sys.executable, "-m", "zenoh_track.clients.dis.gateway", "-e", svc.endpoint]
        gw_in = subprocess.Popen([*base, "--no-out", "--name", "dis-in", "--port",
                                  str(gw_port)], stderr=subprocess.DEVNULL)
        gw_out = subprocess.Popen([*base, "--no-in", "--name", "dis-out", "--send-to",
                                   f"127.0.0.1:{rx.getsockname()[1]}"],
                                  stderr=subprocess.DEVNULL)
        plain = subprocess.Popen([sys.executable, "-c", PLAIN, str(plain_port)],
                                 stdout=subprocess.PIPE, text=True)
        listener = threading.Thread(target=listen, daemon=True)
        try:
            assert plain.stdout is not None and plain.stdout.readline().strip() == "ready"
            wait_status(client, "dis-in")
            wait_status(client, "dis-out")
            listener.start()
            tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            tx.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8 << 20)
            t0 = float(np.ceil(time.time()))
            total = args.warmup + args.seconds
            sent, marks = 0, {}
            chunks = 50  # each second's PDUs in 50 bursts, 20 ms apart
            for k in range(int(total)):
                rows = sim.pdus(t0 + k, t0)
                data = [r.tobytes() for r in rows]
                for c, part in enumerate(np.array_split(np.arange(sim.n), chunks)):
                    time.sleep(max(0.0, t0 + k + c / chunks - time.time()))
                    for i in part.tolist():
                        tx.sendto(data[i], ("127.0.0.1", gw_port))
                        tx.sendto(data[i], ("127.0.0.1", plain_port))
                    sent += len(part)
                if k + 1 == int(args.warmup):
                    marks["start"] = (time.monotonic(), sent, cpu_seconds(gw_in.pid),
                                      cpu_seconds(plain.pid), cpu_seconds(gw_out.pid),
                                      len(out_times))
                    out_before = status(client, "dis-out")["out"]
            time.sleep(1.0)
            end = (time.monotonic(), sent, cpu_seconds(gw_in.pid), cpu_seconds(plain.pid),
                   cpu_seconds(gw_out.pid), len(out_times))
            time.sleep(1.0)
            s_in, s_out, svc_status = status(client, "dis-in"), status(client, "dis-out"), \
                client.status()
        finally:
            done.set()
            stop(gw_in)
            stop(gw_out)
            stop(plain)
    w0, n0, g0, p0, o0, r0 = marks["start"]
    w1, n1, g1, p1, o1, r1 = end
    pdus, wall = n1 - n0, w1 - w0
    i = s_in["in"]
    refused = sum(i["rejected"].values())
    print(f"{args.entities} entities at 1 Hz for {total:g} s ({sent} PDUs), realtime service, "
          f"measured over the last {wall:.1f} s ({pdus} PDUs)")
    print(f"in: sent {sent} = taken {i['accepted']} + refused {refused} "
          f"({i['rejected']}) + own {i['own']} + ended {i['ended']} "
          f"+ kernel-dropped {i['kernel_dropped']} "
          f"+ unread {sent - i['datagrams'] - i['kernel_dropped']}; "
          f"{i['scans']} scan/ messages ({sent / max(i['scans'], 1):.0f} rows each)")
    print(f"service: {svc_status['tracks']} tracks, meas_accepted {svc_status['meas_accepted']},"
          f" meas_rejected {svc_status['meas_rejected']} {svc_status['rejected_by_reason']}")
    g_us, p_us = 1e6 * (g1 - g0) / pdus, 1e6 * (p1 - p0) / pdus
    print(f"CPU per PDU: track-dis in {g_us:.2f} us (whole process: receive, check, convert, "
          f"send to Zenoh), plain UDP receive loop {p_us:.2f} us: ratio {g_us / p_us:.2f}")
    print(f"CPU: track-dis in {100 * (g1 - g0) / wall:.1f} %, plain loop "
          f"{100 * (p1 - p0) / wall:.1f} %, track-dis out {100 * (o1 - o0) / wall:.1f} % of one "
          "core")
    o = s_out["out"]
    causes = {k: v - out_before["sent"][k] for k, v in o["sent"].items()}
    print(f"out: {o['entities']} entities, {(r1 - r0) / wall:.0f} PDUs per second received "
          f"({(r1 - r0) / wall / max(o['entities'], 1):.3f} per entity per second); sent by "
          f"cause in the last {wall:.0f} s {causes}; {o['frames'] - out_before['frames']} "
          f"frames ({o['frames_dropped']} dropped since start), {o['removed']} removed")


if __name__ == "__main__":
    main()
