"""MkDocs hook: the reference pages generated from the code, and every option a page names
checked against the program's own parser.

- `<!-- options -->` in a page becomes the options of every console script of
  pyproject.toml's [project.scripts] (and the sub-programs with parsers of their own),
  read from each program's `parser()`: the reference cannot drift from the programs.
- `<!-- defaults -->` becomes the table of `service/defaults.py`: each name, its value and
  the comment that gives its reason.
- Every page's commands (in code spans and code blocks) that start with a program name are
  read like a shell would: each option must be one of that program's, or the build warns,
  which fails `mkdocs build --strict`. A renamed option therefore fails the docs build.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import io
import logging
import re
import shlex
import tokenize
import tomllib
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
log = logging.getLogger("mkdocs.hooks.reference")

# programs reached through a first positional word, each with a parser of its own
SUBPROGRAMS = {"track-eval manoeuvres": "zenoh_track.clients.evaluation.manoeuvres"}
# how a page may start a program besides its script name
ALIASES = {"python -m zenoh_track": "track-service"}


def scripts() -> dict[str, str]:
    """Console scripts of pyproject.toml: name -> module."""
    with open(ROOT / "pyproject.toml", "rb") as f:
        table = tomllib.load(f)["project"]["scripts"]
    return {name: target.split(":")[0] for name, target in table.items()}


@cache
def parsers() -> dict[str, argparse.ArgumentParser]:
    """Every program's parser, from its module's `parser()` (no program is run)."""
    found = {}
    for name, module in [*scripts().items(), *SUBPROGRAMS.items()]:
        mod = importlib.import_module(module)
        if not hasattr(mod, "parser"):
            raise RuntimeError(f"{module} has no parser(): {name}'s options cannot be documented")
        found[name] = mod.parser()
    return found


def option_strings(parser: argparse.ArgumentParser) -> set[str]:
    return {s for action in parser._actions for s in action.option_strings}


def _cell(text: str) -> str:
    text = " ".join(str(text).split())
    return text.replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")


def _help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    if not action.help or action.help == argparse.SUPPRESS:
        return ""
    return parser._get_formatter()._expand_help(action)


def _value(action: argparse.Action) -> str:
    if action.nargs == 0:
        return ""
    if action.choices:
        return " \\| ".join(f"`{c}`" for c in action.choices)
    meta = action.metavar or (action.dest.upper() if action.option_strings else action.dest)
    return f"`{meta if isinstance(meta, str) else ' '.join(meta)}`"


def _default(action: argparse.Action) -> str:
    d = action.default
    if d is None or d is False or d == [] or d == argparse.SUPPRESS or action.nargs == 0:
        return ""
    return f"`{d}`"


def program_markdown(name: str, parser: argparse.ArgumentParser) -> str:
    """One program: its usage line, its purpose and a table per group of options."""
    usage = parser.format_usage().removeprefix("usage: ").strip()
    purpose = (parser.description or "").strip().split("\n\n")[0]
    lines = [f"## {name}", "", _cell(purpose), "", "```text", usage, "```", ""]
    for group in parser._action_groups:
        actions = [a for a in group._group_actions if a.help != argparse.SUPPRESS]
        if not actions:
            continue
        lines += [f"**{group.title}**", "", "| option | value | default | meaning |",
                  "|---|---|---|---|"]
        for a in actions:
            names = ", ".join(f"`{s}`" for s in a.option_strings) or f"`{a.dest}`"
            lines.append(f"| {names} | {_value(a)} | {_default(a)} | {_cell(_help(parser, a))} |")
        lines.append("")
    return "\n".join(lines)


def options_markdown() -> str:
    return "\n".join(program_markdown(name, p) for name, p in parsers().items())


def defaults_markdown() -> str:
    """service/defaults.py as a table: name, value, the comment beside or above it."""
    source = (ROOT / "service" / "defaults.py").read_text()
    comments: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string.lstrip("# ").strip()
    lines = source.splitlines()
    rows = ["| name | value | why |", "|---|---|---|"]
    for node in ast.parse(source).body:
        if not isinstance(node, ast.Assign | ast.AnnAssign):
            continue
        target = node.targets[0] if isinstance(node, ast.Assign) else node.target
        if not isinstance(target, ast.Name) or not target.id.isupper():
            continue
        above, k = [], node.lineno - 1
        while k in comments and lines[k - 1].lstrip().startswith("#") \
                and not lines[k - 1].lstrip().startswith("# ----"):
            above.insert(0, comments[k])
            k -= 1
        why = " ".join([*above, comments.get(node.lineno, "")]).strip()
        value = ast.get_source_segment(source, node.value) or ""
        rows.append(f"| `{target.id}` | `{_cell(value)}` | {_cell(why)} |")
    return "\n".join(rows)


# ------------------------------------------------------------ options named in the pages
_SPAN = re.compile(r"(?<!`)`([^`\n]+)`(?!`)")
_FENCE = re.compile(r"^(```|~~~)[^\n]*\n(.*?)^\1", re.S | re.M)
_STOP = {"|", "||", "&&", ";", "&", "#"}


def _program_at(words: list[str], i: int) -> tuple[str | None, int]:
    """The program a command starts with at words[i], and how many words name it."""
    word = words[i].rsplit("/", 1)[-1]
    for alias, name in ALIASES.items():
        n = len(alias.split())
        if [w.rsplit("/", 1)[-1] for w in words[i:i + n]] == alias.split():
            return name, n
    if word in parsers():
        sub = f"{word} {words[i + 1]}" if i + 1 < len(words) else ""
        return (sub, 2) if sub in parsers() else (word, 1)
    return None, 1


def unknown_options(command: str) -> list[tuple[str, str]]:
    """(program, option) for every option of a known program that its parser lacks."""
    try:
        words = shlex.split(command, comments=True)
    except ValueError:
        words = command.split()
    bad, program, i = [], None, 0
    while i < len(words):
        w = words[i]
        if w in _STOP or w.endswith(";"):
            program, i = None, i + 1
            continue
        name, n = _program_at(words, i)
        if name:
            program, i = name, i + n
            continue
        if program and re.fullmatch(r"--?[A-Za-z][\w-]*(=.*)?", w):
            opt = w.split("=", 1)[0]
            parser = parsers()[program]
            actions = {s: a for a in parser._actions for s in a.option_strings}
            if opt not in actions:
                bad.append((program, opt))
            elif "=" not in w and actions[opt].nargs != 0:
                i += 1  # its value, which may itself look like an option (--service-arg --q)
        i += 1
    return bad


def check_page(markdown: str, where: str) -> int:
    texts = [m.group(2) for m in _FENCE.finditer(markdown)]
    rest = _FENCE.sub("", markdown)
    commands = [line for t in texts for line in t.splitlines()]
    commands += [m.group(1) for m in _SPAN.finditer(rest)]
    found = 0
    for command in commands:
        for program, opt in unknown_options(command.replace("$ ", "", 1)):
            log.warning("%s: `%s` has no option %s (in: %s)", where, program, opt,
                        command.strip())
            found += 1
    return found


def lay_out_package() -> None:
    """Lay out the package as it installs (service/ is `zenoh_track`, clients/ is
    `zenoh_track.clients`) under build/docs-src, where mkdocstrings reads the docstrings.
    Done when MkDocs loads this hook, before mkdocstrings looks for its paths."""
    package = ROOT / "build" / "docs-src" / "zenoh_track"
    package.mkdir(parents=True, exist_ok=True)
    for link in package.iterdir():
        if not link.exists():  # its module is gone from the source tree
            link.unlink()
    for source in [*(ROOT / "service").iterdir(), ROOT / "clients"]:
        if source.name == "__pycache__":
            continue
        link = package / source.name
        if not link.is_symlink():
            link.symlink_to(source)


lay_out_package()


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ANN001 (MkDocs)
    markdown = markdown.replace("<!-- options -->", options_markdown())
    markdown = markdown.replace("<!-- defaults -->", defaults_markdown())
    check_page(markdown, page.file.src_path)
    return markdown
