"""track-foxglove: the scene and location fixes as Foxglove's SDK encodes them and as a
protobuf decoder reads them; the shipped layout; and through real processes on loopback
(service, feed, `track-foxglove`, a Foxglove protocol client): what a viewer receives,
and a slow viewer that gets recent frames while the server's memory stays put."""

from __future__ import annotations

import asyncio
import json
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pymap3d
import pytest
import zenoh
from foxglove_client import FoxgloveClient, message_class

from zenoh_track.clients import connect
from zenoh_track.clients.foxglove.server import (
    COUNTERS_TOPIC,
    FIXES_TOPIC,
    STATUS_TOPIC,
    layout_text,
)
from zenoh_track.clients.lib import scene
from zenoh_track.clients.lib.frames import NO_STATUS, Frame
from zenoh_track.clients.lib.process import stop
from zenoh_track.wire import STATUSES, Keys, free_port, pack

PY = sys.executable
ORIGIN = (48.85, 2.35, 35.0)
SceneUpdate = message_class(scene.SCENE_SCHEMA, scene.schema(scene.SCENE_SCHEMA))
LocationFixes = message_class(scene.LOCATION_SCHEMA, scene.schema(scene.LOCATION_SCHEMA))


def random_frame(n: int, seed: int = 3, t: float = 12.25) -> Frame:
    rng = np.random.default_rng(seed)
    ids = [f"trk-{i}" * (1 + i % 3) for i in range(n)]  # three lengths of id
    vel = rng.normal(0, 100, (n, 3))
    vel[::7] = 0.0  # standing still: no arrow
    return Frame(t, ids, rng.uniform(-1e5, 1e5, (n, 3)), vel, rng.uniform(5, 400, n),
                 (np.arange(n) % (NO_STATUS + 1)).astype(np.uint8))


def rotate_x(q) -> np.ndarray:
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)])


# ------------------------------------------------------------------ the encoding
def test_the_scene_is_byte_for_byte_the_sdks_encoding():
    """Built with the SDK's message objects (one id length: one label group) in the
    same order, the SDK's `encode()` gives the very bytes of `scene_update`."""
    from foxglove import messages as fm

    f = random_frame(40, seed=5)
    ids = [f"t{i:03d}" for i in range(len(f))]
    f = Frame(f.t, ids, f.pos, f.vel + 0.5, f.sigma, f.codes)  # every track moves
    marker, arrow_s = 100.0, 10.0
    speed = np.linalg.norm(f.vel, axis=1)  # as the scene computes it, to the last bit
    stamp = fm.Timestamp(sec=12, nsec=250_000_000)
    entities = []
    for code in range(NO_STATUS + 1):
        rows = np.flatnonzero(f.codes == code)
        r, g, b = scene.COLOURS[code]

        def col(a: float, r=r, g=g, b=b) -> fm.Color:
            return fm.Color(r=r, g=g, b=b, a=a)

        def pose(i: int, q=None) -> fm.Pose:
            p = f.pos[i]
            return fm.Pose(position=fm.Vector3(x=p[0], y=p[1], z=p[2]),
                           orientation=q or fm.Quaternion(x=0, y=0, z=0, w=1))

        arrows = []
        for i in rows:
            y, z, w = scene.headings(f.vel[i:i + 1])[0]
            length = float(speed[i]) * arrow_s
            arrows.append(fm.ArrowPrimitive(
                pose=pose(i, fm.Quaternion(x=0.0, y=y, z=z, w=w)),
                shaft_length=0.8 * length, shaft_diameter=max(marker / 5, 0.02 * length),
                head_length=0.2 * length, head_diameter=max(marker / 2, 0.06 * length),
                color=col(0.9)))
        entities.append(fm.SceneEntity(
            timestamp=stamp, frame_id="enu",
            id=f"tracks/{(*STATUSES, 'unknown')[code]}",
            metadata=[fm.KeyValuePair(key="count", value=str(len(rows)))],
            arrows=arrows,
            cubes=[fm.CubePrimitive(pose=pose(i), size=fm.Vector3(x=marker, y=marker, z=marker),
                                    color=col(1.0)) for i in rows],
            spheres=[fm.SpherePrimitive(pose=pose(i), size=fm.Vector3(
                x=2 * f.sigma[i], y=2 * f.sigma[i], z=2 * f.sigma[i]), color=col(0.25))
                for i in rows if 2 * f.sigma[i] > marker],
            texts=[fm.TextPrimitive(pose=pose(i), billboard=True, font_size=12.0,
                                    scale_invariant=True, color=col(1.0), text=ids[i])
                   for i in rows]))
    sdk = fm.SceneUpdate(deletions=[fm.SceneEntityDeletion(
        timestamp=stamp, type=fm.SceneEntityDeletionType.All)], entities=entities).encode()
    assert scene.scene_update(f, marker=marker, arrow_s=arrow_s) == sdk


def test_a_decoded_scene_holds_every_track_as_drawn():
    f = random_frame(500)
    sensors = [{"id": "radar1", "pos": [1000.0, -2000.0, 10.0]}]
    interceptors = [{"id": "interceptor-1", "pos": [0.0, 0.0, 500.0], "vel": [0.0, 300.0, 0.0]}]
    update = SceneUpdate.FromString(scene.scene_update(
        f, marker=100.0, sensors=sensors, interceptors=interceptors))
    assert [d.type for d in update.deletions] == [1]  # ALL: ended tracks disappear
    by_id = {e.id: e for e in update.entities}
    assert set(by_id) == {"tracks/tentative", "tracks/confirmed", "tracks/coasting",
                          "tracks/unknown", "sensors", "interceptors"}
    seen = {}
    for code, name in enumerate((*STATUSES, "unknown")):
        e = by_id[f"tracks/{name}"]
        rows = np.flatnonzero(f.codes == code)
        assert (e.frame_id, e.timestamp.seconds, e.timestamp.nanos) == ("enu", 12, 250_000_000)
        assert len(e.cubes) == len(rows) and len(e.texts) == len(rows)
        assert all(c.color.r == pytest.approx(scene.COLOURS[code][0]) for c in e.cubes)
        texts = {t.text: (t.pose.position.x, t.pose.position.y, t.pose.position.z)
                 for t in e.texts}
        for i in rows:
            assert texts[f.id_list[i]] == tuple(f.pos[i])
            seen[f.id_list[i]] = name
        big = [i for i in rows if 2 * f.sigma[i] > 100.0]
        assert sorted(s.size.x for s in e.spheres) == pytest.approx(sorted(2 * f.sigma[big]))
        moving = [i for i in rows if np.any(f.vel[i])]
        assert len(e.arrows) == len(moving)
        for a, i in zip(e.arrows, moving, strict=True):  # rows keep their order
            v = f.vel[i] / np.linalg.norm(f.vel[i])
            assert rotate_x(a.pose.orientation) == pytest.approx(v, abs=1e-9)
            assert a.shaft_length + a.head_length == pytest.approx(
                10.0 * np.linalg.norm(f.vel[i]))
    assert len(seen) == len(f)
    assert [t.text for t in by_id["sensors"].texts] == ["radar1"] and not by_id["sensors"].arrows
    assert by_id["interceptors"].arrows[0].shaft_length == pytest.approx(0.8 * 3000.0)


def test_location_fixes_are_the_tracks_in_latitude_and_longitude():
    f = random_frame(300)
    fixes = LocationFixes.FromString(scene.location_fixes(f, ORIGIN)).fixes
    assert len(fixes) == len(f)
    row = {tid: i for i, tid in enumerate(f.id_list)}
    lat, lon, alt = pymap3d.enu2geodetic(*f.pos.T, *ORIGIN)
    for fix in fixes:
        i = row[fix.frame_id]
        assert (fix.latitude, fix.longitude, fix.altitude) == pytest.approx(
            (lat[i], lon[i], alt[i]), abs=1e-9)
        assert list(fix.position_covariance) == pytest.approx(
            [f.sigma[i] ** 2, 0, 0, 0, f.sigma[i] ** 2, 0, 0, 0, f.sigma[i] ** 2])
        assert fix.position_covariance_type == 2  # DIAGONAL_KNOWN
        assert fix.color.r == pytest.approx(scene.COLOURS[min(f.codes[i], NO_STATUS)][0])
        assert (fix.timestamp.seconds, fix.timestamp.nanos) == (12, 250_000_000)
    # a known place: 10 km north of the origin is 0.0899 deg of latitude further
    north = Frame(0.0, ["n"], np.array([[0.0, 10_000.0, 0.0]]), np.zeros((1, 3)),
                  np.ones(1), np.zeros(1, np.uint8))
    fix = LocationFixes.FromString(scene.location_fixes(north, ORIGIN)).fixes[0]
    assert fix.latitude - ORIGIN[0] == pytest.approx(0.0899, abs=2e-4)
    assert fix.longitude == pytest.approx(ORIGIN[1], abs=1e-9)


def test_the_schemas_shipped_are_the_sdks():
    from foxglove.messages import LocationFixes as SdkFixes
    from foxglove.messages import SceneUpdate as SdkScene

    assert scene.schema(scene.SCENE_SCHEMA) == SdkScene.get_schema().data
    assert scene.schema(scene.LOCATION_SCHEMA) == SdkFixes.get_schema().data


def test_the_layout_names_the_servers_topics():
    layout = json.loads(layout_text())
    panels = layout["configById"]
    assert {k.split("!")[0] for k in panels} >= {"3D", "map", "Plot"}
    paths = [p["value"].split(".")[0] for k, c in panels.items() if k.startswith("Plot!")
             for p in c["paths"]]
    assert set(paths) <= {COUNTERS_TOPIC, STATUS_TOPIC}
    assert panels["3D!tracks"]["topics"] == {scene.TOPIC: {"visible": True}}

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(
            node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)


# ------------------------------------------------------------------ real processes
def start_foxglove(endpoint: str, port: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [PY, "-m", "zenoh_track.clients.foxglove.server", "--mode", "client", "-e", endpoint,
         "--port", str(port), *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)


async def connected(port: int, *topics: str, timeout: float = 30.0,
                    rcvbuf: int | None = None) -> FoxgloveClient:
    """A client of the server on `port`, once it listens and advertises `topics`."""
    deadline = time.monotonic() + timeout
    while True:
        client = FoxgloveClient()
        try:
            await client.connect(f"ws://127.0.0.1:{port}", advertised=set(topics),
                                 rcvbuf=rcvbuf)
            return client
        except OSError:
            await client.close()
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)


@pytest.mark.slow
def test_a_protocol_client_receives_the_services_picture(service_factory):
    proc, _ = service_factory("--clock", "realtime", "--filter", "cv")
    feed = subprocess.Popen([PY, "-m", "zenoh_track.clients.feeds.feed", "multisensor",
                             "--radars", "3", "--realtime", "--duration", "60", "--mode",
                             "client", "-e", proc.endpoint], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    port = free_port()
    fox = start_foxglove(proc.endpoint, port, "--origin", ",".join(map(str, ORIGIN)))
    frames: dict[float, list[str]] = {}
    try:
        with connect(proc.endpoint, mode="client") as client, client.picture() as picture:
            def keep() -> None:
                for fr in picture:
                    frames[round(fr.t, 6)] = fr.id_list

            threading.Thread(target=keep, daemon=True).start()

            async def run() -> tuple[list, list]:
                c = await connected(port, scene.TOPIC, FIXES_TOPIC, COUNTERS_TOPIC,
                                    STATUS_TOPIC)
                try:
                    assert c.server_info["name"].startswith("track-foxglove")
                    await c.subscribe(scene.TOPIC, FIXES_TOPIC, COUNTERS_TOPIC, STATUS_TOPIC)
                    got: dict[str, list] = {}
                    deadline = time.monotonic() + 60
                    while time.monotonic() < deadline and not (
                            len(got.get(scene.TOPIC, [])) >= 30 and STATUS_TOPIC in got
                            and got[scene.TOPIC][-1].entities[0].cubes):
                        topic, _, payload = await c.receive()
                        got.setdefault(topic, []).append(c.decode(topic, payload))
                    stamp = got[scene.TOPIC][-1].entities[0].timestamp
                    t = round(stamp.seconds + stamp.nanos / 1e9, 6)
                    while round(got.get(COUNTERS_TOPIC, [{"t": -1}])[-1]["t"], 6) != t:
                        topic, _, payload = await c.receive()  # the last scene's counters
                        got.setdefault(topic, []).append(c.decode(topic, payload))
                    return got[scene.TOPIC], got[FIXES_TOPIC], got[COUNTERS_TOPIC], \
                        got[STATUS_TOPIC]
                finally:
                    await c.close()

            scenes, fixes, counters, status = asyncio.run(run())
    finally:
        stop(fox)
        stop(feed)
    last = scenes[-1]
    t = round(last.entities[0].timestamp.seconds + last.entities[0].timestamp.nanos / 1e9, 6)
    tracks = sorted(x.text for e in last.entities if e.id.startswith("tracks/")
                    for x in e.texts)
    assert t in frames and tracks == sorted(frames[t]) and tracks  # the service's frame
    sensors = next(e for e in last.entities if e.id == "sensors")
    assert sorted(x.text for x in sensors.texts) == ["radar1", "radar2", "radar3"]
    assert any(len(m.fixes) for m in fixes)
    assert all(abs(x.latitude - ORIGIN[0]) < 3 for m in fixes for x in m.fixes)
    assert counters[-1]["tracks"] == len(tracks) > 0  # the same frame's
    assert sum(counters[-1][s] for s in (*STATUSES, "unknown")) == counters[-1]["tracks"]
    assert status[-1]["tracks"] >= 0 and "meas_accepted" in status[-1]


class FramePublisher:
    """`<ns>/frame` at 30 Hz for n tracks on straight lines, from a peer listening on
    `endpoint`; `t` the latest frame's time."""

    def __init__(self, endpoint: str, n: int, rate: float = 30.0) -> None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
        self.session = zenoh.open(conf)
        rng = np.random.default_rng(2)
        self.pos = rng.uniform(-1e5, 1e5, (n, 3))
        self.vel = rng.normal(0, 150, (n, 3))
        self.ids = [f"swarm-{i:05d}" for i in range(n)]
        self.rate, self.t = rate, 0.0
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        pub = self.session.declare_publisher(Keys().frame,
                                             congestion_control=zenoh.CongestionControl.DROP)
        start, k = time.monotonic(), 0
        sigma = np.full(len(self.ids), 300.0).tobytes()
        while not self.stopping.is_set():
            t = k / self.rate
            pub.put(pack({"t": t, "ids": self.ids, "pos": (self.pos + self.vel * t).tobytes(),
                          "vel": self.vel.tobytes(), "sigma": sigma,
                          "status": bytes([1]) * len(self.ids)}))
            self.t = t
            k += 1
            self.stopping.wait(max(start + k / self.rate - time.monotonic(), 0.0))

    def close(self) -> None:
        self.stopping.set()
        self.thread.join()
        self.session.close()


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


@pytest.mark.slow
def test_a_viewer_that_pauses_is_then_given_the_newest_frame_not_a_queue():
    """A viewer that stops reading for a while, then reads again: what it reads first is
    what its own connection held (its client's message read ahead, then the frame in
    flight, both from before the pause), and the next is the frame newest when the pause
    ended: nothing queued for it meanwhile. Another viewer, reading all along, is given
    frames throughout the pauses. The server's memory does not grow."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    frames = FramePublisher(endpoint, 3000)  # a scene of 1.4 MB: more than the buffers
    port = free_port()
    fox = subprocess.Popen(
        [PY, "-m", "zenoh_track.clients.foxglove.server", "-e", endpoint, "--port", str(port)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    pauses, memory, steady = [], [], []
    try:
        async def read_all_along(c: FoxgloveClient) -> None:
            while True:
                _, _, payload = await c.receive()
                stamp = SceneUpdate.FromString(payload).entities[0].timestamp
                steady.append(stamp.seconds + stamp.nanos / 1e9)

        async def run() -> None:
            other = await connected(port, scene.TOPIC)
            reader = None
            c = None
            try:
                # one viewer after the other (two that subscribe within the same
                # millisecond may be told apart wrongly: docs/foxglove.md)
                await other.subscribe(scene.TOPIC)
                reader = asyncio.create_task(read_all_along(other))
                deadline = time.monotonic() + 30
                while not steady and time.monotonic() < deadline:
                    await asyncio.sleep(0.05)
                c = await connected(port, scene.TOPIC, rcvbuf=1 << 16)
                await c.subscribe(scene.TOPIC)
                for _ in range(4):
                    started = frames.t
                    await asyncio.sleep(2.0)  # reads nothing meanwhile
                    ended = frames.t  # the newest frame published when the pause ends
                    assert steady and steady[-1] > started, (started, steady[-3:])
                    stamps = []
                    for _ in range(3):
                        _, _, payload = await c.receive()
                        stamp = SceneUpdate.FromString(payload).entities[0].timestamp
                        stamps.append(stamp.seconds + stamp.nanos / 1e9)
                    pauses.append((ended, stamps))
                    memory.append(rss_mb(fox.pid))
            finally:
                if reader is not None:
                    reader.cancel()
                if c is not None:
                    await c.close()
                await other.close()

        asyncio.run(run())
    finally:
        stop(fox)
        frames.close()
    print(f"newest frame at each pause's end and the three read after it: {pauses}; "
          f"server RSS, MB: {[round(m) for m in memory]}")
    for ended, stamps in pauses[1:]:  # the first pause starts with the buffers empty
        assert stamps[0] <= stamps[1] < ended - 1e-6 <= stamps[2], (ended, stamps)
    assert memory[-1] - memory[0] < 30, memory


def test_a_viewers_connection_is_found_and_its_unsent_bytes_counted():
    from zenoh_track.clients.foxglove.sockets import accepted

    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    client = socket.create_connection(("127.0.0.1", port))
    client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 64 * 1024)
    served, _ = listener.accept()
    try:
        [conn] = accepted(port)  # not the listening socket
        assert conn.fd == served.fileno() and conn.alive()
        conn.set_send_buffer(64 * 1024)
        assert served.getsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF) == 2 * 64 * 1024
        assert client.getsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF) != 2 * 64 * 1024
        assert conn.unsent() == 0
        served.setblocking(False)
        sent = 0
        try:
            while True:  # until the client's receive buffer and this send buffer are full
                sent += served.send(b"x" * 65536)
        except BlockingIOError:
            pass
        assert 0 < conn.unsent() <= sent
        got = 0
        client.settimeout(5)
        while got < sent:
            got += len(client.recv(1 << 20))
        deadline = time.monotonic() + 5
        while conn.unsent() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert conn.unsent() == 0
    finally:
        for s in (client, served):
            s.close()
    assert not conn.alive() and conn.unsent() is None
    listener.close()


def test_a_viewers_connection_is_the_one_that_has_just_sent_something():
    from zenoh_track.clients.foxglove.sockets import Connection, accepted

    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    clients = [socket.create_connection(("127.0.0.1", port)) for _ in range(3)]
    served = [listener.accept()[0] for _ in clients]
    try:
        for speaker in (1, 0, 2):
            clients[speaker].sendall(b"subscribe")
            deadline = time.monotonic() + 5
            while served[speaker].recv(64, socket.MSG_PEEK) != b"subscribe":
                assert time.monotonic() < deadline
            first = min(accepted(port), key=Connection.recency)
            assert first.fd == served[speaker].fileno()
            served[speaker].recv(64)
            time.sleep(0.01)  # a millisecond tick at least between the speakers
    finally:
        for s in (*clients, *served, listener):
            s.close()
