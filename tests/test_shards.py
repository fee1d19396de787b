"""One picture from several trackers, through real processes on loopback: a router,
N realtime `track-service` instances splitting the labelled targets by the last digit of
their id (deploy/README.md), a realtime swarm feed; then for 30 s every viewer shows the
exact union of the instances' tracks at every picture it draws: the client library's
`Picture`, `track-display --once` run again and again, `track-web` (every frame sent to
a websocket client, and the count the page draws in chromium); a late joiner's first
picture holds them all. Then one instance is killed: its tracks leave every viewer
within the documented time, the others' stay."""

from __future__ import annotations

import asyncio
import os
import re
import signal
import subprocess
import sys
import threading
import time

import pytest
from test_compose import ROOT, ROUTER
from test_web import WebProc, page_text, poll
from test_web import browser as browser  # the fixture

from zenoh_track.clients import ServiceProcess, connect
from zenoh_track.clients.lib.frames import Frame
from zenoh_track.clients.lib.merge import STALE
from zenoh_track.clients.lib.process import stop
from zenoh_track.clients.web.frames import read_message
from zenoh_track.wire import free_port

pytestmark = pytest.mark.slow
TARGETS = 40
WINDOW = 30.0  # s of every viewer watched
ONCE_EVERY = 1.0  # s between two runs of `track-display --once`
GONE_WITHIN = STALE + 1.0  # s: a killed instance's tracks leave every viewer (documented)


def digits(k: int, n: int) -> list[int]:
    """The last digits instance k of n tracks."""
    return [d for d in range(10) if d % n == k]


class Deployment:
    """Router, `n` realtime shards (`shard-<k>`), a realtime swarm feed of TARGETS."""

    def __init__(self, n: int) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.ns = f"shards{n}{free_port()}"
        self.router = subprocess.Popen(
            [sys.executable, "-c", ROUTER, str(ROOT / "deploy" / "router.json5"),
             self.endpoint], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.router.stdout.readline().strip() == "ready"
        self.shards = []
        self.owner = {}
        for k in range(n):
            exprs = [a for d in digits(k, n) for a in ("--meas", f"{self.ns}/meas/*/$*{d}")]
            self.shards.append(ServiceProcess("--instance", f"shard-{k}", *exprs, ns=self.ns,
                                              connect=self.endpoint, clock="realtime"))
        self.ids = {f"swarm-{i:05d}" for i in range(TARGETS)}
        for tid in self.ids:
            self.owner[tid] = f"shard-{int(tid[-1]) % n}"
        for svc in self.shards:
            svc.wait(timeout=120)
        self.feed = subprocess.Popen(
            [sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm", "--targets",
             str(TARGETS), "--duration", "600", "--realtime", "--trackers", str(n),
             "-e", self.endpoint, "--mode", "client", "--ns", self.ns],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    def of(self, shard: str) -> set[str]:
        return {t for t, s in self.owner.items() if s == shard}

    def viewer_args(self) -> list[str]:
        return ["-e", self.endpoint, "--mode", "client", "--ns", self.ns]

    def close(self) -> None:
        stop(self.feed, timeout=10)
        for svc in self.shards:
            svc.stop()
        stop(self.router)


def display_once(dep: Deployment) -> tuple[set[str], int, str]:
    """`track-display --once`: the ids of its rows, its track count, its health line."""
    out = subprocess.run([sys.executable, "-m", "zenoh_track.clients.display.display",
                          "--once", "--rows", "100", *dep.viewer_args()],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    count = int(re.search(r"tracks=(\d+)", out.stdout).group(1))
    ids = {ln.split()[0] for ln in lines if ln.strip().startswith("swarm-")}
    return ids, count, lines[1]


class WebWatch:
    """A websocket client of track-web: the ids of every frame it is sent."""

    def __init__(self, url: str) -> None:
        self.url, self.frames, self.stop = url, [], threading.Event()
        self.thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self.thread.start()

    async def _run(self) -> None:
        import aiohttp

        ids: list[str] = []
        async with aiohttp.ClientSession() as http, http.ws_connect(f"{self.url}/ws") as ws:
            while not self.stop.is_set():
                try:
                    msg = await ws.receive(timeout=1.0)
                except TimeoutError:
                    continue
                if msg.type != aiohttp.WSMsgType.BINARY:
                    continue
                await ws.send_str("ack")
                m = read_message(msg.data)
                ids = m["ids"] if m["ids"] is not None else ids
                self.frames.append((time.monotonic(), m["t"], frozenset(ids[:m["n"]]), m["n"]))


# the count of tracks the page shows, read at every new frame it draws (its clock moves)
OBSERVE = """() => { window.counts = []; new MutationObserver(() => window.counts.push(
  document.getElementById('track-count').textContent)).observe(
  document.getElementById('clock'), {childList: true, characterData: true,
  subtree: true}); }"""


@pytest.mark.parametrize("n", [2, 4])
def test_every_viewer_shows_the_union_of_the_instances_then_loses_a_killed_one(n, browser):
    dep = Deployment(n)
    web = None
    client = connect(dep.endpoint, mode="client", ns=dep.ns)
    try:
        drawn: list[tuple[float, Frame]] = []
        pic = client.picture(on_frame=lambda f: drawn.append((time.monotonic(), f)))
        whole = pic.wait_for(lambda f: set(f.id_list) == dep.ids, timeout=90)
        assert sorted(whole.instances) == [f"shard-{k}" for k in range(n)]
        web = WebProc(dep.endpoint, "--mode", "client", "--ns", dep.ns)
        page = browser.new_page(viewport={"width": 1000, "height": 700})
        page.goto(web.url + "/")
        assert poll(lambda: page_text(page, "track-count") == str(TARGETS), timeout=30)
        page.evaluate(OBSERVE)
        watch = WebWatch(web.url)
        assert poll(lambda: watch.frames, timeout=30)

        start = time.monotonic()
        runs = []
        while time.monotonic() - start < WINDOW:
            runs.append(display_once(dep))
            # a user's pace, not back to back: a new Python process each run would
            # otherwise keep a core busy and starve the realtime instances under test
            time.sleep(ONCE_EVERY)
        end = time.monotonic()
        watch.stop.set()
        counts = page.evaluate("window.counts")
        health = page_text(page, "health")

        library = [f for w, f in drawn if start <= w <= end]
        assert len(library) > 0.5 * 30 * WINDOW, len(library)  # 30 Hz, a loaded machine misses some
        bad = [(f.t, len(f), f.instances) for f in library if set(f.id_list) != dep.ids
               or len(f) != TARGETS]
        # an instance missing from pictures: how many, and what its service logged
        missing = sorted({f"shard-{k}" for k in range(n)} - {i for *_, f in bad for i in f})
        held = {name: (q[-1][0].t, round(time.monotonic() - q[-1][1], 2))
                for name, q in pic.merge.held.items() if q}  # each one's newest t, its age
        # one line first (a long message is cut): what the merge held and whose tokens were up
        assert not bad, (f"{len(bad)} of {len(library)} pictures lack {missing}, t="
                         f"{bad[0][0] if bad else 0:.2f} to {bad[-1][0] if bad else 0:.2f}; "
                         f"newest frame held and its age: {held}; alive: {sorted(pic.alive)}; "
                         f"gone: {sorted(pic.merge.gone_names)}\n"
                         + "\n".join(f"{m}: {dep.shards[int(m[6:])].log()[-1500:]}"
                                     for m in missing))
        ts = [f.t for f in library]
        assert all(b > a for a, b in zip(ts, ts[1:], strict=False)), "pictures out of order"
        for ids, count, line in runs:
            assert ids == dep.ids and count == TARGETS, (count, sorted(dep.ids ^ ids))
            assert f"{n} of {n} instances serve the picture" in line, line
        sent = [f for f in watch.frames if start <= f[0] <= end]
        assert len(sent) > 10 * WINDOW, len(sent)
        assert all(ids == dep.ids and k == TARGETS for _, _, ids, k in sent)
        assert len(counts) > 10 * WINDOW and set(counts) == {str(TARGETS)}, set(counts)
        assert f"{n} of {n} instances serve the picture" in health, health
        print(f"\n{n} instances, {WINDOW:g} s: {len(library)} pictures of the library, "
              f"{len(runs)} track-display --once, {len(sent)} track-web frames, "
              f"{len(counts)} counts drawn in chromium: all {TARGETS} tracks, every one")

        # a late joiner's first picture (every instance's reply to its query, drawn before
        # its subscription) holds every instance's tracks
        joined: list[Frame] = []
        late = client.picture(on_frame=joined.append)
        absent = sorted({f"shard-{k}" for k in range(n)} - set(joined[0].instances))
        assert not absent, (absent, late.received, {m: dep.shards[int(m[6:])].log()[-1500:]
                                                    for m in absent})
        assert set(joined[0].id_list) == dep.ids and len(joined[0]) == TARGETS
        late.close()

        # one instance killed: its tracks leave every viewer, the others' stay
        victim = dep.shards[1]
        keep = dep.ids - dep.of("shard-1")
        watch = WebWatch(web.url)
        killed = time.monotonic()
        victim.proc.kill()
        left = pic.wait_for(lambda f: set(f.id_list) == keep, timeout=30)
        gone_after = time.monotonic() - killed
        assert gone_after < GONE_WITHIN, gone_after
        assert "shard-1" not in left.instances
        assert poll(lambda: page_text(page, "track-count") == str(len(keep)),
                    timeout=GONE_WITHIN)
        web_after = time.monotonic() - killed
        time.sleep(1.0)  # the others' stay
        assert set(pic.latest().id_list) == keep
        ids, count, line = display_once(dep)
        assert ids == keep and count == len(keep), sorted(ids ^ keep)
        assert (f"{n - 1} of {n - 1} instances serve the picture" if n > 2 else
                "tracker shard-0 alive") in line, line
        watch.stop.set()
        assert set(watch.frames[-1][2]) == keep
        print(f"shard-1 killed: its tracks left the library's picture after "
              f"{gone_after:.2f} s, the page after {web_after:.2f} s")
    finally:
        if web is not None:
            web.stop()
        client.close()
        dep.close()


def test_a_frozen_instance_leaves_after_stale_seconds_and_comes_back():
    """SIGSTOP: its connection stays open and its token up, its frames stop; its tracks
    leave the picture after STALE s, its token at the end of Zenoh's lease; SIGCONT: its
    tracks are back with its next frames."""
    dep = Deployment(2)
    client = connect(dep.endpoint, mode="client", ns=dep.ns)
    try:
        pic = client.picture()
        pic.wait_for(lambda f: set(f.id_list) == dep.ids, timeout=90)
        keep = dep.ids - dep.of("shard-1")
        victim = dep.shards[1].proc
        frozen = time.monotonic()
        os.kill(victim.pid, signal.SIGSTOP)
        pic.wait_for(lambda f: set(f.id_list) == keep, timeout=30)
        left = time.monotonic() - frozen
        assert STALE - 0.1 < left < GONE_WITHIN, left
        pic.wait_for(lambda f: "shard-1" not in pic.alive, timeout=30)
        token = time.monotonic() - frozen
        assert set(pic.latest().id_list) == keep
        os.kill(victim.pid, signal.SIGCONT)
        thawed = time.monotonic()
        pic.wait_for(lambda f: set(f.id_list) == dep.ids, timeout=30)
        back = time.monotonic() - thawed
        print(f"\nshard-1 stopped: its tracks left after {left:.2f} s, its token after "
              f"{token:.2f} s; continued: back after {back:.2f} s")
    finally:
        client.close()
        dep.close()
