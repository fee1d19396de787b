"""Every program whose optional dependency is missing says which extra to install, in one
line with exit status 2: tried in a real virtual environment of the product alone
(`pip install -e .`, the README's first command, no extras)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# each console script (or option) that needs an extra, with that extra
NEEDS = [
    (["track-web"], "web"),
    (["track-foxglove"], "foxglove"),
    (["track-demo", "--web"], "web"),
    (["track-eval", "display", "--plot", "figures"], "plot"),
    (["track-replay", "any.mcap", "--plot", "out.png"], "plot"),
    (["track-dis"], "dis"),
]


@pytest.fixture(scope="module")
def bare_venv(tmp_path_factory) -> Path:
    venv = tmp_path_factory.mktemp("bare") / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    out = subprocess.run([str(venv / "bin" / "pip"), "install", "-q", "-e", str(ROOT)],
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    return venv


@pytest.mark.slow
@pytest.mark.parametrize("argv,extra", NEEDS, ids=[" ".join(a) for a, _ in NEEDS])
def test_a_missing_extra_is_one_line_naming_it(bare_venv, tmp_path, argv, extra):
    assert subprocess.run([str(bare_venv / "bin" / "python"), "-c", "import aiohttp"],
                          capture_output=True).returncode != 0, "the venv has the extras"
    out = subprocess.run([str(bare_venv / "bin" / argv[0]), *argv[1:]], capture_output=True,
                         text=True, cwd=tmp_path, timeout=120)
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2, out.stderr
    assert len(lines) == 1, out.stderr
    assert lines[0].startswith(argv[0])
    assert f"pip install 'zenoh-track-service[{extra}]'" in lines[0]
    assert f"pip install -e '.[{extra}]'" in lines[0]
