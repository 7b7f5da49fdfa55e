"""The house's rules (docs/layout.md), read from the code's own imports: no import circle
between modules, and no import from a lower floor to a higher one or across rooms that
must not see each other (a controller never imports the plant, a bridge never imports
the plant, nothing imports the command line's package)."""
from __future__ import annotations

import ast
import os

from .conftest import ROOT

PACKAGES = ("bus", "plant", "controllers", "fmus", "bridges", "diffbot")
#: which top-level packages each may import (besides itself)
MAY_IMPORT = {
    "bus": set(),
    "plant": {"bus"},
    "controllers": {"bus"},
    "bridges": {"bus"},
    "fmus": {"bus", "plant"},            # the plant exported as an FMU hosts its tick
    "diffbot": {"bus", "plant", "controllers", "fmus", "bridges"},
}


def modules() -> dict[str, str]:
    """module name -> file, every module of the packages."""
    out = {}
    for pkg in PACKAGES:
        for dirpath, _, files in os.walk(os.path.join(ROOT, pkg)):
            for f in files:
                if f.endswith(".py"):
                    rel = os.path.relpath(os.path.join(dirpath, f), ROOT)[:-3]
                    name = rel.replace(os.sep, ".")
                    out[name.removesuffix(".__init__")] = os.path.join(dirpath, f)
    return out


def imports_of(name: str, path: str, known: set[str]) -> set[str]:
    """Our modules ``name`` imports, at any depth of its code (an import inside a function
    is an import too)."""
    is_pkg = path.endswith("__init__.py")
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    out = set()
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read(), path)
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            if node.level:
                mod = ".".join(base[:len(base) - node.level + 1] + ([mod] if mod else []))
            targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def graph() -> dict[str, set[str]]:
    mods = modules()
    known = set(mods)
    return {n: imports_of(n, p, known) for n, p in mods.items()}


def circles(g: dict[str, set[str]]) -> list[list[str]]:
    """The import circles of graph ``g`` (a package's submodule importing the package is
    not one: the package's ``__init__`` runs first)."""
    edges = {n: {m for m in deps if not n.startswith(m + ".")} for n, deps in g.items()}
    state: dict[str, int] = {}
    found = []

    def visit(n: str, path: list[str]) -> None:
        state[n] = 1
        for m in sorted(edges.get(n, ())):
            if state.get(m) == 1:
                found.append(path[path.index(m):] + [m])
            elif m not in state:
                visit(m, path + [m])
        state[n] = 2

    for n in sorted(edges):
        if n not in state:
            visit(n, [n])
    return found


def test_no_import_circle_between_modules():
    found = circles(graph())
    assert not found, "import circles:\n" + "\n".join(" -> ".join(c) for c in found)


def test_no_import_from_a_lower_floor_to_a_higher_one():
    wrong = sorted(f"{n} imports {m}" for n, deps in graph().items() for m in deps
                   if (a := n.split(".")[0]) != (b := m.split(".")[0])
                   and b not in MAY_IMPORT[a])
    assert not wrong, "\n".join(wrong)


def test_the_check_sees_a_circle_and_a_wrong_floor(tmp_path):
    """The two checks above can fail: a made-up pair of modules importing each other, and a
    bus module importing the plant, are found."""
    a = tmp_path / "a.py"
    a.write_text("from plant import tick\nimport bus.b\n")
    assert imports_of("bus.a", str(a), {"bus.a", "bus.b", "plant.tick", "plant"}) == \
        {"plant", "plant.tick", "bus.b"}
    assert "plant" not in MAY_IMPORT["bus"]
    assert circles({"x.a": {"x.b"}, "x.b": {"x.c"}, "x.c": {"x.a"}}) == [["x.a", "x.b", "x.c", "x.a"]]
    assert circles({"x": {"x.a"}, "x.a": {"x"}}) == []
