"""The documentation site: built strictly (a broken link or a renamed option fails it),
every option of every program in the generated reference, pages a reader can finish, and
a product that speaks of itself, not of the order its work was done in."""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
MKDOCS = Path(sys.executable).with_name("mkdocs")
MAX_LINES = 500

# what a page must not say: tracker numbers, work sessions, dates and commits of the work,
# and phrases that tell what changed instead of what is
HISTORY = re.compile(
    r"\bissues? ?#?\d+|(?<![\w/&])#\d{1,5}\b"
    r"|\b(first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth"
    r"|thirteenth|fourteenth|fifteenth|this|that|next|previous|last) session\b"
    r"|\b20\d\d-\d\d-\d\d\b|`[0-9a-f]{7,40}`|\bbranch `"
    r"|\b(fixed since|no longer|used to|the old default|the new default|first draft)\b",
    re.IGNORECASE)


def hook():
    """docs/_hooks/reference.py, the MkDocs hook that generates the reference."""
    path = DOCS / "_hooks" / "reference.py"
    spec = importlib.util.spec_from_file_location("docs_reference", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def pages() -> list[Path]:
    return sorted(p for p in DOCS.rglob("*.md") if "results/data" not in p.as_posix())


def build(config: Path, site: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(MKDOCS), "build", "--strict", "-f", str(config), "-d", str(site)],
                          capture_output=True, text=True, timeout=600,
                          env={"PATH": str(MKDOCS.parent), "NO_MKDOCS_2_WARNING": "1"})


def copy_of_docs(tmp: Path) -> Path:
    """The docs, the config and what the hook reads, in a directory of their own."""
    shutil.copytree(DOCS, tmp / "docs", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("mkdocs.yml", "pyproject.toml"):
        shutil.copy(ROOT / name, tmp / name)
    for name in ("service", "clients"):
        (tmp / name).symlink_to(ROOT / name)
    return tmp / "mkdocs.yml"


def test_every_page_is_short_enough_to_read():
    long = {p.relative_to(ROOT).as_posix(): n for p in pages()
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert long == {}, f"pages over {MAX_LINES} lines: {long}"


def test_the_docs_speak_of_the_product_not_of_its_history():
    texts = {p.relative_to(ROOT).as_posix(): p.read_text() for p in pages()}
    texts["README.md"] = (ROOT / "README.md").read_text()
    texts["bench/README.md"] = (ROOT / "bench" / "README.md").read_text()
    for folder in ("bench", "tests"):
        for path in (ROOT / folder).rglob("*.py"):
            if path != Path(__file__).resolve():
                texts[path.relative_to(ROOT).as_posix()] = path.read_text()
    ref = hook()
    for name, parser in ref.parsers().items():
        texts[f"{name} --help"] = parser.format_help()
    found = [f"{where}: {m.group(0)!r}" for where, text in texts.items()
             for m in HISTORY.finditer(text)]
    assert found == []
    # the changelog is history by design, but of releases: no tracker numbers in it either
    assert not re.search(r"\bissues? ?#?\d+", (ROOT / "CHANGELOG.md").read_text(), re.I)


def test_the_check_finds_what_it_looks_for():
    """The pattern above catches each kind of history it names (so its passing means
    something) and leaves ordinary text alone."""
    for text in ("issue 13's targets", "the twelfth session", "measured 2026-12-02",
                 "at commit `a766f1b`", "fixed since", "see #26", "Issue #4"):
        assert HISTORY.search(text), text
    for text in ("a Zenoh session", "§4.2", "[x](protocol.md#51-tracks)", "issues a warning",
                 "the previous frame", "frame 2026 of the run"):
        assert not HISTORY.search(text), text


def test_every_console_script_has_a_parser_the_reference_reads():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    ref = hook()
    assert set(scripts) <= set(ref.parsers())
    markdown = ref.options_markdown()
    for name, parser in ref.parsers().items():
        section = markdown.split(f"## {name}\n", 1)[1].split("\n## ", 1)[0]
        for action in parser._actions:
            for option in action.option_strings:
                assert f"`{option}`" in section, f"{name} {option} missing from the reference"


def test_commands_in_the_pages_are_read_like_a_shell():
    ref = hook()
    assert ref.unknown_options("track-service --filter cv --q 32") == []
    assert ref.unknown_options("track-service --filtre cv") == [("track-service", "--filtre")]
    # a value that looks like an option belongs to the option before it
    assert ref.unknown_options("track-eval crossing --service-arg --pd --service-arg 0.3") == []
    assert ref.unknown_options(".venv/bin/track-eval manoeuvres --labelled --no-such") == [
        ("track-eval manoeuvres", "--no-such")]
    assert ref.unknown_options("python -m zenoh_track --clock lockstep | grep --count x") == []


@pytest.mark.slow
def test_the_site_builds_strictly_with_every_option_in_it(tmp_path):
    result = build(ROOT / "mkdocs.yml", tmp_path / "site")
    assert result.returncode == 0, result.stderr
    html = (tmp_path / "site" / "reference" / "options" / "index.html").read_text()
    ref = hook()
    for name, parser in ref.parsers().items():
        assert f'id="{name.replace(" ", "-")}"' in html, name
        for action in parser._actions:
            for option in action.option_strings:
                assert f"<code>{option}</code>" in html, f"{name} {option}"
    api = (tmp_path / "site" / "reference" / "api" / "index.html").read_text()
    assert "wait_for_errors" in api and "from_payload" in api  # generated from docstrings
    assert "IMM_WIDE_DV" in (tmp_path / "site" / "reference" / "defaults" / "index.html"
                             ).read_text()


@pytest.mark.slow
@pytest.mark.parametrize("broken, says", [
    ("Start it with `track-service --no-such-option`.", "has no option --no-such-option"),
    ("See [the protocol](protocol.md#no-such-section).", "no-such-section"),
    ("See [a page](no-such-page.md).", "no-such-page.md"),
])
def test_a_renamed_option_or_a_broken_link_fails_the_build(tmp_path, broken, says):
    config = copy_of_docs(tmp_path)
    page = tmp_path / "docs" / "tutorials" / "first-tracks.md"
    page.write_text(page.read_text() + f"\n{broken}\n")
    result = build(config, tmp_path / "site")
    assert result.returncode != 0
    assert says in result.stderr


def test_the_results_figures_are_drawn_from_the_benchmarks_output(tmp_path):
    """docs/results/draw.py reads every data file it names and draws each figure the results
    pages show."""
    out = subprocess.run([sys.executable, str(DOCS / "results" / "draw.py"), "--out",
                          str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    drawn = sorted(p.name for p in tmp_path.glob("*.png"))
    shown = sorted(set(re.findall(r"figures/(results_\w+\.png)", "".join(
        (DOCS / page).read_text() for page in ("accuracy.md", "performance.md")))))
    assert drawn == shown
    assert all((tmp_path / name).stat().st_size > 10_000 for name in drawn)
