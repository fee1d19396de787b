"""track-dis's two sides on real UDP sockets (no Zenoh): what comes in is taken or counted
under its reason; what goes out is what a receiver's dead reckoning needs, within the
standard's thresholds, at most a heartbeat apart on straight flight."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from zenoh_track.clients.dis import pdu, standard
from zenoh_track.clients.dis.geodesy import EnuFrame, body_axes, euler_of
from zenoh_track.clients.dis.inbound import Clocks, Inbound, InConfig, open_socket
from zenoh_track.clients.dis.outbound import DeadReckoner, Outbound, OutConfig, marking
from zenoh_track.clients.lib import Frame
from zenoh_track.wire import STATUSES, Origin

ORIGIN = Origin(43.1, 5.9, 0.0)
ENU = EnuFrame(ORIGIN)


def states(enu: np.ndarray, entity: list[int], stamp: float | np.ndarray, *,
           site: int = 1, app: int = 1, exercise: int = 1, absolute: bool = True
           ) -> np.ndarray:
    n = len(entity)
    out = pdu.entity_state(n)
    pdu.header(out, pdu.ENTITY_STATE, pdu.FAMILY_ENTITY_INFO, exercise,
               pdu.timestamp(np.broadcast_to(stamp, n), absolute))
    out["site"], out["application"], out["entity"] = site, app, entity
    out["location"] = ENU.to_ecef(enu)
    out["velocity"] = ENU.vectors_to_ecef(np.tile([0.0, 100.0, 0.0], (n, 1)))
    return out


class Gateway:
    """An Inbound reading a real loopback UDP socket in a thread; what it sends kept."""

    def __init__(self, **config: object) -> None:
        self.sock = open_socket("127.0.0.1", 0, None)
        self.port = self.sock.getsockname()[1]
        self.scans: list[tuple[np.ndarray, list[str], np.ndarray]] = []
        self.reports: list[tuple[str, int]] = []
        self.inbound = Inbound(self.sock, ENU, InConfig(**config),  # type: ignore[arg-type]
                               lambda t, ids, enu: self.scans.append((t, ids, enu)),
                               lambda code, _text, n: self.reports.append((code, n)))
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.inbound.run, args=(self.stop.is_set,))
        self.thread.start()
        self.tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def send(self, *datagrams: bytes) -> None:
        for d in datagrams:
            self.tx.sendto(d, ("127.0.0.1", self.port))

    def until(self, datagrams: int, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while self.inbound.counts.datagrams < datagrams:
            assert time.monotonic() < deadline, self.inbound.counts
            time.sleep(0.01)

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.sock.close()
        self.tx.close()


@pytest.fixture
def gateway() -> object:
    gw = Gateway(window=0.05)
    yield gw
    gw.close()


def test_entity_states_become_one_scan_row_each_in_the_enu_frame(gateway: Gateway) -> None:
    enu = np.array([[1000.0, -2000.0, 300.0], [5.0, 6.0, 7.0], [-4e4, 3e4, 9e3]])
    now = time.time()
    gateway.send(*(r.tobytes() for r in states(enu, [1, 2, 3], now)))
    gateway.until(3)
    rows = {i: (tt, p) for t, ids, pos in gateway.scans
            for i, tt, p in zip(ids, t, pos, strict=True)}
    assert sorted(rows) == ["1-1-1", "1-1-2", "1-1-3"]
    for k, name in enumerate(["1-1-1", "1-1-2", "1-1-3"]):
        t, p = rows[name]
        assert np.abs(p - enu[k]).max() < 1e-6
        assert abs(t - now) <= 3600 / 2**31
    c = gateway.inbound.counts
    assert (c.accepted, c.rejected, c.own) == (3, {}, 0)
    assert len(gateway.inbound.seen) == 3


def test_every_bad_datagram_is_counted_under_its_reason(gateway: Gateway) -> None:
    now = time.time()
    good = states(np.array([[0.0, 0.0, 100.0]]), [1], now)[0].tobytes()
    v6 = bytearray(good)
    v6[0] = 6
    fire = bytearray(good)
    fire[2] = 2  # a Fire PDU: another type
    far = states(np.zeros((1, 3)), [2], now + 60.0)[0].tobytes()
    centre = states(np.zeros((1, 3)), [3], now)
    centre["location"] = 0.0  # the usual "not set": the Earth's centre
    nan = states(np.zeros((1, 3)), [4], now)
    nan["velocity"][0, 1] = np.nan
    own = states(np.zeros((1, 3)), [5], now, site=standard.OWN_SITE,
                 app=standard.OWN_APPLICATION)[0].tobytes()
    other = states(np.zeros((1, 3)), [6], now, exercise=9)[0].tobytes()
    sent = [good, good[:100], good[:5], bytes(v6), bytes(fire), far, centre.tobytes(),
            nan.tobytes(), own, other]
    gateway.send(*sent)
    gateway.until(len(sent))
    c = gateway.inbound.counts
    assert c.accepted == 1 and c.own == 1
    assert c.rejected == {"truncated": 2, "version": 1, "pdu_type": 1, "time": 1,
                          "absurd": 2, "exercise": 1}
    assert c.accepted + c.own + sum(c.rejected.values()) == c.datagrams == len(sent)
    reported: dict[str, int] = {}
    for code, n in gateway.reports:
        reported[code] = reported.get(code, 0) + n
    assert reported == {k: v for k, v in c.rejected.items() if k != "exercise"}


def test_an_entity_twice_in_a_window_goes_in_successive_scans(gateway: Gateway) -> None:
    now = time.time()
    burst = [states(np.array([[10.0 * k, 0.0, 0.0]]), [7], now - 1.0 + 0.1 * k)[0].tobytes()
             for k in range(7)]
    gateway.send(*burst)
    gateway.until(len(burst))
    c = gateway.inbound.counts
    rows = [(t[0], enu[0, 0]) for t, ids, enu in gateway.scans if ids == ["1-1-7"]]
    # each scan holds the entity once; its rows keep their order; at most PER_WINDOW a window
    assert all(len(ids) == len(set(ids)) for _, ids, _ in gateway.scans)
    assert [x for _, x in rows] == sorted(x for _, x in rows)
    assert c.accepted + c.rejected.get("superseded", 0) == 7 and c.accepted >= 4
    assert rows[-1][1] == pytest.approx(60.0)  # the newest is always taken


def test_remove_entity_and_the_deactivated_bit_end_an_entity(gateway: Gateway) -> None:
    now = time.time()
    gateway.send(*(r.tobytes() for r in states(np.zeros((3, 3)), [1, 2, 3], now)))
    gateway.until(3)
    rm = pdu.remove_entity(1)
    pdu.header(rm, pdu.REMOVE_ENTITY, pdu.FAMILY_SIMULATION_MANAGEMENT, 1, 0)
    rm["receiving"]["site"], rm["receiving"]["application"], rm["receiving"]["entity"] = 1, 1, 2
    off = states(np.zeros((1, 3)), [3], now)
    off["appearance"] = pdu.DEACTIVATED
    gateway.send(rm.tobytes(), off.tobytes())
    gateway.until(5)
    c = gateway.inbound.counts
    assert c.removed == c.ended == 2 and c.accepted == 3 and c.datagrams == 5
    assert list(gateway.inbound.names.values()) == ["1-1-1"]


def test_silent_entities_time_out() -> None:
    gw = Gateway(window=0.02, timeout=0.3)
    try:
        gw.send(states(np.zeros((1, 3)), [1], time.time())[0].tobytes())
        gw.until(1)
        deadline = time.monotonic() + 10
        while gw.inbound.counts.timed_out == 0:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        assert not gw.inbound.seen
    finally:
        gw.close()


def test_a_multicast_group_on_loopback() -> None:
    group = "239.255.3.0"
    with open_socket("127.0.0.1", 0, group) as sock, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        sock.settimeout(5.0)
        tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
        data = states(np.zeros((1, 3)), [1], time.time())[0].tobytes()
        tx.sendto(data, (group, sock.getsockname()[1]))
        assert sock.recv(2048) == data


def test_accept_filter_and_arrival_time() -> None:
    gw = Gateway(window=0.02, accept=frozenset({(1, 1)}), clock="arrival")
    try:
        stale = time.time() - 3000.0  # any timestamp: the arrival counts
        gw.send(states(np.zeros((1, 3)), [1], stale)[0].tobytes(),
                states(np.zeros((1, 3)), [2], stale, site=2)[0].tobytes())
        gw.until(2)
        (t, ids, _), = gw.scans
        assert ids == ["1-1-1"] and abs(t[0] - time.time()) < 5.0
        assert gw.inbound.counts.rejected == {"filtered": 1}
    finally:
        gw.close()


def test_times_absolute_nearest_hour_and_relative_continuous() -> None:
    past = np.array([3599.9])
    assert Clocks.nearest_hour(past, np.array([7200.05]))[0] == pytest.approx(7199.9)
    clocks = Clocks()
    sender = np.array([5, 5, 5], np.int64)
    t = clocks.relative(sender, np.array([3598.5, 3599.5, 0.5]), np.full(3, 1e9))
    assert np.diff(t) == pytest.approx([1.0, 1.0])
    t2 = clocks.relative(sender[:1], np.array([1.5]), np.array([2e9]))  # its own clock
    assert t2[0] - t[-1] == pytest.approx(1.0)


# ---------------------------------------------------------------- out
def frames(path: object, seconds: float, rate: float = 30.0) -> list[Frame]:
    """One track "plane" along `path(t) -> (pos, vel)` ENU, a frame each 1/rate s."""
    out = []
    for k in range(int(seconds * rate) + 1):
        t = 1000.0 + k / rate
        p, v = path(t - 1000.0)  # type: ignore[operator]
        out.append(Frame(t, ["plane"], np.array([p]), np.array([v]), np.ones(1),
                         np.array([STATUSES.index("confirmed")], np.uint8)))
    return out


def fly(path: object, seconds: float, dr: str = "fvw") -> tuple[list[bytes], float]:
    """The PDUs out for the frames of `path`, and the largest distance between a
    receiver's dead-reckoned position and the frame's, over every frame."""
    sent: list[bytes] = []
    out = Outbound(ENU, OutConfig(dr=dr), sent.append)
    receiver, worst = DeadReckoner(), 0.0
    for f in frames(path, seconds):
        before = len(sent)
        out.on_frame(f)
        for d in sent[before:]:
            es = np.frombuffer(d, pdu.ENTITY_STATE_PDU)[0]
            past = pdu.seconds_past_hour(np.array([es["timestamp"]]))
            receiver.take(float(Clocks.nearest_hour(past, np.array([f.t]))[0]), es)
        (key,) = receiver.latest
        got = ENU.to_enu(receiver.position(key, f.t)[None])[0]  # type: ignore[index]
        worst = max(worst, float(np.linalg.norm(got - f.pos[0])))
    return sent, worst


def straight(t: float) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([150.0, 200.0, 0.0])
    return np.array([0.0, 0.0, 3000.0]) + v * t, v


def turning(t: float) -> tuple[np.ndarray, np.ndarray]:
    w, r = np.radians(3.0), 200.0 / np.radians(3.0)  # 200 m/s, 3 deg/s
    return (np.array([r * np.sin(w * t), r * (1 - np.cos(w * t)), 3000.0]),
            np.array([200.0 * np.cos(w * t), 200.0 * np.sin(w * t), 0.0]))


@pytest.mark.parametrize("dr", ["fvw", "fpw", "rvw"])
def test_straight_flight_goes_out_at_the_heartbeat_only(dr: str) -> None:
    sent, worst = fly(straight, 20.0, dr)
    assert len(sent) == 5  # new, then at 5, 10, 15 and 20 s
    assert worst < 1e-3  # float32 velocities: the picture stays on the line


@pytest.mark.parametrize("dr", ["fvw", "fpw", "rvw"])
def test_turning_flight_stays_within_the_thresholds(dr: str) -> None:
    sent, worst = fly(turning, 20.0, dr)
    assert worst <= standard.DRA_POS_THRSH + 1e-6
    assert 5 < len(sent) < 20 * 30 / 2  # more than heartbeats, far fewer than frames
    es = np.frombuffer(b"".join(sent), pdu.ENTITY_STATE_PDU)
    assert set(es["dr_algorithm"].tolist()) == {standard.DR_ALGORITHMS[dr][0]}
    # the orientation stated is along the velocity stated
    assert np.allclose(euler_of(body_axes(es["location"].astype(float),
                                          es["velocity"].astype(float))),
                       es["orientation"].astype(float), atol=1e-6)


def test_a_track_that_leaves_goes_out_deactivated_then_removed() -> None:
    sent: list[bytes] = []
    out = Outbound(ENU, OutConfig(), sent.append)
    f = frames(straight, 0.1)
    out.on_frame(f[0])
    out.on_frame(Frame(f[1].t, [], np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                       np.zeros(0, np.uint8)))
    first, last, remove = sent
    es = np.frombuffer(last, pdu.ENTITY_STATE_PDU)[0]
    assert es["appearance"] & pdu.DEACTIVATED and es["entity"] == \
        np.frombuffer(first, pdu.ENTITY_STATE_PDU)[0]["entity"]
    rm = np.frombuffer(remove, pdu.REMOVE_ENTITY_PDU)[0]
    assert rm["pdu_type"] == pdu.REMOVE_ENTITY and rm["receiving"]["entity"] == es["entity"]
    assert out.counts.removed == 1 and not out.table.index


def test_markings_short_and_distinct() -> None:
    assert marking("ship-7", 3) == "ship-7"
    long = [marking("maneuver-000123", n) for n in (1, 2, 65534)]
    assert long == ["maneu~00001", "maneu~00002", "maneu~65534"]
    assert all(len(m) == 11 for m in long)
    sent: list[bytes] = []
    out = Outbound(ENU, OutConfig(), sent.append)
    ids = [f"aircraft-{i:05d}-long" for i in range(50)]
    out.on_frame(Frame(1.0, ids, np.zeros((50, 3)), np.ones((50, 3)), np.ones(50),
                       np.full(50, STATUSES.index("confirmed"), np.uint8)))
    marks = np.frombuffer(b"".join(sent), pdu.ENTITY_STATE_PDU)["marking"]
    assert len(set(marks.tolist())) == 50
