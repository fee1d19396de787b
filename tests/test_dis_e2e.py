"""track-dis end to end: real processes on loopback (the service, the gateway, the
simulation's sender), real UDP sockets. Scenario A through DIS both ways; the gateway's
own PDUs never read back; bad input reported; the deployment's one origin enforced
(operator mistakes: one line, exit status 2)."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from zenoh_track.clients.dis import pdu, standard
from zenoh_track.clients.dis.geodesy import EnuFrame
from zenoh_track.clients.lib import ServiceProcess
from zenoh_track.clients.lib.process import stop
from zenoh_track.wire import Origin, free_port, unpack

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
import dis_scenario_a as scenario  # noqa: E402

GATEWAY = [sys.executable, "-m", "zenoh_track.clients.dis.gateway"]
ORIGIN = Origin(43.1, 5.9, 0.0)


def udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def gateway_status(client: object, name: str = "dis") -> dict:
    for r in client.session.get(f"track/gateway/{name}/status", timeout=3.0):  # type: ignore
        if r.ok is not None:
            return unpack(r.ok.payload.to_bytes())
    return {}


def poll(condition: object, timeout: float = 30.0) -> object:
    deadline = time.monotonic() + timeout
    while not (value := condition()):  # type: ignore[operator]
        assert time.monotonic() < deadline, "condition not met"
        time.sleep(0.1)
    return value


@pytest.mark.slow
def test_scenario_a_through_dis_both_ways() -> None:
    """The frames through DIS as accurate as the same positions on Zenoh (RMS within 1 %);
    the PDUs out dead-reckoned by a receiver within 1 m of the service's frames at every
    frame instant; at most one PDU a second on straight flight."""
    zen = scenario.via_zenoh()
    dis, status = scenario.via_dis(10.0)
    rms_z = np.sqrt(np.mean(scenario.frame_errors(zen) ** 2))
    rms_d = np.sqrt(np.mean(scenario.frame_errors(dis) ** 2))
    assert len(scenario.frame_errors(dis)) == len(scenario.frame_errors(zen)) > 1500
    assert abs(rms_d / rms_z - 1.0) < 0.01, (rms_d, rms_z)
    assert status["in"]["accepted"] == 57 and not status["in"]["rejected"]
    ts, got, want = scenario.receiver_picture(dis)
    assert len(ts) > 1500
    assert np.linalg.norm(got - want, axis=1).max() <= standard.DRA_POS_THRSH + 1e-3
    straight = dict((name, n / (t1 - t0)) for name, t0, t1, n in scenario.phases(dis))
    assert straight["straight"] <= 1.0
    assert len(dis.pdus) < 56  # far fewer than one a second over the flight


@pytest.mark.slow
def test_own_pdus_never_come_back_bad_input_reported_tracks_end() -> None:
    """A realtime service; the gateway sends its PDUs to its own port (the default): they
    are counted as its own and never measured. A truncated PDU is reported on
    errors/dis. When the entity stops, the gateway times it out, the service deletes the
    track, and the gateway sends it out deactivated and removed."""
    with ServiceProcess("--origin", ORIGIN.text(), "--delete-after", "2",
                        clock="realtime") as svc:
        client = svc.wait()
        errors: list[dict] = []
        sub = client.session.declare_subscriber(
            "track/errors/dis", lambda s: errors.append(unpack(s.payload.to_bytes())))
        port = udp_port()
        gw = subprocess.Popen([*GATEWAY, "-e", svc.endpoint, "--port", str(port),
                               "--timeout", "1"], stderr=subprocess.PIPE, text=True)
        try:
            poll(lambda: gateway_status(client))
            tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            enu = EnuFrame(ORIGIN)
            for k in range(4):
                es = pdu.entity_state(1)
                now = time.time()
                pdu.header(es, pdu.ENTITY_STATE, pdu.FAMILY_ENTITY_INFO, 1,
                           pdu.timestamp([now], True))
                es["site"], es["application"], es["entity"] = 1, 1, 9
                es["location"] = enu.to_ecef(np.array([[100.0 * k, 0.0, 500.0]]))
                es["velocity"] = enu.vectors_to_ecef(np.array([[100.0, 0.0, 0.0]]))
                tx.sendto(es.tobytes(), ("127.0.0.1", port))
                time.sleep(max(0.0, now + 1.0 - time.time()))
            tx.sendto(es.tobytes()[:60], ("127.0.0.1", port))
            # its own PDUs (new ... removed) come back through the kernel after they are
            # counted as sent: awaited, not read at once
            done = poll(lambda: (s := gateway_status(client)) and s["out"]["removed"] >= 1
                        and s["in"]["own"] >= 2 and s)
            assert client.status()["tracks"] == 0
            assert done["in"]["accepted"] == 4
            assert done["in"]["timed_out"] == 1 and done["in"]["rejected"] == {"truncated": 1}
            assert done["out"]["sent"]["new"] == 1
            assert client.status()["meas_accepted"] == 4  # its own PDUs never measured
            poll(lambda: errors)
            assert errors[0]["code"] == "truncated" and errors[0]["count"] == 1
            # a flood of another version: every datagram counted (read and refused, or
            # dropped by the kernel), reported in a few messages, the gateway still serving
            flood = bytes([5]) + es.tobytes()[1:]
            for _ in range(5000):
                tx.sendto(flood, ("127.0.0.1", port))

            def flooded() -> dict | None:
                s = gateway_status(client)["in"]
                seen = s["rejected"].get("version", 0) + s["kernel_dropped"]
                reported = sum(e["count"] for e in errors if e["code"] == "version")
                return s if seen == 5000 and reported == s["rejected"].get("version") else None

            poll(flooded)
            assert 1 <= sum(e["code"] == "version" for e in errors) <= 10
        finally:
            err = stop(gw)
            sub.undeclare()
    assert "Traceback" not in err


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(list(args), capture_output=True, text=True, timeout=60)


@pytest.mark.slow
def test_operator_mistakes_end_with_one_line_and_status_2() -> None:
    bad = run(sys.executable, "-m", "zenoh_track", "-l", f"tcp/127.0.0.1:{free_port()}",
              "--origin", "91,0,0")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--origin" in bad.stderr
    with ServiceProcess("--origin", ORIGIN.text()) as svc:
        client = svc.wait()
        origin = unpack(next(iter(client.session.get("track/origin", timeout=5))).ok
                        .payload.to_bytes())
        assert origin == {"frame": "enu", "datum": "WGS-84", "lat": 43.1, "lon": 5.9,
                          "alt": 0.0}
        other = run(*GATEWAY, "-e", svc.endpoint, "--origin", "43.1,5.9001,0",
                    "--port", str(udp_port()))
        assert other.returncode == 2 and other.stderr.count("\n") == 1
        assert "disagrees with the service's origin 43.1,5.9,0" in other.stderr
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
            taken.bind(("127.0.0.1", 0))
            busy = run(*GATEWAY, "-e", svc.endpoint, "--port", str(taken.getsockname()[1]))
        assert busy.returncode == 2 and busy.stderr.strip().endswith("--port)"), busy.stderr
        assert "cannot receive on udp/127.0.0.1" in busy.stderr
        web = run(sys.executable, "-m", "zenoh_track.clients.web.web", "-e", svc.endpoint,
                  "--origin", "0,0,0", "--port", str(free_port()))
        assert web.returncode == 2 and "disagrees" in web.stderr
    with ServiceProcess() as local:
        local.wait()
        none = run(*GATEWAY, "-e", local.endpoint, "--port", str(udp_port()))
        assert none.returncode == 2 and "no geodetic origin" in none.stderr


@pytest.mark.slow
def test_track_web_takes_the_services_origin() -> None:
    import asyncio

    import aiohttp

    from zenoh_track.clients.lib.process import stop as stop_proc

    with ServiceProcess("--origin", ORIGIN.text()) as svc:
        client = svc.wait()
        assert client.status()["origin"] == {"frame": "enu", "datum": "WGS-84", "lat": 43.1,
                                             "lon": 5.9, "alt": 0.0}
        port = free_port()
        web = subprocess.Popen([sys.executable, "-m", "zenoh_track.clients.web.web", "-e",
                                svc.endpoint, "--port", str(port)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

        async def config() -> dict:
            async with aiohttp.ClientSession() as http, \
                    http.ws_connect(f"http://127.0.0.1:{port}/ws") as ws:
                return json.loads((await ws.receive(timeout=20)).data)

        try:
            def up() -> dict | None:
                try:
                    return asyncio.run(config())
                except aiohttp.ClientError:
                    return None

            got = poll(up)
        finally:
            stop_proc(web)
    assert got["type"] == "config" and got["origin"] == [43.1, 5.9, 0.0]  # type: ignore
