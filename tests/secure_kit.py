"""The secured deployment of deploy/secure/ on loopback, for the tests of test_security*:
a throwaway CA from make-certs.sh, the shipped config files with only the certificate
directory (and, for user/password, the password) moved, `track-router` on each router
file, and the service and clients as processes or sessions of their role."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh
from routers import DEPLOY, ENV, RouterProc, client_conf

from zenoh_track.clients.lib.process import stop
from zenoh_track.wire import Keys, free_port, wait_for_tracker

SECURE = DEPLOY / "secure"
MOUNT = "/deploy/secure/certs/"
VARIANTS = ("mtls", "usrpwd")
# role -> (certificate common name / user, client file)
ROLES = {"tracker": ("track-service", "service.json5"), "feed": ("track-feed", "feed.json5"),
         "viewer": ("track-viewer", "viewer.json5"),
         "interceptor": ("track-intercept", "intercept.json5")}
KEYS = Keys("track")  # the policy's namespace
BIN = Path(sys.executable).parent


def make_certs(where: Path) -> Path:
    subprocess.run(["sh", str(SECURE / "make-certs.sh"), str(where), "router", "localhost",
                    "127.0.0.1"], check=True, capture_output=True, timeout=120)
    return where


@pytest.fixture(scope="session")
def pki(tmp_path_factory) -> tuple[Path, Path]:
    """The deployment's certificates and passwords, and another CA's."""
    base = tmp_path_factory.mktemp("pki")
    return make_certs(base / "certs"), make_certs(base / "rogue")


def mounted(variant: str, name: str, certs: Path, out: Path, password: str | None = None,
            edit=None) -> Path:
    """The shipped file with the certificates where this test keeps them (and the password
    make-certs.sh wrote in place of CHANGE-ME); `edit(text)` changes it further."""
    text = (SECURE / variant / name).read_text().replace(MOUNT, f"{certs}/")
    if password is not None:
        text = text.replace('"CHANGE-ME"', json.dumps(password))
    if edit is not None:
        text = edit(text)
    path = out / f"{variant}-{len(list(out.glob('*')))}-{name}"
    path.write_text(text)
    return path


def role_config(variant: str, role: str, certs: Path, out: Path, edit=None) -> Path:
    cn, name = ROLES[role]
    pw = (certs / f"{cn}.password").read_text() if variant == "usrpwd" else None
    return mounted(variant, name, certs, out, pw, edit)


def session_for(path: Path, endpoint: str) -> zenoh.Session:
    return zenoh.open(client_conf(path, endpoint))


def program(name: str, *args: str) -> list[str]:
    """The installed command `name` (track-display, ...) with its arguments."""
    return [str(BIN / name), *args]


def one_line(argv: list[str], timeout: float = 60) -> tuple[int, str, float]:
    """Run a program that is to be refused: (exit status, stderr, seconds it took)."""
    t0 = time.monotonic()
    p = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, env=ENV,
                       stdin=subprocess.DEVNULL)
    return p.returncode, p.stderr, time.monotonic() - t0


class Deployment:
    """`track-router` with one shipped router file and a lockstep service behind it."""

    def __init__(self, variant: str, certs: Path, out: Path, router_edit=None) -> None:
        self.variant, self.certs, self.out = variant, certs, out
        self.endpoint = f"tls/127.0.0.1:{free_port()}"
        self.router = RouterProc(mounted(variant, "router.json5", certs, out,
                                         edit=router_edit), self.endpoint)
        self.service: subprocess.Popen | None = None
        self.sessions: list[zenoh.Session] = []

    def config(self, role: str, edit=None) -> Path:
        return role_config(self.variant, role, self.certs, self.out, edit)

    def session(self, role: str) -> zenoh.Session:
        s = session_for(self.config(role), self.endpoint)
        self.sessions.append(s)
        return s

    def start(self, service: bool = True) -> Deployment:
        self.router.start()
        if service:
            self.service = subprocess.Popen(
                program("track-service", "-c", str(self.config("tracker")), "-e",
                        self.endpoint, "--clock", "lockstep", "--instance", "secure"),
                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=ENV)
            if not wait_for_tracker(self.session("viewer"), KEYS, 1, timeout=60):
                raise RuntimeError(f"no tracker: {stop(self.service)[-2000:]}")
        return self

    def close(self) -> str:
        for s in self.sessions:
            s.close()
        err = stop(self.service)
        self.router.stop()
        return err


@pytest.fixture(scope="module", params=VARIANTS)
def deployment(request, pki, tmp_path_factory):
    """A started Deployment of each variant, shared by a module's tests."""
    d = Deployment(request.param, pki[0], tmp_path_factory.mktemp(request.param)).start()
    yield d
    err = d.close()
    assert "Traceback" not in err, err
