"""The recipe of docs/operations.md section 2, run as written: make-certs.sh, the config
files pointed at the certificates (and passwords), then track-router, track-service,
track-feed and track-display, each a process, over TLS on loopback, for both variants;
the live display (plain text when piped) shows the feed's 100 tracks within seconds.
Only the port (7447, maybe taken) and the variant line move."""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import threading
import time

import pytest
from routers import DEPLOY, ENV, ROOT
from secure_kit import BIN, VARIANTS

from zenoh_track.clients.lib.process import stop_all
from zenoh_track.wire import free_port

pytestmark = pytest.mark.slow
WAIT = 120.0  # s: generous for a loaded machine; the wait ends when the table is full


def recipe() -> tuple[str, list[str]]:
    """The shell lines before the first program (Docker's left out), and the programs."""
    text = (ROOT / "docs" / "operations.md").read_text()
    section = text[text.index("## 2. Running it secured"):text.index("## 3.")]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1).splitlines()
    first = next(i for i, ln in enumerate(block) if ln.startswith("track-"))
    setup = [ln for ln in block[:first] if not ln.startswith("docker ")]
    return "\n".join(setup) + "\n", block[first:]


def test_the_recipe_parses_as_expected():
    setup, programs = recipe()
    assert "make-certs.sh" in setup and re.search(r"^v=mtls\b", setup, re.M)
    assert [shlex.split(p)[0] for p in programs] == ["track-router", "track-service",
                                                     "track-feed", "track-display"]


def lines_of(proc: subprocess.Popen, sink: list[str], cond, hit: threading.Event) -> None:
    """Keep `proc`'s stdout lines; set `hit` at the first that meets `cond`, or at its
    end (then `cond` was never met)."""
    for line in proc.stdout:
        sink.append(line)
        if cond(line):
            sink.append("<met>")
            hit.set()
    hit.set()


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_secured_recipe_shows_the_tracks(variant, tmp_path):
    shutil.copytree(DEPLOY, tmp_path / "deploy", ignore=shutil.ignore_patterns("certs"))
    setup, programs = recipe()
    setup = re.sub(r"^v=mtls\b", f"v={variant}", setup, flags=re.M)
    env = {**ENV, "PATH": f"{BIN}:{ENV.get('PATH', '')}"}
    subprocess.run(["sh", "-c", setup], cwd=tmp_path, env=env, check=True, timeout=300,
                   capture_output=True)
    port = str(free_port())
    argv = [[a.replace("7447", port) for a in shlex.split(p)] for p in programs]
    procs: list[subprocess.Popen] = []
    out: dict[str, list[str]] = {}
    try:
        for args in argv:
            name = args[0]
            p = subprocess.Popen([str(BIN / name), *args[1:]], cwd=tmp_path, env=env,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            procs.append(p)
            out[name] = []
            hit = threading.Event()
            if name == "track-router":  # the others wait for it (5 s at most)
                cond = lambda ln: "listening on" in ln  # noqa: E731
            elif name == "track-display":
                cond = lambda ln: any(int(n) >= 100 for n in  # noqa: E731
                                      re.findall(r"tracks=(\d+)", ln))
            else:
                continue
            threading.Thread(target=lines_of, args=(p, out[name], cond, hit),
                             daemon=True).start()
            t0 = time.monotonic()
            hit.wait(WAIT)
            if "<met>" not in out[name]:
                codes = {a[0]: q.poll() for a, q in zip(argv, procs, strict=False)}
                stop_all(procs)
                pytest.fail(f"{name}: {''.join(out[name][-20:])} exit codes {codes}; "
                            f"stderr: {[q.stderr.read()[-1500:] for q in procs]}")
        shown = time.monotonic() - t0
        codes = {a[0]: q.poll() for a, q in zip(argv, procs, strict=False)}
    finally:
        stop_all(procs)
    print(f"{variant}: the display showed 100 tracks {shown:.1f} s after its start")
    assert set(codes.values()) == {None}, codes  # all still running
