"""Security, role by key, through the real secured routers (deploy/secure/, both variants):
what each role may do works, what it may not reaches no one and changes nothing.

One deployment per variant (tests/secure_kit.py): `track-router` on the shipped router
file, a lockstep `track-service` with the tracker's file, and a session per role with
that role's shipped client file. The feed's legitimate inputs make three tracks; every
forbidden put, queryable, token, subscription and query is tried beside them; a watcher
(a viewer subscribed to `track/**`, as track-record is) and the service's own counters
show what got through. The shipped programs (track-display live, track-record) run as
processes against the same deployment."""

from __future__ import annotations

import subprocess
import threading

import pytest
import secure_kit
import test_web
import zenoh
from routers import ENV, Stamped
from secure_kit import KEYS, program

from zenoh_track.clients.lib.process import stop
from zenoh_track.clients.record.files import Recording
from zenoh_track.wire import pack, unpack

pytestmark = pytest.mark.slow
pki, deployment = secure_kit.pki, secure_kit.deployment  # the fixtures
browser = test_web.browser  # a headless chromium (skips without one)
WAIT = 60.0  # s: generous, for a loaded machine; every wait ends on its condition
ROGUES = ("viewer", "interceptor", "feed", "tracker")
TARGETS = ("ok-1", "ok-2", "ok-3")


def meas(t: float, x: float) -> bytes:
    return pack({"t": t, "pos": [x, 2000.0]})


def forbidden_puts(s: zenoh.Session, role: str) -> None:
    """Everything a role may not put or delete (for the feed: the outputs; for the
    tracker identity: the inputs; for the others: both, and other keys)."""
    tag = f"{role[:4]}-fake"
    outputs = [KEYS.display(tag), KEYS.tracks(tag), KEYS.errors(tag), KEYS.frame,
               KEYS.states]
    inputs = [KEYS.meas("radar1", tag), KEYS.clock, KEYS.plots("radar1"),
              KEYS.scan("radar1"), KEYS.truth(tag)]
    keys = {"feed": outputs + [KEYS.display(f"interceptor-{tag}")],
            "tracker": inputs,
            "interceptor": outputs[1:] + inputs + [KEYS.display(tag)],
            "viewer": outputs + inputs + [KEYS.display(f"interceptor-{tag}")]}[role]
    for k in dict.fromkeys(keys):
        body = meas(1.5, 9999.0) if "/meas/" in k else pack({"t": 500.0, "id": tag,
                                                             "forged": True})
        s.put(k, body)
    if role != "tracker":  # the tracker identity may delete its outputs
        s.delete(KEYS.tracks("ok-1"))
        s.delete(KEYS.display("ok-1"))


def replies(s: zenoh.Session, key: str, timeout: float = 5.0) -> list[dict]:
    got = s.get(key, target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout)
    return [unpack(r.ok.payload.to_bytes()) for r in got if r.ok is not None]


def test_each_role_does_its_part_and_nothing_else(deployment):
    d = deployment
    s = {r: d.session(r) for r in ("feed", "viewer", "interceptor", "tracker")}
    watcher = d.session("viewer")  # what everyone else sees
    seen_all = Stamped(watcher, "track/**")
    tokens: list[str] = []
    watcher.liveliness().declare_subscriber(
        "track/alive/**", lambda x: tokens.append(str(x.key_expr)), history=True)

    # subscriptions: (role, key) -> expected to receive
    subs = {("viewer", k): True for k in (KEYS.frame, "track/display/**", "track/tracks/**",
                                          "track/errors/**", KEYS.states, "track/meas/**",
                                          "track/truth/**", KEYS.clock)}
    subs |= {("interceptor", k): True for k in ("track/display/**", "track/truth/**",
                                                KEYS.clock)}
    subs |= {("interceptor", k): False for k in (KEYS.frame, "track/tracks/**",
                                                 "track/meas/**", "track/errors/**")}
    subs |= {("feed", k): False for k in (KEYS.frame, "track/display/**", "track/tracks/**",
                                          "track/errors/**", "track/truth/**")}
    subs |= {("tracker", "track/meas/**"): True, ("tracker", KEYS.frame): False,
             ("tracker", "track/truth/**"): False}
    # (on sessions of their own: a session delivers its own puts to its own subscribers)
    listen = {r: d.session(r) for r in ("feed", "viewer", "interceptor", "tracker")}
    got = {rk: Stamped(listen[rk[0]], rk[1]) for rk in subs}

    # forbidden queryables and liveliness tokens; the interceptor's own token is allowed
    # (on sessions of their own: a session's own queryable answers its own queries)
    other = {r: d.session(r) for r in ("viewer", "feed", "interceptor")}
    spoofs = [other[r].declare_queryable(k, lambda q, r=r: q.reply(
        q.key_expr, pack({"instance": f"spoof-{r}", "id": f"{r[:4]}-fake", "t": 0.0})))
        for r in ("viewer", "feed", "interceptor") for k in (KEYS.status, "track/tracks/**",
                                                             KEYS.frame)]
    held = [other[r].liveliness().declare_token(f"track/alive/tracker/{r}-fake")
            for r in ("viewer", "feed", "interceptor")]
    held.append(s["interceptor"].liveliness().declare_token("track/alive/intercept/i-ok"))

    for r in ROGUES:
        forbidden_puts(s[r], r)
    # the feed's legitimate inputs: two scans of three targets, one bad input, the truth
    for i, t in enumerate((1.0, 2.0)):
        for j, tid in enumerate(TARGETS):
            s["feed"].put(KEYS.meas("radar1", tid), meas(t, 1000.0 * j + 10.0 * i))
    s["feed"].put(KEYS.meas("radar1", "bad-1"), pack({"t": 2.5}))  # no pos: rejected
    s["feed"].put(KEYS.truth("ok-1"), pack({"t": 2.0, "pos": [0.0, 2000.0],
                                            "vel": [10.0, 0.0]}))
    s["feed"].put(KEYS.clock, pack({"t": 3.0}))
    # the interceptor's own display state, after the display keys have subscribers
    s["interceptor"].put(KEYS.display("interceptor-ok-1"), pack(
        {"t": 2.0, "id": "interceptor-ok-1", "pos": [0.0, 0.0, 0.0], "vel": [0.0, 0.0, 0.0],
         "sigma": 0.0, "status": "confirmed", "age": 0.0}))
    for r in ROGUES:  # again, now that tracks exist
        forbidden_puts(s[r], r)
    # a marker from the feed after all that: once it is tracked, the rest would be too
    s["feed"].put(KEYS.meas("radar1", "marker-1"), meas(4.0, 5.0))
    s["feed"].put(KEYS.clock, pack({"t": 5.0}))

    def ids(samples, what: str) -> set[str]:
        out = set()
        for _, k, kind, b in samples:
            if kind == "PUT" and k == KEYS.frame and "ids" in b:
                out |= set(b["ids"])
            elif kind == "PUT" and k.startswith(f"track/{what}/"):
                out.add(k.rsplit("/", 1)[1])
        return out

    assert seen_all.wait_for(lambda x: "marker-1" in ids(x, "tracks"), WAIT), \
        f"the feed's marker was not tracked: {sorted(ids(seen_all.snapshot(), 'tracks'))}"
    problems = []
    if not seen_all.wait_for(lambda x: any(k == KEYS.frame and b.get("t", 0) >= 4.9
                                           for _, k, kind, b in x if kind == "PUT"), WAIT):
        problems.append("a track/** subscriber (as track-record) got no frame up to t=5")
    if not got[("viewer", KEYS.frame)].wait_for(
            lambda x: {*TARGETS, "marker-1"} <= ids(x, "frame"), WAIT):
        problems.append("a viewer's frame subscription did not get the tracks")
    everything = seen_all.snapshot()
    for _, k, kind, b in everything:  # nothing forged reached the watcher
        if "fake" in k or (kind == "PUT" and isinstance(b, dict) and b.get("forged")):
            problems.append(f"the watcher got {kind} {k}")
        if kind == "DELETE" and k.endswith("/ok-1"):
            problems.append(f"the watcher got a forged DELETE {k}")
    shown = [b["t"] for _, k, kind, b in everything if k == KEYS.frame and kind == "PUT"]
    if shown and max(shown) >= 100:  # a forged clock (t=500) moved the service's time
        problems.append(f"a forged clock moved the picture to t={max(shown)}")
    if "track/alive/intercept/i-ok" not in tokens:
        problems.append("the interceptor's token was not seen")
    problems += [f"a forged token was seen: {t}" for t in tokens if "fake" in t]

    # what each subscription received, beside what it should
    for (role, key), ok in subs.items():
        n = len(got[(role, key)].snapshot())
        if ok != (n > 0):
            problems.append(f"{role} subscribed to {key}: {n} samples (expected "
                            f"{'some' if ok else 'none'})")

    # queries: (role, key) -> expected to be answered, all asked at once
    asks = {("viewer", k): True for k in (KEYS.frame, "track/tracks/**", "track/display/**",
                                          KEYS.status)}
    asks |= {("feed", KEYS.status): True}
    asks |= {(r, k): False for r in ("feed", "interceptor", "tracker")
             for k in (KEYS.frame, "track/tracks/**", "track/display/**")}
    asks |= {("interceptor", KEYS.status): False, ("tracker", KEYS.status): False}
    answers: dict = {}
    threads = [threading.Thread(target=lambda rk=rk: answers.__setitem__(
        rk, replies(s[rk[0]], rk[1]))) for rk in asks]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for (role, key), ok in asks.items():
        n = len(answers[(role, key)])
        if ok != (n > 0):
            problems.append(f"{role} asked {key}: {n} replies (expected "
                            f"{'some' if ok else 'none'})")
        spoofed = [a for a in answers[(role, key)] if "spoof" in str(a.get("instance"))
                   or "fake" in str(a.get("id"))]
        if spoofed:
            problems.append(f"{role} asked {key}: a forged answer {spoofed}")
    status = replies(watcher, KEYS.status)
    if [x["instance"] for x in status] != ["secure"]:
        problems.append(f"status answered by {[x.get('instance') for x in status]}")
    else:  # exactly the feed's inputs reached the service: 7 measurements, 1 bad input
        st = status[0]
        if (st["meas_accepted"], st["meas_rejected"]) != (7, 1):
            problems.append(f"the service counted {st['meas_accepted']} accepted, "
                            f"{st['meas_rejected']} rejected inputs (expected 7, 1)")
    held_tracks = {x["id"] for x in replies(watcher, "track/tracks/**")}
    if held_tracks != {*TARGETS, "marker-1"}:
        problems.append(f"the service holds {sorted(held_tracks)}")
    for q in spoofs:
        q.undeclare()
    for tok in held:
        tok.undeclare()
    assert not problems, "\n".join(problems)


def test_shipped_viewers_show_and_record_the_tracks(deployment, tmp_path):
    """track-display (live, plain text as when piped; then --once) shows the feed's
    tracks, and track-record records the frames, each with the viewer's shipped file."""
    d = deployment
    viewer = str(d.config("viewer"))
    out = tmp_path / "secure.mcap"
    display = subprocess.Popen(program("track-display", "-c", viewer, "-e", d.endpoint),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=ENV)
    record = subprocess.Popen(program("track-record", "-o", str(out), "-c", viewer, "-e",
                                      d.endpoint), stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True, env=ENV)
    feed = d.session("feed")
    lines: list[str] = []
    ready = threading.Event()

    def read() -> None:
        for line in display.stdout:
            lines.append(line)
            if "shown-3" in line:
                ready.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        rec_up = threading.Event()
        threading.Thread(target=lambda: (record.stderr.readline(), rec_up.set()),
                         daemon=True).start()
        assert rec_up.wait(WAIT), "track-record did not start"
        t = 20.0  # after the other test's times: lockstep time only goes forward
        while not ready.is_set() and t < 60.0:
            for j in range(1, 4):
                feed.put(KEYS.meas("radar1", f"shown-{j}"), meas(t, 500.0 * j))
            feed.put(KEYS.clock, pack({"t": t + 0.5}))
            ready.wait(1.0)  # the condition, polled while the lockstep picture advances
            t += 1.0
        assert ready.is_set(), "".join(lines[-40:]) + stop(display)[-2000:]
        # --once, started now with the picture paused: the table from its queries
        once = subprocess.run(program("track-display", "--once", "-c", viewer, "-e",
                                      d.endpoint), capture_output=True, text=True,
                              timeout=WAIT, env=ENV, stdin=subprocess.DEVNULL)
        assert once.returncode == 0 and "shown-3" in once.stdout, once.stdout + once.stderr
    finally:
        err_d = stop(display)
        err_r = stop(record)
    assert "Traceback" not in err_d + err_r, err_d + err_r
    with open(out, "rb") as f:
        rec = Recording(f)
        frame_ids = {cid for cid, ch in rec.channels.items() if ch.key == KEYS.frame}
        shown = set()
        for _, sample in rec.samples(frame_ids):
            shown |= set(unpack(sample.payload).get("ids", []))
    assert {"shown-1", "shown-2", "shown-3"} <= shown, sorted(shown)



def test_track_web_shows_the_tracks_in_a_browser(deployment, browser):
    """track-web with the viewer's shipped file: the page in a real browser counts the
    tracks of the latest frame, the feed's new ones among them, and shows the tracker."""
    d = deployment
    frames: list[dict] = []
    watcher = d.session("viewer")
    watcher.declare_subscriber(KEYS.frame, lambda x: frames.append(unpack(
        x.payload.to_bytes())))
    web = test_web.WebProc(d.endpoint, "-c", str(d.config("viewer")))
    feed = d.session("feed")
    names = {"web-1", "web-2", "web-3"}
    try:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(web.url + "/")
        t = 100.0  # after the other tests' times: lockstep time only goes forward

        def shown() -> bool:
            nonlocal t
            if frames and names <= set(frames[-1]["ids"]) and test_web.page_text(
                    page, "track-count") == str(len(frames[-1]["ids"])):
                return True
            for j, tid in enumerate(sorted(names)):  # the picture advances meanwhile
                feed.put(KEYS.meas("radar1", tid), meas(t, 700.0 * j))
            feed.put(KEYS.clock, pack({"t": t + 0.5}))
            t += 1.0
            return False

        assert test_web.poll(shown, timeout=WAIT, step=0.5), (
            test_web.page_text(page, "track-count"), frames[-1:])
        assert test_web.poll(lambda: "secure" in test_web.page_text(page, "health"),
                             timeout=WAIT)
    finally:
        err = web.stop()
    assert "Traceback" not in err, err
