"""The house's rules (docs/layout.md), read from the code's own imports: no import circle
between modules, and no import from a lower floor to a higher one or across rooms that
must not see each other (a controller never imports the plant, a bridge never imports
the plant, nothing imports the command line's package); inside diffbot/, its packages by
concern on floors of their own, and children started one way; no module over 500
lines nor function over 80 outside tests; and no issue numbers in code, tests or docs."""
from __future__ import annotations

import ast
import functools
import os
import re
import subprocess

from ..conftest import ROOT

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


@functools.lru_cache(maxsize=1)
def graph() -> dict[str, set[str]]:
    """module -> our modules it imports (read once a session; not to be changed)."""
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


#: diffbot's packages by concern, and which of them each may import (besides itself and the
#: ``diffbot`` package): the runner (child processes, a pool or Ray) is the ground floor, the
#: analysis imports none of them, the environments only the runner (and analysis modules
#: without plots: ENVS_NO_PLOTS), the launch what a run needs, the batch runs and the study
#: the launch; the command line (``cli``) is imported by nothing.
DIFFBOT_MAY_IMPORT = {
    "runner": set(),
    "analysis": set(),
    "envs": {"runner", "analysis"},
    "launch": {"runner", "analysis", "envs"},
    "sweep": {"runner", "analysis", "launch"},
    "study": {"runner", "analysis", "launch"},
    "bench": {"runner", "analysis", "envs", "launch", "sweep", "study"},
    "cli": set(),
}
#: third-party libraries that draw: a module importing one is plotting
PLOTTING = ("matplotlib", "cv2")
#: what may be over the size limits below, each while its owner splits it: drop a line
#: once the split lands
LONG_MODULES: set[str] = set()
LONG_FUNCTIONS: set[str] = set()
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80


def _concern(module: str) -> str | None:
    """The package by concern of a diffbot module (``diffbot.launch.run`` -> ``launch``;
    ``diffbot.cli`` -> ``cli``); None for the ``diffbot`` package itself."""
    parts = module.split(".")
    return parts[1] if parts[0] == "diffbot" and len(parts) > 1 else None


def floor_problems(g: dict[str, set[str]], plotting: set[str]) -> list[str]:
    """Imports between diffbot's packages that their floors do not allow, an import of
    the command line, and an environment importing an analysis module that plots (in
    ``plotting``, or importing one at any depth)."""
    wrong = []
    for n, deps in g.items():
        a = _concern(n)
        for m in deps:
            b = _concern(m)
            if b == "cli":
                wrong.append(f"{n} imports {m}: nothing imports the command line")
            elif a is not None and b is not None and a != b and b not in DIFFBOT_MAY_IMPORT[a]:
                wrong.append(f"{n} imports {m}")
            elif a == "envs" and b == "analysis" and m in plotting:
                wrong.append(f"{n} imports {m}, which plots")
    return sorted(wrong)


def plotting_modules(g: dict[str, set[str]]) -> set[str]:
    """Our modules that import a plotting library, or one of ours that does, at any depth."""
    mods = modules()
    plots = {n for n in g if _third_party(mods[n]) & set(PLOTTING)}
    grew = True
    while grew:
        more = {n for n, deps in g.items() if n not in plots and deps & plots}
        plots |= more
        grew = bool(more)
    return plots


def _third_party(path: str) -> set[str]:
    """The top-level names a file imports (ours too), at any depth of its code."""
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read(), path)
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module.split(".")[0])
    return out


def size_problems(files: dict[str, str]) -> list[str]:
    """Modules over MAX_MODULE_LINES and functions over MAX_FUNCTION_LINES, of ``files``
    (repository path -> source), but for the allowances."""
    wrong = []
    for rel, src in sorted(files.items()):
        lines = len(src.splitlines())
        if lines > MAX_MODULE_LINES and rel not in LONG_MODULES:
            wrong.append(f"{rel}: {lines} lines (at most {MAX_MODULE_LINES})")
        for name, n in _functions(ast.parse(src, rel)):
            if n > MAX_FUNCTION_LINES and rel not in LONG_FUNCTIONS \
                    and f"{rel}:{name}" not in LONG_FUNCTIONS:
                wrong.append(f"{rel}:{name}: {n} lines (at most {MAX_FUNCTION_LINES})")
    return wrong


def _functions(tree: ast.AST, prefix: str = ""):
    """(qualified name, lines) of every function and method of a module."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield prefix + node.name, node.end_lineno - node.lineno + 1
            yield from _functions(node, prefix + node.name + ".")
        elif isinstance(node, ast.ClassDef):
            yield from _functions(node, prefix + node.name + ".")
        else:
            yield from _functions(node, prefix)


def test_diffbots_packages_import_only_lower_floors():
    g = graph()
    wrong = floor_problems(g, plotting_modules(g))
    assert not wrong, "\n".join(wrong)


def test_nothing_loose_at_diffbots_top_but_the_command_line():
    top = {f for f in os.listdir(os.path.join(ROOT, "diffbot")) if f.endswith(".py")}
    assert top <= {"__init__.py", "__main__.py", "cli.py"}, sorted(top)
    dirs = {d for d in os.listdir(os.path.join(ROOT, "diffbot"))
            if os.path.isfile(os.path.join(ROOT, "diffbot", d, "__init__.py"))}
    assert dirs == set(DIFFBOT_MAY_IMPORT) - {"cli"}, sorted(dirs)


@functools.lru_cache(maxsize=1)
def sources() -> dict[str, str]:
    """repository path -> source, of every module of the packages."""
    out = {}
    for path in modules().values():
        with open(path, encoding="utf-8") as f:
            out[os.path.relpath(path, ROOT)] = f.read()
    return out


def test_no_module_over_500_lines_and_no_function_over_80_outside_tests():
    wrong = size_problems(sources())
    assert not wrong, "\n".join(wrong)


def test_the_floor_and_size_checks_can_fail():
    """A made-up env importing the launcher, the command line or a plotting analysis, and a
    long function, are found."""
    g = {"diffbot.envs.x": {"diffbot.launch.launcher", "diffbot.analysis.plots",
                            "diffbot.analysis.bands"},
         "diffbot.analysis.runs": {"diffbot.launch.scenario"},
         "diffbot.launch.y": {"diffbot.cli"}}
    assert floor_problems(g, {"diffbot.analysis.plots"}) == [
        "diffbot.analysis.runs imports diffbot.launch.scenario",
        "diffbot.envs.x imports diffbot.analysis.plots, which plots",
        "diffbot.envs.x imports diffbot.launch.launcher",
        "diffbot.launch.y imports diffbot.cli: nothing imports the command line"]
    body = "".join(f"    x = {i}\n" for i in range(MAX_FUNCTION_LINES))
    src = f"class A:\n    def f(self):\n    {body.replace(chr(10), chr(10) + '    ')}\n"
    assert size_problems({"bus/a.py": src}) == [f"bus/a.py:A.f: {MAX_FUNCTION_LINES + 1} lines "
                                                f"(at most {MAX_FUNCTION_LINES})"]
    assert size_problems({"bus/a.py": "x = 1\n" * (MAX_MODULE_LINES + 1)}) == [
        f"bus/a.py: {MAX_MODULE_LINES + 1} lines (at most {MAX_MODULE_LINES})"]


def popen_users(files: dict[str, str]) -> list[str]:
    """The files of ``files`` (path -> source) that name ``Popen`` or procs' private
    ``_preexec``, but diffbot/runner/procs.py."""
    out = []
    for rel, src in sorted(files.items()):
        if rel == "diffbot/runner/procs.py":
            continue
        for node in ast.walk(ast.parse(src, rel)):
            name = node.attr if isinstance(node, ast.Attribute) else \
                node.id if isinstance(node, ast.Name) else None
            if name in ("Popen", "_preexec"):
                out.append(f"{rel}:{node.lineno}: {name}")
    return out


def test_diffbot_starts_its_children_one_way():
    """In diffbot/, a child that outlives the call is started by diffbot/runner/procs.py
    (Child, or popen for one that keeps this process's output): stop signals reset in the
    child, the kernel's SIGTERM when the parent dies, a stop by PID."""
    wrong = popen_users({p: s for p, s in sources().items() if p.startswith("diffbot/")})
    assert not wrong, "\n".join(wrong)
    assert popen_users({"diffbot/envs/w.py": "import subprocess\nsubprocess.Popen(['x'])\n"}) \
        == ["diffbot/envs/w.py:2: Popen"]


#: the one page that tells a change's history (the benchmarks' log): everywhere else a
#: comment or a doc says the rule and why, and the history stays in the commits
HISTORY_PAGES = {"docs/benchmarks.md"}
ISSUE_NUMBER = re.compile(r"[Ii]ssues? ?#?[0-9]+|issue-[0-9]")


def test_code_tests_and_docs_cite_no_issue_numbers():
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"],
                           cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    wrong = []
    for rel in files:
        name = os.path.basename(rel)
        if rel in HISTORY_PAGES or not (name == "Makefile" or name.endswith(
                (".py", ".md", ".c", ".h", ".toml"))):
            continue
        path = os.path.join(ROOT, rel)
        if not os.path.isfile(path):
            continue
        with open(path, encoding="utf-8", errors="replace") as f:
            for n, line in enumerate(f, 1):
                if ISSUE_NUMBER.search(line):
                    wrong.append(f"{rel}:{n}: {line.strip()}")
    assert not wrong, "say the rule and why instead (the commit keeps the history):\n" \
        + "\n".join(wrong)
