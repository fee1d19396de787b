"""The pytest plugin (docs/client.md) in pytest sessions of their own (pytester, in a
subprocess): the documented tests pass against real services, a failing one carries the
service's log, the services are gone afterwards, and the plugin is active only where a
project enables it."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from zenoh_track import __version__
from zenoh_track.tracking.compiled import KERNELS

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "client.md"
ENABLE = 'pytest_plugins = ["zenoh_track.clients.pytest_plugin"]\n'


def doc_blocks(path: Path = DOC) -> list[str]:
    """The python code blocks of a document, in order."""
    return re.findall(r"```python\n(.*?)```", path.read_text(), re.S)


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return not Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"


def test_the_documented_tests_pass_and_a_wrong_one_shows_the_log(pytester):
    first, marker = doc_blocks()[0], doc_blocks()[1]
    assert "def test_my_feed_confirms_a_track(track)" in first
    wrong = first.replace("[500.0, 0.0, 1000.0]", "[600.0, 0.0, 1000.0]") \
        .replace("def test_my_feed_confirms_a_track", "def test_wrong_position")
    assert wrong != first
    pids = pytester.path / "pids"
    pytester.makeconftest(ENABLE + f"""
import pytest

@pytest.fixture(autouse=True)
def note_pid(request):
    yield
    svc = request.node.funcargs.get("track")
    svc = svc.service if svc is not None else request.node.funcargs.get("track_service")
    if svc is not None:
        with open({str(pids)!r}, "a") as f:
            f.write(f"{{svc.proc.pid}}\\n")
""")
    # the tutorials' feed and its test, as a newcomer copies them
    my_radar = doc_blocks(ROOT / "docs" / "tutorials" / "first-tracks.md")[0]
    tutorial = doc_blocks(ROOT / "docs" / "tutorials" / "your-feed.md")
    assert tutorial[0] == ENABLE and "def test_my_radar_makes_one_confirmed_track" in tutorial[1]
    pytester.makepyfile(test_doc=first, test_wrong=wrong, my_radar=my_radar,
                        test_tutorial=tutorial[1], test_marker="import pytest\n\n" + marker)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-rA", timeout=600)
    result.assert_outcomes(passed=4, failed=1)
    out = result.stdout.str()
    assert "FAILED test_wrong.py::test_wrong_position" in out
    assert re.search(r"track-service test[0-9a-f]+ log", out), out[-3000:]
    assert f"track-service {__version__}: ns=test" in out  # the service's own first line
    started = [int(p) for p in pids.read_text().split()]
    assert len(started) == 4 and not any(alive(p) for p in started)


def test_the_factories_of_a_conftest(pytester):
    pytester.makeconftest(ENABLE + doc_blocks()[2])
    pytester.makepyfile(test_cv="""
def test_module_scoped(cv_service, cv_client):
    assert cv_client.status()["clock"] == "lockstep"
    assert cv_client.keys.ns == cv_service.ns

def test_same_service(cv_service, cv_client, track_service):
    assert cv_service.ns != track_service.ns
    assert cv_service.proc.poll() is None

def test_feed_and_picture_fixtures(track_feed, track_picture, track_client):
    track_feed.measure("x-1", t=0.0, pos=[1.0, 2.0, 3.0])
    track_feed.clock(1.0)
    frame = track_picture.wait_for(lambda f: f.t > 0.95)
    assert frame.id_list == ["x-1"] and list(track_client.tracks()) == ["x-1"]
""")
    pytester.runpytest_subprocess("-p", "no:cacheprovider", timeout=300) \
        .assert_outcomes(passed=3)


@pytest.mark.parametrize("how", ["ini", "-p", "none"])
def test_active_only_where_enabled(pytester, how):
    """The package's pytest11 entry point adds only the `zenoh_track` ini switch: the
    fixtures exist where the switch, `-p` or a conftest line enables them."""
    if how == "ini":
        pytester.makeini("[pytest]\nzenoh_track = true\n")
    pytester.makepyfile(test_x="def test_x(track_service):\n    assert track_service.client\n")
    args = ["-p", "zenoh_track.clients.pytest_plugin"] if how == "-p" else []
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", *args, timeout=300)
    if how == "none":
        result.assert_outcomes(errors=1)
        assert "fixture 'track_service' not found" in result.stdout.str()
    else:
        result.assert_outcomes(passed=1)


def test_importing_the_plugin_is_cheap():
    code = ("import sys, zenoh_track.clients.pytest_plugin, zenoh_track.clients.pytest_enable\n"
            "assert not {'zenoh', 'numpy'} & set(sys.modules), sorted(sys.modules)\n")
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.slow
def test_a_first_start_says_it_compiles_the_kernels(pytester, monkeypatch, tmp_path):
    """A fresh kernel cache: the fixture's wait tells the terminal what the service is
    doing and how far it is, through pytest's output capture."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "kernels"))
    pytester.makeconftest(ENABLE)
    pytester.makepyfile(test_x="def test_x(track_service):\n    assert track_service.client\n")
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", timeout=600)
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines([
        "*[[]zenoh_track[]] track-service: compiling the filter kernels, the first start on "
        "this machine only (about * s on two cores; then cached)...",
        f"*[[]zenoh_track[]] track-service: kernels {len(KERNELS)}/{len(KERNELS)} ready*"])


@pytest.mark.slow
def test_a_port_taken_before_the_service_listens_is_tried_again(monkeypatch):
    """The free port a service is given may be taken by another process before the
    service listens on it: the fixture starts it again on another one."""
    import socket

    from zenoh_track.clients import pytest_plugin
    from zenoh_track.clients.lib import process
    from zenoh_track.wire import free_port

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        ports = iter([port])
        monkeypatch.setattr(process, "free_port", lambda: next(ports, None) or free_port())
        svc = pytest_plugin.start(None, clock="lockstep")
        try:
            assert svc.client is not None and svc.endpoint != f"tcp/127.0.0.1:{port}"
        finally:
            svc.stop()
