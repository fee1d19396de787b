"""What a team gets from `pip install zenoh-track-service`: the built wheel (not an
editable install) in a fresh venv, beside a project of its own whose packages are called
`service` and `clients`, running docs/client.md's test with the plugin and the library
alone: it passes, and it fails (with the service's log) when its assertion is wrong."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent


def run(*cmd: str | Path, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=env)


def user_project(path: Path, test: str) -> None:
    """A project with packages `service` and `clients` of its own, a conftest that enables
    the plugin and uses its own packages, and `test` as its test file."""
    for pkg, text in (("service", "NAME = 'the team service'\n"),
                      ("clients", "NAME = 'the team clients'\n")):
        (path / pkg).mkdir(parents=True)
        (path / pkg / "__init__.py").write_text(text)
    (path / "conftest.py").write_text(
        'pytest_plugins = ["zenoh_track.clients.pytest_plugin"]\n\n'
        "import clients\nimport service\n\n"
        "assert service.NAME == 'the team service' and clients.NAME == 'the team clients'\n")
    (path / "tests").mkdir()
    (path / "tests" / "test_my_feed.py").write_text(test)


def test_the_wheel_in_a_fresh_venv_beside_a_project_of_its_own(tmp_path):
    doc_test = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "client.md").read_text(),
                          re.S)[0]
    dist, venv = tmp_path / "dist", tmp_path / "venv"
    out = run(sys.executable, "-m", "pip", "wheel", "-q", ".", "--no-deps", "-w", dist, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    (wheel,) = dist.glob("zenoh_track_service-*.whl")
    out = run(sys.executable, "-m", "venv", venv, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    py = venv / "bin" / "python"
    out = run(py, "-m", "pip", "install", "-q", wheel, "pytest", cwd=tmp_path, timeout=600)
    assert out.returncode == 0, out.stderr

    good, bad = tmp_path / "good", tmp_path / "bad"
    user_project(good, doc_test)
    wrong = doc_test.replace("[500.0, 0.0, 1000.0]", "[600.0, 0.0, 1000.0]")
    assert wrong != doc_test
    user_project(bad, wrong)

    # the team's packages and ours side by side, ours from the wheel
    code = ("import service, clients, zenoh_track, zenoh_track.clients as zc\n"
            "print(service.NAME, clients.NAME, zenoh_track.__file__, zc.Picture.__name__)")
    out = run(py, "-c", code, cwd=good)
    assert out.returncode == 0, out.stderr
    assert "the team service the team clients" in out.stdout
    assert str(venv) in out.stdout and "site-packages/zenoh_track" in out.stdout
    assert out.stdout.split()[-1] == "Picture"

    passed = run(py, "-m", "pytest", "-q", "-p", "no:cacheprovider", cwd=good)
    assert passed.returncode == 0, passed.stdout[-3000:] + passed.stderr[-2000:]
    assert "1 passed" in passed.stdout
    failed = run(py, "-m", "pytest", "-q", "-p", "no:cacheprovider", cwd=bad)
    assert failed.returncode == 1, failed.stdout[-3000:]
    assert "1 failed" in failed.stdout and "assert" in failed.stdout
    assert re.search(r"track-service test[0-9a-f]+ log", failed.stdout)
