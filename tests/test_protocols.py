"""The tracker is given its parts and uses only what their protocols declare
(`tracking/protocols.py`), and nothing sets a part on a component after its construction.
Both are read from the source: every `self.<part>.<name>` in `Tracker`, every call the
adapter makes through the tracker, and every attribute assignment in the product."""

from __future__ import annotations

import ast
import dataclasses
import inspect
from pathlib import Path

from zenoh_track.tracking import protocols
from zenoh_track.tracking.tracker import Tracker

ROOT = Path(__file__).resolve().parent.parent
SERVICE = ROOT / "service"


def members(proto: type) -> set[str]:
    """The names a protocol declares (its own and its bases')."""
    out: set[str] = set()
    for cls in proto.__mro__:
        if cls.__module__ != protocols.__name__:
            continue
        out |= {n for n in vars(cls) if not n.startswith("_")}
        out |= set(getattr(cls, "__annotations__", {}))
    return out


def tracker_parts() -> dict[str, type]:
    """Each attribute `Tracker.__init__` annotates with a protocol: name -> protocol."""
    tree = ast.parse(inspect.getsource(Tracker))
    init = next(n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)
                and n.name == "__init__")
    out = {}
    for node in ast.walk(init):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Attribute) \
                and isinstance(node.annotation, ast.Name) \
                and hasattr(protocols, node.annotation.id):
            out[node.target.attr] = getattr(protocols, node.annotation.id)
    return out


def uses(tree: ast.AST, owner: str, parts: dict[str, type]) -> list[tuple[str, str, int]]:
    """Every `<owner>.<part>.<name>` in `tree` (owner: the attribute holding the tracker,
    or `self` inside it): (part, name, line)."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute) \
                and node.value.attr in parts:
            base = node.value.value
            name = base.attr if isinstance(base, ast.Attribute) else getattr(base, "id", "")
            if name == owner:
                out.append((node.value.attr, node.attr, node.lineno))
    return out


def test_the_tracker_is_given_every_part_and_calls_only_what_its_protocol_declares():
    parts = tracker_parts()
    assert {"updater", "associator", "scan_associator", "initiator", "deleter", "life",
            "display", "noise"} <= set(parts)
    params = set(inspect.signature(Tracker.__init__).parameters)
    assert {"filter", "associator", "scan_associator", "initiator", "deleter", "life",
            "display", "noise"} <= params  # given, not built inside
    found = uses(ast.parse(inspect.getsource(Tracker)), "self", parts)
    assert found, "the reader found no calls: it reads nothing"
    wrong = [(p, n, line) for p, n, line in found if n not in members(parts[p])]
    assert not wrong, f"calls on parts that their protocols do not declare: {wrong}"


def test_the_adapter_reaches_the_tracker_through_its_own_methods_and_declared_parts():
    parts = tracker_parts()
    public = {n for n in dir(Tracker) if not n.startswith("_")} | set(parts) | {"store"}
    checked = 0
    for path in sorted((SERVICE / "adapter").glob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute) \
                    and node.value.attr == "tracker":
                checked += 1
                assert node.attr in public, f"{path.name}:{node.lineno}: tracker.{node.attr}"
        for part, name, line in uses(tree, "tracker", parts):
            assert name in members(parts[part]), f"{path.name}:{line}: {part}.{name}"
        for node in ast.walk(tree):  # nothing three levels into the tracker
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute) \
                    and isinstance(node.value.value, ast.Attribute) \
                    and node.value.value.attr == "tracker" and node.value.attr != "noise":
                raise AssertionError(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
    assert checked, "the reader found no use of the tracker in the adapter"


def part_names() -> set[str]:
    """The constructor parameters of the product's parts (its classes that are not
    records): the names of what a component is given."""
    import importlib
    import pkgutil

    import zenoh_track

    records: set[str] = set()
    given: set[str] = set()
    for mod in pkgutil.walk_packages(zenoh_track.__path__, "zenoh_track."):
        if ".clients" in mod.name or mod.name.endswith("__main__"):
            continue
        module = importlib.import_module(mod.name)
        for _, cls in inspect.getmembers(module, inspect.isclass):
            if cls.__module__ != module.__name__:
                continue
            if dataclasses.is_dataclass(cls):
                records |= {f.name for f in dataclasses.fields(cls)}
            elif "__init__" in vars(cls):
                given |= set(inspect.signature(cls.__init__).parameters) - {"self"}
    return given - records


def test_no_part_is_set_on_a_component_after_its_construction():
    """An assignment `<something>.<part> = ...` outside the object's own `self` (and
    outside its own class's constructors) would patch a component: none in service/ or
    tests/."""
    names = part_names() | set(tracker_parts()) | {"store"}
    assert {"predict", "stages", "updater", "scan_associator", "reach"} <= names
    bad = []
    for path in sorted([*SERVICE.rglob("*.py"), *(ROOT / "tests").rglob("*.py")]):
        tree = ast.parse(path.read_text())
        for cls_node in [tree, *[n for n in ast.walk(tree) if isinstance(n, ast.ClassDef)]]:
            for node in ast.walk(cls_node):
                targets = node.targets if isinstance(node, ast.Assign) else \
                    [node.target] if isinstance(node, ast.AnnAssign | ast.AugAssign) else []
                for t in targets:
                    for el in t.elts if isinstance(t, ast.Tuple) else [t]:
                        if not isinstance(el, ast.Attribute) or el.attr not in names:
                            continue
                        own = isinstance(el.value, ast.Name) and el.value.id in ("self", "cls")
                        if not own and isinstance(cls_node, ast.Module):
                            bad.append(f"{path.relative_to(ROOT)}:{el.lineno}: "
                                       f"{ast.unparse(el)}")
    made_here = {"gating.py"}  # `Gating.cut` builds a new Gating without __init__
    bad = [b for b in set(bad) if Path(b.split(":")[0]).name not in made_here]
    assert not bad, "parts set after construction:\n" + "\n".join(sorted(bad))
