"""How the plant FMU's binary finds and loads diffbot-cosim in a Python it does not own.

The FMU carries this file as ``resources/plant_guest.py``; its C shim (fmus/plant_wrapper/)
uses it twice:

- **as a script**, run by the Python the shim has chosen when its host process has no
  Python of its own (a C master): ``python plant_guest.py RESOURCES`` prints, one
  ``key=value`` a line, what that Python is (``executable``, ``version``, ``libpython``
  to load, ``home``), where diffbot-cosim is installed (``root``, ``package_version``),
  that Python's import path (``path=`` lines), and an ``error=`` line for each thing that is
  missing, so that the shim says what it found and what is missing before it loads anything;
- **as the guest loader**, compiled by the shim into a namespace of its own (never the
  host's ``__main__``): :func:`load` returns a :class:`Guest`, through which every FMI call
  reaches :mod:`fmus.plant_fmu`.

A guest in its host's Python: the package's top-level modules (``plant``, ``bus``,
``fmus``, ...) come from the installed distribution's folder only, and are in
``sys.modules`` only while an FMI call runs. The host's own modules of those names (a
``plant.py`` beside its script) are put aside during the call and back after it, so neither
shadows the other; ``sys.path`` is only ever appended to (the chosen Python's import path,
in a host without Python). Third-party packages (numpy, dartpy) are shared with the host:
a host that runs Python must have diffbot-cosim's dependencies importable in its own
environment, in versions diffbot-cosim supports.

Only the standard library is imported here at module level.
"""
from __future__ import annotations

import importlib
import importlib.machinery
import importlib.metadata
import json
import os
import sys
import sysconfig

DIST = "diffbot-cosim"
#: the distribution's top-level packages (pyproject.toml)
NAMES = frozenset({"bus", "plant", "controllers", "fmus", "bridges", "diffbot"})
MIN_PYTHON = (3, 10)


def read_cfg(resources: str) -> dict[str, str]:
    """resources/plant.cfg as a dict (``key=value`` lines)."""
    out = {}
    with open(os.path.join(resources, "plant.cfg"), encoding="utf-8") as f:
        for line in f:
            key, eq, value = line.rstrip("\r\n").partition("=")
            if eq:
                out[key] = value
    return out


def compatible(installed: str, exported: str) -> bool:
    """The FMU runs on the package version it was exported with, or a later one of the same
    release series: the same major and minor number (0.1.x for 0.1.0)."""
    return installed.split(".")[:2] == exported.split(".")[:2]


def locate(search: list[str] | None = None) -> tuple[str, str]:
    """(the folder holding the installed package's top-level packages, its version), looked
    up in ``search`` (default sys.path); LookupError saying what is missing."""
    try:
        dist = importlib.metadata.distribution(DIST) if search is None else next(
            iter(importlib.metadata.distributions(name=DIST, path=search)))
    except (importlib.metadata.PackageNotFoundError, StopIteration):
        raise LookupError(f"{DIST} is not installed in this Python") from None
    roots = []
    direct = dist.read_text("direct_url.json")
    if direct:                                 # an editable install: the clone's folder
        info = json.loads(direct)
        if info.get("dir_info", {}).get("editable") and info.get("url", "").startswith("file://"):
            from urllib.parse import unquote, urlparse
            roots.append(unquote(urlparse(info["url"]).path))
    roots.append(str(dist.locate_file("")))
    for root in roots:
        if os.path.isfile(os.path.join(root, "fmus", "plant_fmu.py")):
            return os.path.abspath(root), dist.version
    raise LookupError(f"{DIST} {dist.version} is installed but its fmus/plant_fmu.py is not in "
                      f"{' or '.join(roots)}")


def query(resources: str) -> list[str]:
    """The lines the script prints (module docstring)."""
    search = [p for p in sys.path if p and os.path.abspath(p) not in
              (os.getcwd(), os.path.dirname(os.path.abspath(__file__)))]
    lines = [f"executable={sys.executable}", f"version={sys.version.split()[0]}",
             f"home={sys.base_prefix}"]
    if sys.version_info[:2] < MIN_PYTHON:
        lines.append(f"error=Python {sys.version.split()[0]} is older than "
                     f"{'.'.join(map(str, MIN_PYTHON))}")
    libdir = sysconfig.get_config_var("LIBDIR") or ""
    soname = sysconfig.get_config_var("INSTSONAME") or sysconfig.get_config_var("LDLIBRARY") or ""
    libpython = os.path.join(libdir, soname) if soname else ""
    if not sysconfig.get_config_var("Py_ENABLE_SHARED") or not os.path.isfile(libpython):
        lines.append(f"error=this Python has no shared library libpython ({libpython or soname} "
                     "missing; a Python built with --enable-shared has it) to load into the host")
    else:
        lines.append(f"libpython={libpython}")
    try:
        root, version = locate(search)
        exported = read_cfg(resources).get("package_version", "")
        lines += [f"root={root}", f"package_version={version}"]
        if exported and not compatible(version, exported):
            lines.append(f"error={DIST} {version} is installed there; this FMU was exported "
                         f"with {exported} and needs {'.'.join(exported.split('.')[:2])}.x")
    except LookupError as e:
        lines.append(f"error={e}")
    lines += [f"path={p}" for p in search]
    return lines


class _Finder:
    """A meta path finder that takes the package's top-level names from its folder only."""

    def __init__(self, root: str) -> None:
        self.root = root

    def find_spec(self, name, path=None, target=None):
        if path is None and name in NAMES:
            return importlib.machinery.PathFinder.find_spec(name, [self.root])
        return None


class Guest:
    """diffbot-cosim's modules, in ``sys.modules`` only within ``with guest:``."""

    def __init__(self, root: str, version: str) -> None:
        self.root, self.version = root, version
        self.finder = _Finder(root)
        self.ours: dict[str, object] = {}      # our modules, while outside a call
        self.host: dict[str, object] = {}      # the host's modules of our names, within one
        self.depth = 0
        self._swapped = False
        with self:
            self.plant_fmu = importlib.import_module("fmus.plant_fmu")

    @staticmethod
    def _ours(name: str) -> bool:
        return name.partition(".")[0] in NAMES

    def __enter__(self) -> "Guest":
        self.depth += 1
        # (a host that frees the FMU while its interpreter shuts down has no sys.meta_path
        # any more: the call then runs with the modules as they are)
        if self.depth == 1 and isinstance(sys.meta_path, list) and isinstance(sys.modules, dict):
            mods = sys.modules
            if not NAMES.isdisjoint(mods):     # the host has modules of our names: aside
                self.host = {k: mods.pop(k) for k in [k for k in mods if self._ours(k)]}
            mods.update(self.ours)
            sys.meta_path.insert(0, self.finder)
            self._count = len(mods)
            self._swapped = True
        return self

    def __exit__(self, *exc) -> None:
        self.depth -= 1
        if self.depth or not self._swapped:
            return
        self._swapped = False
        mods = sys.modules
        try:
            sys.meta_path.remove(self.finder)
        except (ValueError, AttributeError):
            pass
        if len(mods) != self._count:           # modules were imported: ours among them?
            self.ours.update((k, m) for k, m in list(mods.items()) if self._ours(k))
        for k in self.ours:
            mods.pop(k, None)
        mods.update(self.host)
        self.host = {}

    def instantiate(self, fmi: int, resources: str, name: str, token: str) -> "Instance":
        exported = read_cfg(resources).get("package_version", "")
        if exported and not compatible(self.version, exported):
            raise LookupError(f"this process runs {DIST} {self.version} (from {self.root}); "
                              f"this FMU was exported with {exported} and needs "
                              f"{'.'.join(exported.split('.')[:2])}.x")
        with self:
            return Instance(self, self.plant_fmu.instantiate(fmi, resources, name, token))


class Instance:
    """An FMI instance whose every method call runs within its guest (``with guest:``)."""

    __slots__ = ("_guest", "_instance")

    def __init__(self, guest: Guest, instance) -> None:
        self._guest, self._instance = guest, instance

    def __getattr__(self, name: str):
        method = getattr(self._instance, name)
        guest = self._guest

        def call(*args):
            with guest:
                return method(*args)
        return call


def load(resources: str, query_text: str) -> Guest:
    """The guest for this process. ``query_text``: the script's output when the shim started
    the Python it chose (its import path is appended to sys.path), "" in a host that runs
    Python (the package is looked up on the host's own sys.path). LookupError/ImportError
    say what is missing."""
    cfg = read_cfg(resources)
    exported = cfg.get("package_version", "")
    found = [line.partition("=")[::2] for line in query_text.splitlines()]
    for key, value in found:
        if key == "path" and value not in sys.path:
            sys.path.append(value)
    where = dict(found).get("executable") or f"the host's Python ({sys.executable or '?'})"
    if sys.version_info[:2] < MIN_PYTHON:
        raise LookupError(f"{where} is Python {sys.version.split()[0]}: the plant FMU needs "
                          f"{'.'.join(map(str, MIN_PYTHON))} or later")
    try:
        root, version = locate([p for p in sys.path if p and os.path.abspath(p) != os.getcwd()])
    except LookupError as e:
        raise LookupError(f"{e} ({where}, Python {sys.version.split()[0]}): install it there "
                          f"(pip install '{DIST}=={'.'.join(exported.split('.')[:2])}.*' or its "
                          "wheel), or name another Python in DIFFBOT_FMU_PYTHON") from None
    if exported and not compatible(version, exported):
        raise LookupError(f"{DIST} {version} is installed in {where}; this FMU was exported with "
                          f"{exported} and needs {'.'.join(exported.split('.')[:2])}.x")
    return Guest(root, version)


if __name__ == "__main__":
    print("\n".join(query(sys.argv[1] if len(sys.argv) > 1 else ".")))
