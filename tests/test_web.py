"""track-web: the browser's frame format, the server's latest-frame-wins stream, and the
page in a real headless browser (Debian's chromium driven by Playwright) against the real
service on loopback."""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import zenoh

from zenoh_track.clients.lib.process import stop
from zenoh_track.clients.web.frames import UNKNOWN_STATUS, FrameHub, read_message
from zenoh_track.clients.web.web import WINDOW, parse_origin
from zenoh_track.wire import STATUSES, Keys, free_port, pack, unpack

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
# no sandbox (root in CI), software drawing, nothing fetched from the network
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync"]
CONFIRMED_RGB = (0x4A, 0xDE, 0x80)  # STATUS_COLORS[1] of web_static/render.js


def frame_payload(t: float, ids: list[str], pos: np.ndarray, status: bytes | None = None) -> bytes:
    msg = {"t": t, "ids": ids, "pos": pos.astype("<f8").tobytes(),
           "vel": (-pos).astype("<f8").tobytes(),
           "sigma": np.arange(len(ids), dtype="<f8").tobytes()}
    if status is not None:
        msg["status"] = status
    return pack(msg)


# ------------------------------------------------------------------ the frame format
def test_browser_message_carries_the_frame_and_the_ids_only_when_new():
    hub = FrameHub()
    pos = np.array([[1.5, -2.25, 3.0], [1e5, 2e5, 1e4]])
    hub.put(frame_payload(12.5, ["a", "b-2"], pos, bytes([1, 2])))
    frame = hub.latest()
    first = read_message(frame.message(-1, 0))
    assert first["ids"] == ["a", "b-2"] and first["t"] == 12.5 and first["n"] == 2
    assert np.array_equal(first["pos"], pos.astype("<f4"))
    assert np.array_equal(first["vel"], (-pos).astype("<f4"))
    assert first["sigma"].tolist() == [0.0, 1.0] and first["status"].tolist() == [1, 2]
    again = read_message(frame.message(frame.ids_seq, 3, b'{"interceptors": []}'))
    assert again["ids"] is None and again["dropped"] == 3
    assert json.loads(again["extra"]) == {"interceptors": []}
    assert np.array_equal(again["pos"], first["pos"])
    # same ids: same version; new ids: a new version, sent again
    hub.put(frame_payload(12.6, ["a", "b-2"], pos + 1, bytes([1, 1])))
    assert hub.latest().ids_seq == frame.ids_seq
    hub.put(frame_payload(12.7, ["a"], pos[:1]))  # a frame without the status bin
    newer = hub.latest()
    assert newer.ids_seq == frame.ids_seq + 1
    got = read_message(newer.message(frame.ids_seq, 0))
    assert got["ids"] == ["a"] and got["status"].tolist() == [UNKNOWN_STATUS]


def test_a_bad_frame_is_counted_and_the_last_good_one_kept():
    hub = FrameHub()
    hub.put(frame_payload(1.0, ["a"], np.zeros((1, 3))))
    good = hub.latest()
    hub.put(b"\xc1 not msgpack")
    assert hub.latest() is good and hub.bad == 1
    hub.put(pack({"t": 2.0, "ids": ["a", "b"], "pos": b"", "vel": b"", "sigma": b""}))
    assert hub.latest() is good and hub.bad == 2


def test_origin_option():
    assert parse_origin("48.85,2.35,35") == [48.85, 2.35, 35.0]
    for bad in ("48.85,2.35", "north,2,3", "91,0,0"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_origin(bad)


# ------------------------------------------------------------------ the server
class WebProc:
    """`python -m zenoh_track.clients.web.web` on a free port, connected to `endpoint`."""

    def __init__(self, endpoint: str, *extra: str) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "zenoh_track.clients.web.web", "-e", endpoint, "--port",
             str(self.port),
             *extra], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 30
        while True:
            try:
                self.health()
                return
            except OSError:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"track-web did not start: {self.stop()}") from None
                time.sleep(0.1)

    def health(self) -> dict:
        return json.loads(urllib.request.urlopen(f"{self.url}/api/health", timeout=5).read())

    def stop(self) -> str:
        return stop(self.proc)


def listening_peer(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    return zenoh.open(conf)


def poll(condition, timeout: float = 30.0, step: float = 0.1):
    deadline = time.monotonic() + timeout
    while not (value := condition()):
        if time.monotonic() > deadline:
            return value
        time.sleep(step)
    return value


@pytest.mark.slow
def test_a_browser_that_does_not_answer_gets_the_newest_frame_not_a_queue():
    """Frames published while a browser has WINDOW frames unanswered are skipped; its
    next frame after answering is the newest one, with the count of those skipped."""
    import aiohttp

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = listening_peer(endpoint)
    web = WebProc(endpoint)
    pub = session.declare_publisher(Keys().frame,
                                    congestion_control=zenoh.CongestionControl.BLOCK)
    ids, total = ["t1", "t2"], 40

    async def frame(ws) -> dict:
        while True:  # health messages come once a second between the frames
            msg = await ws.receive(timeout=20)
            if msg.type == aiohttp.WSMsgType.BINARY:
                return read_message(msg.data)
            assert msg.type == aiohttp.WSMsgType.TEXT, msg

    async def browse() -> tuple[list[dict], dict]:
        async with aiohttp.ClientSession() as http, http.ws_connect(f"{web.url}/ws") as ws:
            texts = [json.loads((await ws.receive(timeout=20)).data) for _ in range(2)]
            assert [m["type"] for m in texts] == ["config", "health"]
            got = []
            for k in range(1, total + 1):
                pub.put(frame_payload(float(k), ids, np.full((2, 3), float(k))))
                if k <= WINDOW:  # each sent as it comes, until WINDOW are unanswered
                    got.append(await frame(ws))
            assert await asyncio.to_thread(poll, lambda: web.health()["frames_received"]
                                           == total)
            await ws.send_str("ack")
            return got, await frame(ws)

    try:
        first, after = asyncio.run(browse())
    finally:
        err = web.stop()
        session.close()
    assert [f["t"] for f in first] == [1.0, 2.0], err
    assert first[0]["ids"] == ids and first[1]["ids"] is None
    assert after["t"] == float(total) and after["dropped"] == total - WINDOW - 1
    assert np.all(after["pos"] == float(total))


# ------------------------------------------------------------------ the page
@pytest.fixture(scope="module")
def browser():
    if not os.path.exists(CHROMIUM):
        pytest.skip("chromium is not installed (apt-get install -y chromium; the README's "
                    "test command and .ci/run install it)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield b
        b.close()


def page_text(page, element: str) -> str:
    return page.evaluate("id => document.getElementById(id).textContent", element)


def status_of(session: zenoh.Session) -> dict:
    for reply in session.get(Keys().status, timeout=5):
        if reply.ok is not None:
            return unpack(reply.ok.payload.to_bytes())
    raise AssertionError("no status reply")


def pixels_of(page, rgb: tuple[int, int, int]) -> int:
    """Pixels of the map canvas in exactly this colour."""
    return page.evaluate("""([r, g, b]) => {
        const c = document.getElementById('map');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let n = 0;
        for (let i = 0; i < d.length; i += 4) if (d[i] === r && d[i+1] === g && d[i+2] === b) n++;
        return n; }""", list(rgb))


def enu_of(lat: float, lon: float, h: float, origin: list[float]) -> np.ndarray:
    """WGS-84 geodetic -> ENU about `origin` (closed form), to check the page's lat/lon."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)

    def ecef(la: float, lo: float, hh: float) -> np.ndarray:
        la, lo = math.radians(la), math.radians(lo)
        n = a / math.sqrt(1 - e2 * math.sin(la) ** 2)
        return np.array([(n + hh) * math.cos(la) * math.cos(lo),
                         (n + hh) * math.cos(la) * math.sin(lo),
                         (n * (1 - e2) + hh) * math.sin(la)])

    d = ecef(lat, lon, h) - ecef(*origin)
    la, lo = math.radians(origin[0]), math.radians(origin[1])
    rot = np.array([[-math.sin(lo), math.cos(lo), 0],
                    [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
                    [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)]])
    return rot @ d


@pytest.mark.slow
def test_page_draws_the_services_tracks_and_shows_a_clicked_track(service_factory, browser,
                                                                   tmp_path: Path):
    """Scenario multisensor (three radars, unlabelled scans) through a lockstep service:
    the page counts the service's tracks, draws them, shows the health, and a click on a
    track shows its id, its tracks/ state and its latitude/longitude."""
    origin = [48.85, 2.35, 35.0]
    svc, session = service_factory("--clock", "lockstep", "--instance", "web-test")
    frames: list[dict] = []
    sub = session.declare_subscriber(Keys().frame,
                                     lambda s: frames.append(unpack(s.payload.to_bytes())))
    web = WebProc(svc.endpoint, "--origin", ",".join(map(str, origin)))
    try:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(web.url + "/")
        svc.feed("multisensor", "--radars", "3")  # returns once the service has it all
        tracks = status_of(session)["tracks"]
        assert tracks > 0
        assert poll(lambda: page_text(page, "track-count") == str(tracks)), \
            (page_text(page, "track-count"), tracks)
        assert poll(lambda: frames and len(frames[-1]["ids"]) == tracks)
        last = frames[-1]
        assert poll(lambda: "web-test" in page_text(page, "health"))
        assert poll(lambda: pixels_of(page, CONFIRMED_RGB) > 0)
        page.screenshot(path=str(tmp_path / "track-web.png"))

        # click the track farthest from its neighbours, centred, neighbours >= 40 px away
        pos = np.frombuffer(last["pos"], "<f8").reshape(-1, 3)
        status = bytes(last["status"])
        confirmed = [i for i in range(tracks) if STATUSES[status[i]] == "confirmed"]
        gaps = [np.delete(np.hypot(*(pos[:, :2] - pos[i, :2]).T), i).min() for i in confirmed]
        i = confirmed[int(np.argmax(gaps))]
        mpp = max(gaps) / 40
        page.goto(f"{web.url}/#{pos[i, 0]},{pos[i, 1]},{mpp}")
        assert poll(lambda: page_text(page, "track-count") == str(tracks))
        box = page.locator("#map").bounding_box()
        page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        assert poll(lambda: page_text(page, "detail-id") == last["ids"][i])
        assert poll(lambda: f"tracks/{last['ids'][i]}" in page_text(page, "detail-body"))
        body = page_text(page, "detail-body")
        assert "confirmed" in body and "updates" in body
        lat, lon, alt = latlon_of(page_text(page, "detail-latlon"))
        assert np.allclose(enu_of(lat, lon, alt, origin), pos[i], atol=0.5)
        page.screenshot(path=str(tmp_path / "track-web-selected.png"))
        print(f"\ntrack-web screenshots: {tmp_path}")

        # a track-web started now, with the picture paused, has it at once (get frame)
        late = WebProc(svc.endpoint)
        try:
            page.goto(late.url + "/")
            assert poll(lambda: page_text(page, "track-count") == str(tracks))
        finally:
            late.stop()
    finally:
        sub.undeclare()
        err = web.stop()
    assert "Traceback" not in err, err


def latlon_of(text: str) -> tuple[float, float, float]:
    """`48.850123° N 2.350456° E, 35.2 m` -> (lat, lon, alt)."""
    head, alt = text.split(", ")
    lat, ns, lon, ew = head.replace("°", "").split()
    return (float(lat) * (1 if ns == "N" else -1), float(lon) * (1 if ew == "E" else -1),
            float(alt.split()[0]))


@pytest.mark.slow
def test_page_keeps_drawing_a_realtime_service(service_factory, browser, capsys):
    """1,000 targets through a realtime service: the page keeps drawing new frames and
    knows the radar; the frames drawn per second are printed (targets:
    bench/bench_web.py)."""
    n = 1000
    svc, session = service_factory("--clock", "realtime", "--filter", "cv",
                                   "--no-display-keys")
    feed = subprocess.Popen([sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm",
                             "--targets", str(n),
                             "--realtime", "--duration", "600", "-e", svc.endpoint],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    web = WebProc(svc.endpoint)
    try:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(web.url + "/")
        assert poll(lambda: int(page_text(page, "track-count")) == n, timeout=60)
        # the radar, from the sensor_pos of its measurements (a feed that published before
        # it had a link to track-web could not be seen: peers link up in their own time)
        assert poll(lambda: "radar1" in {s["id"] for s in web.health()["sensors"]})
        clock = float(page_text(page, "clock"))
        assert poll(lambda: float(page_text(page, "clock")) > clock + 1.0)
        fps = []
        for _ in range(5):
            time.sleep(1)
            fps.append(int(page_text(page, "fps")))
        assert max(fps) > 0
        with capsys.disabled():
            print(f"\ntrack-web, {n} tracks from a realtime service: drawn "
                  f"{sorted(fps)[2]} frames/s (median of 5 s), "
                  f"{page_text(page, 'draw-ms')} ms per draw, load {os.getloadavg()[0]:.1f}")
    finally:
        stop(feed, timeout=10)
        web.stop()


@pytest.mark.slow
def test_demo_web_serves_the_live_map_and_stops_everything():
    port = free_port()
    # Ctrl-C as in a terminal: SIGINT handled, even when this test runs in a background
    # job (whose children inherit an ignored SIGINT from a shell without job control)
    demo = subprocess.Popen([sys.executable, "-m", "zenoh_track.clients.demo", "--web", "--port",
                             str(port),
                             "--targets", "20"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    url = f"http://127.0.0.1:{port}"
    try:
        line = ""  # the service's own first line may come before (the demo waits for it)
        while "track-demo: the live map is on" not in line:
            line = demo.stdout.readline()
            assert line, "track-demo ended without saying where the map is"

        def health() -> dict | None:
            try:
                return json.loads(urllib.request.urlopen(f"{url}/api/health", timeout=5).read())
            except OSError:
                return None

        assert poll(lambda: (h := health()) and h["alive"] and h["frames_received"] > 0,
                    timeout=60)
        page = urllib.request.urlopen(f"{url}/", timeout=5).read().decode()
        assert 'id="track-count"' in page and "/static/app.js" in page
        demo.send_signal(signal.SIGINT)
        demo.wait(timeout=30)
        assert poll(lambda: health() is None, timeout=10)  # track-web stopped with it
    finally:
        stop(demo)
