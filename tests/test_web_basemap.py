"""track-web's geography in a real browser (Debian's chromium, Playwright): the
Natural Earth coastline drawn where it belongs (a vertex of the shipped file at the pixel
pymap3d puts it), the page's geodesy against pymap3d, sensors' range rings, nothing
fetched beyond track-web by default and an operator's tile server when asked, labels
that never overlap, and the details panel's covariance table whole at 1,400 px."""

from __future__ import annotations

import http.server
import json
import threading
import time
from importlib import resources

import numpy as np
import pymap3d
import pytest
from test_web import (  # noqa: F401
    CHROMIUM_ARGS,
    WebProc,
    browser,
    frame_payload,
    listening_peer,
    pixels_of,
    poll,
)

from zenoh_track.clients import connect
from zenoh_track.wire import Keys, free_port, pack

ORIGIN = [50.95, 1.85, 0.0]  # the Strait of Dover: coast within a few km
COAST_RGB = (0x7F, 0xA7, 0xD6)  # basemap.js COAST
COVERAGE_RGB = (0x2D, 0x4F, 0x6B)  # basemap.js COVERAGE
BASEMAP = resources.files("zenoh_track.clients.web") / "web_static" / "basemap"


def coast_vertex(near: tuple[float, float]) -> tuple[float, float]:
    """The vertex (lat, lon) of the 1:10m land outline nearest `near`, decoded from the
    shipped TopoJSON (quantized, delta-encoded arcs: TopoJSON specification 2.1.2)."""
    topo = json.loads((BASEMAP / "countries-10m.json").read_text())
    (sx, sy), (tx, ty) = topo["transform"]["scale"], topo["transform"]["translate"]
    used: set[int] = set()

    def collect(node) -> None:
        if isinstance(node, int):
            used.add(node if node >= 0 else ~node)
        else:
            for x in node:
                collect(x)

    for g in topo["objects"]["land"]["geometries"]:
        collect(g["arcs"])
    best, best_d = None, float("inf")
    for i in used:
        q = np.cumsum(np.array(topo["arcs"][i], dtype=float), axis=0)
        lon, lat = q[:, 0] * sx + tx, q[:, 1] * sy + ty
        d = np.hypot(lat - near[0], (lon - near[1]) * np.cos(np.radians(near[0])))
        k = int(np.argmin(d))
        if d[k] < best_d:
            best, best_d = (float(lat[k]), float(lon[k])), float(d[k])
    return best


def canvas_pixels(page, x: int, y: int, r: int) -> list[tuple[int, int, int]]:
    return [tuple(p) for p in page.evaluate("""([x, y, r]) => {
        const c = document.getElementById('map');
        const d = c.getContext('2d').getImageData(x - r, y - r, 2 * r + 1, 2 * r + 1).data;
        const out = [];
        for (let i = 0; i < d.length; i += 4) out.push([d[i], d[i + 1], d[i + 2]]);
        return out; }""", [x, y, r])]


class Publisher:
    """A peer on loopback publishing one frame every 0.1 s and a radar's measurement
    (its position and a 15 km range) every 0.5 s."""

    def __init__(self, endpoint: str, ids: list[str], pos: np.ndarray) -> None:
        self.session = listening_peer(endpoint)
        self.stopping = threading.Event()
        keys = Keys()

        def run() -> None:
            k = 0
            while not self.stopping.wait(0.1):
                self.session.put(keys.frame, frame_payload(k * 0.1, ids, pos,
                                                           bytes([1]) * len(ids)))
                if k % 5 == 0:
                    self.session.put(f"{keys.ns}/meas/radar1/x", pack(
                        {"t": k * 0.1, "r": 15_000.0, "az": 0.5, "el": 0.01,
                         "sensor_pos": [float(pos[0, 0]), float(pos[0, 1]), 0.0]}))
                k += 1

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.stopping.set()
        self.thread.join()
        self.session.close()


@pytest.mark.slow
def test_the_coast_is_drawn_where_it_belongs(browser):  # noqa: F811
    lat, lon = coast_vertex((50.87, 1.58))  # Cap Gris-Nez
    e, n, _ = pymap3d.geodetic2enu(lat, lon, 0.0, *ORIGIN)
    # a radar and a track sharing a place, labels to place around them
    pos = np.array([[e + 8000.0, n - 6000.0, 500.0], [e + 8000.0, n - 6000.0, 500.0]])
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    pub = Publisher(endpoint, ["swarm-00020", "swarm-00021"], pos)
    tiles = TileServer()
    web = WebProc(endpoint, "--origin", ",".join(map(str, ORIGIN)))
    try:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        requests: list[str] = []
        page.on("request", lambda r: requests.append(r.url))
        mpp, cx, cy = 40.0, e + 3000.0, n - 2000.0  # a 51 km view: the 1:10m level
        page.goto(f"{web.url}/#{cx},{cy},{mpp}")
        assert poll(lambda: page.evaluate("document.getElementById('track-count')"
                                          ".textContent") == "2")
        assert poll(lambda: pixels_of(page, COAST_RGB) > 200)
        px, py = round((e - cx) / mpp + 640), round(400 - (n - cy) / mpp)
        assert COAST_RGB in canvas_pixels(page, px, py, 1), (px, py)
        # a kilometre off (25 px) along the parallel: no coast there (the line runs N-S)
        assert COAST_RGB not in canvas_pixels(page, px + 25, py, 1)
        assert poll(lambda: pixels_of(page, COVERAGE_RGB) > 100)  # radar1 reaches 15 km
        assert any("/static/basemap/countries-10m.json" in u for u in requests)
        assert all(u.startswith(web.url) for u in requests), requests  # nothing else fetched
        assert not tiles.paths

        # the page's geodesy against pymap3d, 300 km around
        places = [(51.2, 1.3, 0.0), (48.85, 2.35, 35.0), (52.5, -1.0, 1000.0)]
        got = page.evaluate("""async ([origin, places]) => {
            const geo = await import('/static/geo.js');
            return places.map(([la, lo, h]) => geo.geodeticToEnu(origin, la, lo, h)); }""",
                            [ORIGIN, places])
        for (la, lo, h), enu in zip(places, got, strict=True):
            assert enu == pytest.approx(pymap3d.geodetic2enu(la, lo, h, *ORIGIN), abs=1e-3)

        # the map off (?basemap=off): no coast
        page.goto(f"{web.url}/?basemap=off#{cx},{cy},{mpp}")
        assert poll(lambda: page.evaluate("document.getElementById('track-count')"
                                          ".textContent") == "2")
        time.sleep(0.5)
        assert pixels_of(page, COAST_RGB) == 0
        page.close()
    finally:
        web.stop()
        pub.close()
        tiles.close()


def test_labels_never_overlap_and_the_rest_are_thinned(browser):  # noqa: F811
    """labels.js in the browser: 60 labels at nearly one place, a mark in the middle."""
    page = browser.new_page()
    page.set_content("<html></html>")
    web_static = resources.files("zenoh_track.clients.web") / "web_static"
    page.add_script_tag(content=(web_static / "labels.js").read_text()
                        .replace("export ", ""))
    boxes = page.evaluate("""() => {
        const p = new Placer(800, 600);
        p.reserve([394, 294, 406, 306]);
        const out = [];
        for (let i = 0; i < 60; i++) out.push(p.place(400 + (i % 5), 300 + (i % 3), 70, 13));
        return out; }""")
    placed = [b for b in boxes if b is not None]
    assert 1 <= len(placed) <= 4 < len(boxes)  # the four corners, then thinned
    for i, a in enumerate(placed):
        assert not (a[0] < 406 and 394 < a[2] and a[1] < 306 and 294 < a[3])  # the mark
        for b in placed[i + 1:]:
            assert not (a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]), (a, b)
    page.close()


class TileServer:
    """An operator's tile server on loopback: a grey 256 px PNG for every z/x/y."""

    PNG = bytes.fromhex(
        "89504e470d0a1a0a0000000d4948445200000001000000010806000000"
        "1f15c4890000000d49444154789c63f8cfc0f01f0005000201ff6d3f5a0c0000000049454e44ae426082")

    def __init__(self) -> None:
        self.paths: list[str] = []
        outer = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802
                outer.paths.append(self.path)
                self.send_response(200)
                self.send_header("Content-Type", "image/png")
                self.send_header("Access-Control-Allow-Origin", "*")
                self.end_headers()
                self.wfile.write(outer.PNG)

            def log_message(self, *args) -> None:
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


@pytest.mark.slow
def test_an_operators_tile_server_is_used_when_given(browser):  # noqa: F811
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    pub = Publisher(endpoint, ["a"], np.array([[0.0, 0.0, 100.0]]))
    tiles = TileServer()
    web = WebProc(endpoint, "--origin", ",".join(map(str, ORIGIN)), "--tiles",
                  tiles.url + "/{z}/{x}/{y}.png")
    try:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(f"{web.url}/#0,0,100")
        # 100 m/px at 51 deg N: zoom 10 (153 m/px at the equator, 96 here); the tile of the
        # view's centre, the origin, is among those asked for
        x, y = 2 ** 10 * (ORIGIN[1] + 180) / 360, 2 ** 10 * (
            1 - np.arcsinh(np.tan(np.radians(ORIGIN[0]))) / np.pi) / 2
        assert poll(lambda: f"/10/{int(x)}/{int(y)}.png" in tiles.paths), tiles.paths
        assert {int(p.split("/")[1]) for p in tiles.paths} == {10}
        page.close()
    finally:
        web.stop()
        pub.close()
        tiles.close()


@pytest.mark.slow
def test_the_covariance_table_is_whole_at_1400_px(service_factory, browser):  # noqa: F811
    svc, _ = service_factory("--clock", "lockstep")
    web = WebProc(svc.endpoint, "--origin", ",".join(map(str, ORIGIN)))
    try:
        with connect(svc.endpoint) as client:
            feed = client.feed("radar1")
            for k in range(8):
                feed.measure("plane-1", t=float(k), pos=[200.0 * k, 100.0 * k, 3000.0],
                             sigma=20.0)
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        page.goto(web.url + "/")
        assert poll(lambda: page.evaluate("document.getElementById('track-count')"
                                          ".textContent") == "1")
        page.keyboard.press("l")  # ids of every track
        box = page.locator("#map").bounding_box()
        # select the one track: the view fits it, so it is at the centre
        page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        if not poll(lambda: page.locator("#detail-matrix").count() > 0, timeout=10):
            pytest.fail("no covariance table shown")
        # measured in one step: the panel's content is drawn again every 250 ms
        got = page.evaluate("""() => {
            const t = document.getElementById('detail-matrix');
            const panel = document.getElementById('details').getBoundingClientRect();
            const heads = t.rows[0].cells, last = heads[heads.length - 1];
            return { last: last.textContent, right: last.getBoundingClientRect().right,
                     panel: panel.right, scroll: t.parentElement.scrollWidth,
                     shown: t.parentElement.clientWidth,
                     heights: [...t.rows].map((r) => r.getBoundingClientRect().height) };
        }""")
        assert got["last"] in ("az", "vz", "z"), got
        assert got["right"] <= got["panel"] and got["scroll"] <= got["shown"], got  # not cut
        assert max(got["heights"]) - min(got["heights"]) < 2, got  # no row wraps
        page.close()
    finally:
        web.stop()
