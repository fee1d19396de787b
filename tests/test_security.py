"""Security: the shipped configs of deploy/secure/ (mutual TLS; user/password over TLS;
one access-control policy) on loopback, with a throwaway CA from
deploy/secure/make-certs.sh and `track-router` reading the router's file.

Proved for both variants: the authorised feed -> service -> viewer chain works end to
end; a viewer cannot inject a measurement, a clock message, a display state or a status
answer; a feed cannot publish display states; a client without valid credentials (no
certificate, a certificate of another CA, no or a wrong password, plain TCP) cannot
connect at all. The config files are the ones docker-compose.secure.yml mounts: only the
certificate directory (/deploy/secure/certs in the containers) and the endpoint move."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh
from routers import DEPLOY, ENV, RouterProc, Stamped

from clients.procs import stop
from service.wire import Keys, free_port, pack, unpack, wait_for_tracker

SECURE = DEPLOY / "secure"
MOUNT = "/deploy/secure/certs/"
ROLES = ("track-service", "track-feed", "track-viewer")
FILES = {"track-service": "service.json5", "track-feed": "feed.json5",
         "track-viewer": "viewer.json5"}
KEYS = Keys("track")  # the policy's namespace


def make_certs(where: Path) -> Path:
    subprocess.run(["sh", str(SECURE / "make-certs.sh"), str(where), "router", "localhost",
                    "127.0.0.1"], check=True, capture_output=True, timeout=120)
    return where


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> tuple[Path, Path]:
    """The deployment's certificates and passwords, and another CA's."""
    base = tmp_path_factory.mktemp("pki")
    return make_certs(base / "certs"), make_certs(base / "rogue")


def mounted(variant: str, name: str, certs: Path, out: Path, password: str | None = None
            ) -> Path:
    """The shipped config with the certificates where this test keeps them (and, for a
    user/password client, the password make-certs.sh wrote in place of CHANGE-ME)."""
    text = (SECURE / variant / name).read_text().replace(MOUNT, f"{certs}/")
    if password is not None:
        text = text.replace('"CHANGE-ME"', json.dumps(password))
    path = out / f"{variant}-{name}"
    path.write_text(text)
    return path


def role_config(variant: str, role: str, certs: Path, out: Path) -> Path:
    pw = (certs / f"{role}.password").read_text() if variant == "usrpwd" else None
    return mounted(variant, FILES[role], certs, out, pw)


def session_for(path: Path, endpoint: str, timeout_ms: int = -1) -> zenoh.Session:
    conf = zenoh.Config.from_file(str(path))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    if timeout_ms >= 0:  # a client that is to be refused: give up instead of waiting
        conf.insert_json5("connect/timeout_ms", str(timeout_ms))
        conf.insert_json5("connect/exit_on_failure", "true")
    return zenoh.open(conf)


def refused(path: Path, endpoint: str, edit=None) -> bool:
    """True when a client of this config cannot open a session with the router."""
    conf_path = path
    if edit is not None:
        conf_path = path.with_name("edited-" + path.name)
        conf_path.write_text(edit(path.read_text()))
    zenoh.Config.from_file(str(conf_path))  # a valid config: refused for its credentials
    try:
        s = session_for(conf_path, endpoint, timeout_ms=1500)
    except zenoh.ZError:
        return True
    connected = bool(list(s.info.routers_zid()))
    s.close()
    return not connected


def statuses(session: zenoh.Session) -> list[dict]:
    replies = session.get(KEYS.status, target=zenoh.QueryTarget.ALL,
                          consolidation=zenoh.ConsolidationMode.NONE, timeout=10)
    return [unpack(r.ok.payload.to_bytes()) for r in replies if r.ok is not None]


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["mtls", "usrpwd"])
def test_secured_router_lets_each_role_do_only_its_part(variant, certs, tmp_path):
    good, rogue = certs
    endpoint = f"tls/127.0.0.1:{free_port()}"
    router = RouterProc(mounted(variant, "router.json5", good, tmp_path), endpoint)
    router.start()
    svc = None
    sessions: list[zenoh.Session] = []
    try:
        svc = subprocess.Popen(
            [sys.executable, "-m", "service", "-c",
             str(role_config(variant, "track-service", good, tmp_path)), "-e", endpoint,
             "--clock", "lockstep", "--instance", "secure"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=ENV)
        viewer_conf = role_config(variant, "track-viewer", good, tmp_path)
        viewer = session_for(viewer_conf, endpoint)
        watcher = session_for(viewer_conf, endpoint)  # a second viewer: what others see
        sessions += [viewer, watcher]
        display = Stamped(watcher, KEYS.space("display"))
        tracks = Stamped(watcher, KEYS.space("tracks"))
        errors = Stamped(watcher, KEYS.space("errors"))
        assert wait_for_tracker(viewer, KEYS, 1, timeout=30), "tracker not seen by a viewer"

        # the viewer tries to inject, before and during the feed's run
        fake_meas = pack({"t": 1.0, "pos": [1000.0, 2000.0]})
        viewer.put(KEYS.meas("radar1", "intruder-1"), fake_meas)
        viewer.put(KEYS.clock, pack({"t": 5000.0}))
        viewer.put(KEYS.display("fake-1"), pack(
            {"t": 1.0, "id": "fake-1", "pos": [0.0, 0.0, 0.0], "vel": [0.0, 0.0, 0.0],
             "sigma": 1.0, "status": "confirmed", "age": 0.0}))
        spoof = viewer.declare_queryable(KEYS.status, lambda q: q.reply(
            KEYS.status, pack({"tracks": 999, "instance": "spoof"})))
        feed_conf = role_config(variant, "track-feed", good, tmp_path)
        feed_session = session_for(feed_conf, endpoint)
        sessions.append(feed_session)
        feed_session.put(KEYS.display("fake-2"), pack({"t": 1.0, "id": "fake-2"}))

        run = subprocess.run(
            [sys.executable, "-m", "clients.feed", "swarm", "--targets", "3", "--duration",
             "4", "-c", str(feed_conf), "-e", endpoint], capture_output=True, text=True,
            timeout=120, env=ENV)
        assert run.returncode == 0, run.stderr[-2000:]
        names = {f"swarm-{i:05d}" for i in range(3)}
        seen = lambda s: {k.rsplit("/", 1)[1] for _, k, _, _ in s}  # noqa: E731
        assert display.wait_for(lambda s: seen(s) >= names, 30), seen(display.snapshot())
        assert tracks.wait_for(lambda s: seen(s) >= names, 30)
        viewer.put(KEYS.meas("radar1", "intruder-2"), fake_meas)  # and after the run
        # a marker from the feed, sent after the intruder's: once it is tracked, the
        # intruder's measurement would have been too
        feed_session.put(KEYS.meas("radar1", "marker-1"), pack({"t": 5.5,
                                                                "pos": [5.0, 5.0]}))
        feed_session.put(KEYS.clock, pack({"t": 6.5}))  # its frames: up to 6.467
        assert tracks.wait_for(lambda s: "marker-1" in seen(s), 30)
        assert display.wait_for(lambda s: "marker-1" in seen(s), 30)

        held = [unpack(r.ok.payload.to_bytes())["id"]
                for r in viewer.get(KEYS.space("tracks"), timeout=10) if r.ok is not None]
        assert sorted(held) == sorted([*names, "marker-1"])  # nothing injected got in
        st = statuses(watcher)  # (the viewer's own session would answer itself locally)
        assert [s["instance"] for s in st] == ["secure"], st  # the spoof never answers
        assert st[0]["meas_rejected"] == 0  # the viewer's inputs never reached it
        assert seen(display.snapshot()) == {*names, "marker-1"}
        assert not {"fake-1", "fake-2", "intruder-1", "intruder-2"} & \
            (seen(display.snapshot()) | seen(tracks.snapshot()))
        assert errors.snapshot() == []
        assert all(b["t"] < 6.5 for _, _, k, b in display.snapshot() if k == "PUT")
        spoof.undeclare()

        # clients without valid credentials cannot connect at all
        assert not refused(viewer_conf, endpoint)  # (the check can tell)
        assert refused(viewer_conf, endpoint.replace("tls/", "tcp/"))  # plain TCP
        if variant == "mtls":
            assert refused(mounted(variant, "viewer.json5", rogue, tmp_path), endpoint)
            assert refused(viewer_conf, endpoint, lambda t: re.sub(
                r"\s*connect_(certificate|private_key): [^\n]*\n", "\n", t))
            assert refused(viewer_conf, endpoint, lambda t: t.replace(
                "enable_mtls: true", "enable_mtls: false"))
        else:
            assert refused(mounted(variant, "viewer.json5", good, tmp_path), endpoint)
            assert refused(viewer_conf, endpoint, lambda t: t.replace(
                (good / "track-viewer.password").read_text(),
                (rogue / "track-viewer.password").read_text()))
            assert refused(viewer_conf, endpoint, lambda t: re.sub(
                r"auth: \{[^\n]*\n", "\n", t))
        assert refused(viewer_conf, endpoint, lambda t: t.replace(str(good), str(rogue)))
    finally:
        for s in sessions:
            s.close()
        err = stop(svc)
        router.stop()
    assert "Traceback" not in err, err


def test_both_routers_carry_the_same_policy():
    """The two variants differ in how clients prove who they are, not in what each
    role may do."""
    def policy(variant: str) -> tuple:
        conf = zenoh.Config.from_file(str(SECURE / variant / "router.json5"))
        acl = json.loads(conf.get_json("access_control"))
        return acl["enabled"], acl["default_permission"], acl["rules"], acl["policies"], \
            [s["id"] for s in acl["subjects"]]
    assert policy("mtls") == policy("usrpwd")
    mtls = json.loads(zenoh.Config.from_file(str(SECURE / "mtls" / "router.json5"))
                      .get_json("access_control/subjects"))
    assert sorted(c for s in mtls for c in s["cert_common_names"]) == sorted(ROLES)
    assert policy("mtls")[:2] == (True, "deny")


def test_make_certs_names_each_role_in_its_certificate(tmp_path):
    certs = make_certs(tmp_path / "c")
    for role in ROLES:
        subject = subprocess.run(["openssl", "x509", "-in", str(certs / f"{role}.pem"),
                                  "-noout", "-subject"], capture_output=True, text=True,
                                 check=True).stdout
        assert f"CN = {role}" in subject or f"CN={role}" in subject
        assert len((certs / f"{role}.password").read_text()) == 32
    lines = (certs / "credentials.txt").read_text().splitlines()
    assert [ln.split(":")[0] for ln in lines] == list(ROLES)
    assert not (certs / "ca.srl").exists()


