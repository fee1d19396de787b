"""`track-web`: the live picture in a web browser.

Serves one page (package data, nothing fetched at run time) on http://127.0.0.1:8080/:
every track of `<ns>/frame` drawn on a pannable, zoomable map with its trail, velocity
vector, uncertainty circle (1 sigma), status colour and id; the sensors, the
interceptors, a scale bar, the simulation clock, the track count and the service's health
(liveliness tokens, rejected inputs per second from `status`). A click on a track shows
its `tracks/<id>` state (get through this server): state, covariance, model
probabilities, age.

Frames reach each browser over a WebSocket as binary typed arrays (`frames`): one
frame at a time, the next only once the browser has taken the previous one (it answers
each with "ack"); frames that arrive meanwhile are skipped, never queued, so a slow
browser sees the newest picture late rather than an old one.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from importlib import resources
from typing import Any

import zenoh

from zenoh_track.wire import (
    CHUNK,
    Keys,
    Stop,
    add_zenoh_args,
    fail,
    on_signals,
    open_session,
)

try:
    from aiohttp import WSMsgType, web
except ImportError as exc:
    from zenoh_track.wire import missing_extra

    missing_extra(exc, "web", "track-web")

from zenoh_track.clients.lib import Frame as Columns
from zenoh_track.clients.lib.origin import deployment_origin, parse_origin
from zenoh_track.clients.web.frames import FrameHub
from zenoh_track.clients.web.link import Link

WINDOW = 2  # frames in flight to one browser (unanswered)
HEALTH_PERIOD = 1.0  # s between health messages
TRAIL = 30.0  # s of history drawn behind each track
STATIC = resources.files("zenoh_track.clients.web") / "web_static"


def tile_url(text: str) -> str:
    """An XYZ tile URL template: http(s), with {z}, {x} and {y}."""
    if not text.startswith(("http://", "https://")) or not all(
            f"{{{k}}}" in text for k in "zxy"):
        raise argparse.ArgumentTypeError(
            f"expected an http(s) URL with {{z}}, {{x}} and {{y}}, got {text!r}")
    return text


class Browser:
    """One connected page: what it holds and how many frames it has not answered."""

    def __init__(self, ws: web.WebSocketResponse) -> None:
        self.ws = ws
        self.credits = WINDOW
        self.sent_seq = 0  # the hub's seq of the last frame sent
        self.ids_seq = -1  # the id list it holds
        self.dropped = 0
        self.wake = asyncio.Event()


class WebServer:
    """The aiohttp application of one namespace."""

    def __init__(self, session: zenoh.Session, keys: Keys, origin: list[float] | None,
                 trail: float, tiles: str | None = None) -> None:
        self.keys, self.origin, self.trail, self.tiles = keys, origin, trail, tiles
        self.hub = FrameHub()
        self.browsers: set[Browser] = set()
        self.loop = asyncio.get_running_loop()
        self.link = Link(session, keys, self._frame_from_zenoh)
        self.app = web.Application()
        self.app.add_routes([
            web.get("/", self.index),
            web.get("/ws", self.websocket),
            web.get("/api/health", self.api_health),
            web.get("/api/tracks/{id}", self.api_track),
            web.static("/static", str(STATIC)),
        ])
        self.app.on_shutdown.append(self._close_browsers)
        self.health_task = self.loop.create_task(self._health())

    def _frame_from_zenoh(self, frame: Columns) -> None:
        try:
            self.loop.call_soon_threadsafe(self._frame, frame)
        except RuntimeError:  # the loop has closed: shutting down
            pass

    def _frame(self, frame: Columns) -> None:
        self.hub.put(frame)
        for b in self.browsers:
            b.wake.set()

    # ------------------------------------------------------------ pages
    async def index(self, request: web.Request) -> web.Response:
        return web.Response(text=(STATIC / "index.html").read_text(), content_type="text/html")

    async def api_health(self, request: web.Request) -> web.Response:
        return web.json_response(self._health_message())

    async def api_track(self, request: web.Request) -> web.Response:
        """The `tracks/<id>` state of a track, with its age and status at the latest
        frame."""
        track_id = request.match_info["id"]
        if not CHUNK.fullmatch(track_id):
            return web.json_response({"error": f"bad track id {track_id!r}"}, status=400)
        state = await asyncio.to_thread(self.link.track, track_id)
        if state is None:
            return web.json_response({"error": f"no track {track_id!r}"}, status=404)
        frame = self.hub.latest()
        row = frame.row(track_id) if frame is not None else None
        if frame is not None and isinstance(state.get("t"), float):
            state["age"] = max(frame.t - state["t"], 0.0)
            state["frame_t"] = frame.t
        if row is not None:
            state["status_code"] = int(frame.status[row])
        return web.json_response(state)

    def _health_message(self) -> dict[str, Any]:
        return self.link.health() | {"frames_received": self.hub.seq,
                                     "frames_bad": self.hub.bad}

    # ------------------------------------------------------------ the stream
    async def websocket(self, request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(heartbeat=30.0, compress=False)  # frames: 0.3 MB each
        await ws.prepare(request)
        browser = Browser(ws)
        self.browsers.add(browser)
        await ws.send_str(json.dumps({"type": "config", "ns": self.keys.ns,
                                      "origin": self.origin, "trail": self.trail,
                                      "tiles": self.tiles}))
        await ws.send_str(json.dumps(self._health_message()))
        sender = asyncio.create_task(self._send_frames(browser))
        browser.wake.set()
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT and msg.data == "ack":
                    browser.credits = min(browser.credits + 1, WINDOW)
                    browser.wake.set()
        finally:
            self.browsers.discard(browser)
            sender.cancel()
        return ws

    async def _send_frames(self, b: Browser) -> None:
        """Send the newest frame whenever there is one the browser has not seen and it
        has answered enough of the earlier ones; whatever came in between is skipped."""
        while not b.ws.closed:
            await b.wake.wait()
            b.wake.clear()
            if b.credits <= 0 or self.hub.seq == b.sent_seq:
                continue
            frame = self.hub.latest()
            if frame is None:
                continue
            if b.sent_seq:
                b.dropped += frame.seq - b.sent_seq - 1
            extra = self.link.extra()
            data = frame.message(b.ids_seq, b.dropped,
                                 json.dumps({"interceptors": extra}).encode() if extra else b"")
            b.sent_seq, b.ids_seq, b.credits = frame.seq, frame.ids_seq, b.credits - 1
            try:
                await b.ws.send_bytes(data)
            except ConnectionError:
                return

    async def _health(self) -> None:
        while True:
            await asyncio.sleep(HEALTH_PERIOD)
            text = json.dumps(self._health_message())
            for b in list(self.browsers):
                if not b.ws.closed:
                    try:
                        await b.ws.send_str(text)
                    except ConnectionError:
                        pass

    async def _close_browsers(self, app: web.Application) -> None:
        for b in list(self.browsers):
            await b.ws.close()

    def close(self) -> None:
        self.health_task.cancel()
        self.link.close()


async def serve(args: argparse.Namespace, stop: Stop) -> None:
    session = open_session(args, log=True)
    try:
        origin = deployment_origin(session, args.ns, args.origin, "track-web")
        server = WebServer(session, Keys(args.ns), list(origin) if origin else None, args.trail,
                           args.tiles)
    except BaseException:
        session.close()
        raise
    runner = web.AppRunner(server.app, access_log=None)
    await runner.setup()
    try:
        # on SIGTERM wait at most 2 s for open connections (aiohttp's default: 60 s)
        await web.TCPSite(runner, args.host, args.port, shutdown_timeout=2.0).start()
        host = f"[{args.host}]" if ":" in args.host else args.host
        print(f"track-web: http://{host}:{args.port}/ (ns {args.ns})", file=sys.stderr,
              flush=True)
        await asyncio.get_running_loop().run_in_executor(None, stop.wait)
    finally:
        await runner.cleanup()
        server.close()
        session.close()


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-web", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_zenoh_args(p)
    p.add_argument("--host", default="127.0.0.1",
                   help="address to serve on (default %(default)s: this machine only)")
    p.add_argument("--port", type=int, default=8080, help="HTTP port (default %(default)s)")
    p.add_argument("--origin", type=parse_origin, metavar="LAT,LON,ALT",
                   help="geodetic origin of the ENU frame: positions also in lat/lon "
                        "(default: the service's, track-service --origin; one that differs "
                        "is refused)")
    p.add_argument("--tiles", type=tile_url, metavar="URL",
                   help="an operator's own map tile server under the basemap, e.g. "
                        "'https://tiles.example/{z}/{x}/{y}.png' (XYZ, Web Mercator); never "
                        "fetched unless given")
    p.add_argument("--trail", type=float, default=TRAIL,
                   help="seconds of history behind each track (default %(default)s)")
    return p


def main(argv: list[str] | None = None) -> None:
    args = parser().parse_args(argv)
    stop = on_signals()
    try:
        asyncio.run(serve(args, stop))
    except OSError as exc:
        fail(f"cannot serve on {args.host}:{args.port}: {exc.strerror or exc} (another "
             "program on that port? choose another with --port)", "track-web")


if __name__ == "__main__":
    main()
