"""TOML files read with a line per mistake: world files (:mod:`plant.world`), scenario
files (diffbot/launch/scenario.py) and FMU mapping files (fmus/mapping.py) alike. Every error is
``file:key: reason`` (:class:`WorldError`, or the error type the reader names), so the
command line can print it as one line and exit 2."""
from __future__ import annotations

import math
import os
import re

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

from bus.cliargs import did_you_mean


_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


class WorldError(ValueError):
    """A world or scenario file that cannot be used; the message is ``file:key: reason``."""


def read_toml(path: str, error: type[ValueError] = WorldError) -> dict:
    """The TOML file at ``path``, or ``error`` naming the file and what is wrong."""
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror}") from None


def shipped_or_path(name_or_path: str, folder: str, what: str, listed: str = "shipped") -> str:
    """``name_or_path`` if it is a file, else the shipped ``folder/<name>.toml``, else
    WorldError ``NAME: no such <what> (did you mean ...?) (<listed>: a, b, ...)``."""
    if os.path.isfile(name_or_path):
        return name_or_path
    shipped = os.path.join(folder, f"{name_or_path}.toml")
    if os.path.isfile(shipped):
        return shipped
    names = sorted(f[:-5] for f in os.listdir(folder) if f.endswith(".toml"))
    raise WorldError(f"{name_or_path}: no such {what}{did_you_mean(name_or_path, names)} "
                     f"({listed}: {', '.join(names)})")


class Table:
    """Typed access to one TOML table that remembers which keys were read; its mistakes
    (and its sub-tables') are ``error`` (WorldError unless the reader names another)."""

    def __init__(self, path: str, where: str, data: dict,
                 error: type[ValueError] = WorldError) -> None:
        self.path, self.where, self.data, self.error = path, where, data, error
        if not isinstance(data, dict):
            self.fail("", f"expected a table, got {type(data).__name__}")
        self.used: set[str] = set()

    def key(self, k: str) -> str:
        if not _BARE_KEY.match(str(k)):        # quoted TOML keys: "a b", "x\ny" (one line)
            k = repr(k)
        return f"{self.where}.{k}" if self.where else k

    def fail(self, k: str, reason: str):
        raise self.error(f"{self.path}:{self.key(k) if k else self.where}: {reason}")

    def has(self, k: str) -> bool:
        return k in self.data

    def raw(self, k: str, default=None):
        self.used.add(k)
        return self.data.get(k, default)

    def number(self, k: str, default=None, *, positive=False, nonneg=False, required=False) -> float:
        self.used.add(k)
        if k not in self.data:
            if required or default is None:
                self.fail(k, "missing (a number is required)")
            return default
        v = self.raw(k)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(k, f"expected a number, got {type(v).__name__} {v!r}")
        v = float(v)
        if not math.isfinite(v):
            self.fail(k, f"must be finite, got {v}")
        if positive and v <= 0:
            self.fail(k, f"must be > 0, got {v:g}")
        if nonneg and v < 0:
            self.fail(k, f"must be >= 0, got {v:g}")
        return v

    def integer(self, k: str, default: int) -> int:
        v = self.raw(k, default)
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(k, f"expected an integer, got {type(v).__name__} {v!r}")
        return v

    def string(self, k: str, default=None, choices=None, *, nonempty=False) -> str:
        self.used.add(k)
        if k not in self.data and default is None:
            self.fail(k, "missing (a string is required)")
        v = self.raw(k, default)
        if not isinstance(v, str):
            self.fail(k, f"expected a string, got {type(v).__name__} {v!r}")
        if nonempty and not v and k in self.data:
            self.fail(k, "expected a non-empty string, got ''")
        if choices and v not in choices:
            self.fail(k, f"must be one of {', '.join(choices)}, got {v!r}"
                         f"{did_you_mean(v, choices)}")
        return v

    def boolean(self, k: str, default: bool) -> bool:
        v = self.raw(k, default)
        if not isinstance(v, bool):
            self.fail(k, f"expected true or false, got {v!r}")
        return v

    def vector(self, k: str, n: int | tuple[int, ...], default=None, *, positive=False,
               unit_range=False) -> tuple[float, ...]:
        self.used.add(k)
        if k not in self.data:
            if default is None:
                self.fail(k, "missing")
            return tuple(default)
        v = self.raw(k)
        ns = (n,) if isinstance(n, int) else n
        if not isinstance(v, list) or len(v) not in ns or any(
                isinstance(x, bool) or not isinstance(x, (int, float)) for x in v):
            want = " or ".join(str(i) for i in ns)
            self.fail(k, f"expected a list of {want} numbers, got {v!r}")
        v = tuple(float(x) for x in v)
        if not all(math.isfinite(x) for x in v):
            self.fail(k, f"values must be finite, got {v}")
        if positive and any(x <= 0 for x in v):
            self.fail(k, f"values must be > 0, got {list(v)}")
        if unit_range and any(x < 0 or x > 1 for x in v):
            self.fail(k, f"colour components must be in 0..1, got {list(v)}")
        return v

    def table(self, k: str) -> "Table":
        return Table(self.path, self.key(k), self.raw(k, {}), self.error)

    def tables(self, k: str) -> list["Table"]:
        v = self.raw(k, [])
        if not isinstance(v, list):
            self.fail(k, f"expected an array of tables ([[{k}]]), got {type(v).__name__}")
        return [Table(self.path, f"{self.key(k)}[{i}]", item, self.error)
                for i, item in enumerate(v)]

    def done(self, known: tuple[str, ...] = ()) -> None:
        """Refuse keys nobody asked for (typos), suggesting the closest one read or
        ``known`` (else listing ``known``: the keys the table may hold)."""
        for k in self.data:
            if k not in self.used:
                hint = did_you_mean(k, sorted(self.used | set(known)))
                if not hint and known:
                    hint = f" (known: {', '.join(known)})"
                self.fail(k, f"unknown key{hint}")
