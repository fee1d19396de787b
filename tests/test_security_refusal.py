"""Refused clients fail fast and say why, at the router: through the real secured routers
of deploy/secure/ (both variants, no service needed), a client with no certificate (mTLS
off in its own config), another CA's certificate, a wrong or missing password, or plain
TCP is refused by the router, and every program of the product given such a config
exits with status 2 and one line naming the cause, the shipped files' 5 s later."""

from __future__ import annotations

import re
import threading

import pytest
import secure_kit
import zenoh
from routers import client_conf
from secure_kit import Deployment, mounted, one_line, program

from zenoh_track.clients.record.files import RecordingWriter
from zenoh_track.wire import free_port
from zenoh_track.wire.cli import bound_connect
from zenoh_track.wire.refusal import why_refused

pytestmark = pytest.mark.slow
pki = secure_kit.pki  # the fixture
FAST = 10.0  # s: a refused program's whole run, start to exit


@pytest.fixture(scope="module", params=secure_kit.VARIANTS)
def router(request, pki, tmp_path_factory):
    d = Deployment(request.param, pki[0], tmp_path_factory.mktemp(request.param)).start(
        service=False)
    yield d
    d.close()


def router_refuses(conf_path, endpoint: str) -> str:
    """The router's refusal of a client of this config (the cause a program would print),
    or "" when it connected. A client that fails on its own, before the router (a missing
    key: "Missing TLS private key"), fails this check instead of passing it, and so does
    one that reached nothing (the probe must reach the router)."""
    conf = client_conf(conf_path, endpoint)
    bound_connect(conf, 3.0)
    try:
        zenoh.open(conf).close()
    except zenoh.ZError as exc:
        assert "Unable to connect" in str(exc), f"failed before the router: {exc}"
        reached, cause = why_refused(conf, [endpoint])
        assert reached, cause
        return cause
    return ""


def no_cert(text: str) -> str:
    """A client with mTLS off in its own config and no certificate lines."""
    text = text.replace("enable_mtls: true", "enable_mtls: false")
    return re.sub(r"\n\s*connect_(certificate|private_key): [^\n]*", "", text)


def in_parallel(checks: dict) -> dict:
    """Run each zero-argument check on a thread of its own: name -> result (or the
    AssertionError's text)."""
    out: dict = {}

    def run(name, check) -> None:
        try:
            out[name] = check()
        except AssertionError as exc:
            out[name] = f"not refused by the router: {exc}"

    threads = [threading.Thread(target=run, args=kv) for kv in checks.items()]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return out


def test_clients_without_valid_credentials_are_refused_by_the_router(router, pki):
    d, (good, rogue) = router, pki
    viewer = d.config("viewer")
    cases = {"valid": (viewer, d.endpoint, ""),
             "plain TCP": (viewer, d.endpoint.replace("tls/", "tcp/"), "speaks TLS")}
    if d.variant == "mtls":
        cases["no certificate"] = (d.config("viewer", no_cert), d.endpoint,
                                   "TLS refused by the router")
        cases["another CA's certificate"] = (d.config("viewer", lambda t: t.replace(
            f"{good}/track-viewer", f"{rogue}/track-viewer")), d.endpoint,
            "TLS refused by the router")
    else:
        pw = (good / "track-viewer.password").read_text()
        for name, other in (("wrong password", (rogue / "track-viewer.password").read_text()),
                            ("CHANGE-ME", "CHANGE-ME"),
                            ("another role's password",
                             (good / "track-feed.password").read_text())):
            cases[name] = (d.config("viewer", lambda t, o=other: t.replace(pw, o)),
                           d.endpoint, "authentication refused by the router")
        cases["no user"] = (d.config("viewer", lambda t: re.sub(r"auth: \{[^\n]*\n", "\n",
                                                                 t)), d.endpoint,
                            "refused the Zenoh session")
    causes = in_parallel({n: (lambda c=c: router_refuses(c[0], c[1]))
                          for n, c in cases.items()})
    for name, (_, _, expected) in cases.items():
        assert (expected in causes[name]) if expected else causes[name] == "", \
            (name, causes[name])


def test_a_router_that_wants_no_certificate_takes_the_same_client(pki, tmp_path):
    """The control of the refusal above: the client without a certificate connects to a
    router of the same file with mTLS off, so the refusal was the router's."""
    good = pki[0]
    d = Deployment("mtls", good, tmp_path, router_edit=lambda t: t.replace(
        "enable_mtls: true", "enable_mtls: false")).start(service=False)
    try:
        assert router_refuses(d.config("viewer", no_cert), d.endpoint) == ""
        # and a client that fails on its own is told so, not that the router refused it
        keyless = d.config("viewer", lambda t: re.sub(r"\n\s*connect_private_key: [^\n]*",
                                                      "", t))
        rc, err, _ = one_line(program("track-display", "-c", str(keyless), "-e", d.endpoint))
    finally:
        d.close()
    assert not single(rc, err, "mTLS on without a client certificate and key"), err
    assert "refused by the router" not in err, err


def single(rc: int, err: str, *words: str) -> str:
    lines = err.strip().splitlines()
    problem = ""
    if rc != 2 or len(lines) != 1 or "Traceback" in err:
        problem = f"exit {rc}, {len(lines)} lines: {err[-1500:]}"
    elif not all(w in lines[0] for w in words):
        problem = f"{lines[0]!r} does not say {words}"
    return problem


@pytest.mark.parametrize("variant,cause", [("mtls", "TLS refused by the router"),
                                           ("usrpwd", "authentication refused by the router")])
def test_a_refused_viewer_exits_at_once_with_one_line(variant, cause, pki, tmp_path):
    """track-display with another CA's certificate (mTLS) or a wrong password: exit 2 and
    one line naming the cause, within 10 s of its start."""
    good, rogue = pki
    d = Deployment(variant, good, tmp_path).start(service=False)
    try:
        if variant == "mtls":
            conf = d.config("viewer", lambda t: t.replace(f"{good}/", f"{rogue}/").replace(
                f"{rogue}/ca.pem", f"{good}/ca.pem"))
        else:
            pw = (good / "track-viewer.password").read_text()
            conf = d.config("viewer", lambda t: t.replace(pw, "wrong-password"))
        rc, err, took = one_line(program("track-display", "-c", str(conf), "-e",
                                         d.endpoint))
    finally:
        d.close()
    print(f"{variant}: exit {rc} after {took:.1f} s: {err.strip()}")
    assert not single(rc, err, "track-display: cannot connect to", d.endpoint, cause), err
    assert took < FAST, (took, err)


def refused_runs(d: Deployment, good, rogue, tmp_path) -> dict[str, list[str]]:
    """Every program with a config of its role that the router refuses."""
    if d.variant == "mtls":
        def bad(role: str):
            cn = secure_kit.ROLES[role][0]
            return str(d.config(role, lambda t: t.replace(f"{good}/{cn}", f"{rogue}/{cn}")))
    else:
        def bad(role: str):
            cn = secure_kit.ROLES[role][0]
            pw = (good / f"{cn}.password").read_text()
            return str(d.config(role, lambda t: t.replace(pw, "wrong-password")))
    rec = tmp_path / "one.mcap"
    with open(rec, "wb") as f:
        w = RecordingWriter(f, "track", ["track/**"])
        w.write("track/clock", "put", "application/msgpack", b"\x81\xa1t\xcb" + bytes(8),
                1_000, None)
        w.finish(received=1)
    e = ["-e", d.endpoint]
    return {
        "track-service": ["-c", bad("tracker"), *e],
        "track-feed": ["swarm", "--targets", "2", "-c", bad("feed"), *e],
        "track-replay": [str(rec), "--feed", "-c", bad("feed"), *e],
        "track-display": ["-c", bad("viewer"), *e],
        "track-web": ["--port", str(free_port()), "-c", bad("viewer"), *e],
        "track-record": ["-o", str(tmp_path / "x.mcap"), "-c", bad("viewer"), *e],
        "track-intercept": ["--targets-like", "x", "-c", bad("interceptor"), *e],
    }


@pytest.mark.parametrize("variant", secure_kit.VARIANTS)
def test_every_program_says_why_it_is_refused(variant, pki, tmp_path):
    good, rogue = pki
    d = Deployment(variant, good, tmp_path).start(service=False)
    cause = {"mtls": "TLS refused by the router",
             "usrpwd": "authentication refused by the router"}[variant]
    try:
        runs = {name: (lambda n=name, a=args: one_line(program(n, *a), timeout=120))
                for name, args in refused_runs(d, good, rogue, tmp_path).items()}
        # track-eval takes no config file: without the CA it refuses the router itself
        runs["track-eval"] = lambda: one_line(program("track-eval", "radar3d", "--runs", "1",
                                                      "-e", d.endpoint), timeout=120)
        # the router: a certificate it cannot read
        runs["track-router"] = lambda: one_line(program("track-router", "-c", str(mounted(
            variant, "router.json5", good, tmp_path, edit=lambda t: t.replace(
                "router.pem", "missing.pem"))), "-l", f"tls/127.0.0.1:{free_port()}"))
        results = in_parallel(runs)
    finally:
        d.close()
    words = {"track-eval": ("router's TLS certificate is not accepted",),
             "track-router": ("cannot read the TLS listen_certificate", "missing.pem",
                                      "No such file")}
    problems = {name: single(rc, err, *words.get(name, (f"{name}: cannot connect to",
                                                        cause)))
                for name, (rc, err, _) in results.items()}
    assert not any(problems.values()), problems
