"""The data's way is one direction (docs/architecture.md): wire contract -> estimation ->
tracking -> the Zenoh adapter (`zenoh_track.adapter`, which may import everything below it
and which nothing below imports) -> clients. Every import of the product's modules is read
from the source and checked against the rules; the wire package is also imported in a
fresh interpreter to show it loads neither NumPy nor Zenoh."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
STDLIB = set(sys.stdlib_module_names) | {"__future__"}

# package -> (allowed third-party top-level modules, allowed service sub-packages/modules)
RULES: dict[str, tuple[set[str], set[str]]] = {
    "zenoh_track.wire": ({"msgpack", "zenoh"}, {"zenoh_track.wire"}),
    "zenoh_track.defaults": (set(), set()),
    "zenoh_track.estimation": ({"numpy", "numba"}, {"zenoh_track.estimation",
                                                    "zenoh_track.wire", "zenoh_track.defaults"}),
    "zenoh_track.tracking": ({"numpy", "scipy", "numba"},
                             {"zenoh_track.tracking", "zenoh_track.estimation",
                              "zenoh_track.wire", "zenoh_track.defaults"}),
    "zenoh_track.adapter": ({"numpy", "zenoh"},
                            {"zenoh_track.adapter", "zenoh_track.tracking",
                             "zenoh_track.estimation", "zenoh_track.wire",
                             "zenoh_track.defaults", "zenoh_track.__version__"}),
    "zenoh_track.clients": ({"numpy", "scipy", "zenoh", "msgpack", "matplotlib", "mcap", "rich",
                             "tqdm", "aiohttp", "pytest", "foxglove", "pymap3d"},
                            {"zenoh_track.wire", "zenoh_track.clients"}),
}
# the folders of the import names (pyproject.toml's package-dir)
PACKAGE_DIR = {"service": "zenoh_track", "clients": "zenoh_track.clients"}


def module_name(path: Path) -> str:
    """The import name of a file of service/ or clients/ (zenoh_track...)."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    parts = [PACKAGE_DIR[parts[0]], *parts[1:]]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> list[str]:
    """Every module the file imports (relative imports resolved), wherever it stands."""
    return imports_of(path, module_name(path))


def imports_of(path: Path, name: str) -> list[str]:
    """Every module the file `path`, of the module `name`, imports."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
                # `from . import x`: x may be a module of the package
                out += [f"{mod}.{a.name}" for a in node.names] if not node.module else [mod]
            else:
                out.append(node.module or "")
    return out


def rule_for(name: str) -> tuple[str, tuple[set[str], set[str]]] | None:
    for prefix, rule in RULES.items():
        if name == prefix or name.startswith(prefix + "."):
            return prefix, rule
    return None


def under(name: str, allowed: set[str]) -> bool:
    return any(name == a or name.startswith(a + ".") for a in allowed)


FILES = sorted(p for d in ("service", "clients") for p in (ROOT / d).rglob("*.py"))


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_follow_the_layers(path: Path) -> None:
    found = rule_for(module_name(path))
    if found is None:  # the programs (zenoh_track.__main__, zenoh_track.router)
        return
    _, (third_party, ours) = found
    bad = []
    for imp in imports(path):
        top = imp.split(".")[0]
        if top in STDLIB:
            continue
        if top == "zenoh_track":
            ok = under(imp, ours) or (imp == "zenoh_track" and "zenoh_track.wire" in ours)
        else:
            ok = top in third_party
        if not ok:
            bad.append(imp)
    assert not bad, f"{path.relative_to(ROOT)} imports {bad}"


def test_the_rules_catch_a_wrong_import(tmp_path: Path) -> None:
    """The checker itself: an estimation module importing tracking is reported."""
    rule = rule_for("zenoh_track.estimation.kalman")
    assert rule is not None
    _, (_, ours) = rule
    assert not under("zenoh_track.tracking.store", ours)
    assert not under("zenoh", ours)
    assert under("zenoh_track.wire", ours)
    assert rule_for("zenoh_track.__main__") is None
    for below in ("zenoh_track.wire", "zenoh_track.estimation", "zenoh_track.tracking"):
        _, (_, allowed) = rule_for(below + ".x")  # type: ignore[misc]
        assert not under("zenoh_track.adapter.worker", allowed), below
    _, (_, adapter) = rule_for("zenoh_track.adapter.worker")  # type: ignore[misc]
    assert under("zenoh_track.tracking.tracker", adapter)
    assert not under("zenoh_track.clients.feeds.feed", adapter)


def test_the_adapter_is_its_own_package() -> None:
    """The adapter's modules live in service/adapter/ (governed above), not beside it:
    service/ holds only the package's root, the defaults and the programs (with the
    service program's allocator set-up, imported before anything starts a thread)."""
    loose = {p.name for p in (ROOT / "service").glob("*.py")}
    assert loose == {"__init__.py", "__main__.py", "defaults.py", "router.py", "malloc.py"}, \
        loose


def test_every_layer_has_files() -> None:
    """The rules are not vacuous: each governed package has modules that were checked."""
    names = {module_name(p) for p in FILES}
    for prefix in RULES:
        assert any(n == prefix or n.startswith(prefix + ".") for n in names), prefix


def test_wire_and_estimation_load_without_zenoh() -> None:
    """In a fresh interpreter: the wire package pulls in neither NumPy nor Zenoh, and the
    estimation and tracking packages do not pull in Zenoh."""
    code = (
        "import sys\n"
        "import zenoh_track.wire\n"
        "assert 'numpy' not in sys.modules and 'zenoh' not in sys.modules, 'wire'\n"
        "import zenoh_track.estimation.filters, zenoh_track.estimation.imm\n"
        "import zenoh_track.estimation.vdf\n"
        "import zenoh_track.tracking.tracker\n"
        "assert 'zenoh' not in sys.modules, 'estimation/tracking'\n"
        "import zenoh_track.__main__\n"
        "assert 'numba' not in sys.modules, 'the kernels load in the background (jit)'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_the_old_import_names_are_gone() -> None:
    """The product installs one top-level package, `zenoh_track`: no module of it, no test
    and no benchmark imports the folders' names `service` or `clients`, and nothing in this
    test session loaded a second copy of the product under those names."""
    old = []
    for path in sorted(p for d in ("service", "clients", "tests", "bench", "fuzz")
                       for p in (ROOT / d).rglob("*.py")):
        name = module_name(path) if path.parts[len(ROOT.parts)] in PACKAGE_DIR else "x.y"
        for imp in imports_of(path, name):
            if imp.split(".")[0] in PACKAGE_DIR:
                old.append(f"{path.relative_to(ROOT)}: {imp}")
    assert not old, old
    assert not set(PACKAGE_DIR) & set(sys.modules), "a second copy under the folders' names"
    assert module_name(ROOT / "clients" / "feeds" / "feed.py") == "zenoh_track.clients.feeds.feed"


def test_clients_are_families() -> None:
    """clients/ holds one sub-package per client family (feeds, display, web, record,
    evaluation, intercept, the library): at its top only the demo, the process helpers and
    the pytest plugin, never another flat module; and every family is installed."""
    top = {p.stem for p in (ROOT / "clients").glob("*.py")}
    assert top == {"__init__", "demo", "pytest_plugin", "pytest_enable"}, top
    families = {p.parent.name for p in (ROOT / "clients").glob("*/__init__.py")}
    text = (ROOT / "pyproject.toml").read_text()
    assert families >= {"feeds", "display", "web", "record", "evaluation", "intercept", "lib"}
    assert all(f'"zenoh_track.clients.{f}"' in text for f in families), families
