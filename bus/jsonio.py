"""Strict JSON out: every JSON file or reply the project writes goes through here.

JSON has no NaN or infinity (``json.dumps`` writes them anyway unless told not to, and
strict parsers then reject the file): a non-finite number becomes null, and whoever
produced it says why in a ``*_reason`` key next to it.
"""
from __future__ import annotations

import json
import math
import os

import numpy as np


def write_json(path: str, data: dict) -> None:
    """Write strict JSON atomically (a reader never sees half a file). JSON has no NaN or
    infinity: a non-finite number is written as null (say why in a ``*_reason`` key)."""
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as f:
        json.dump(strict_json(data), f, indent=2, allow_nan=False)
        f.write("\n")
    os.replace(tmp, path)


def read_json(path: str) -> dict:
    """A JSON file's object, or {} if it is missing or not JSON (a process that died
    before it wrote its stats)."""
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return {}


def write_stats(path: str | None, stats: dict | None, log) -> None:
    """A process's ``--stats`` file, written last (after its session closed, so a path it
    cannot write is one logged error, never a hang at exit)."""
    if path and stats is not None:
        try:
            write_json(path, stats)
        except OSError as exc:
            log.error("cannot write --stats %s: %s", path, exc)


def dumps(o, **kw) -> str:
    """``json.dumps`` of :func:`strict_json` ``(o)``, refusing NaN."""
    return json.dumps(strict_json(o), allow_nan=False, **kw)


def strict_json(o):
    """``o`` with numpy values made plain and non-finite floats made None, recursively."""
    if isinstance(o, dict):
        return {k: strict_json(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [strict_json(v) for v in o]
    if isinstance(o, np.ndarray):
        return strict_json(o.tolist())
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if o is None or isinstance(o, (str, int, float, bool)):
        return o
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
