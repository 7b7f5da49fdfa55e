"""The parameter grid of a sweep: ``--grid KEY=V1,V2`` options (several multiply) and
``--seeds A-B``, turned into one ``diffbot run`` command line per point.

A key is either an option of ``diffbot run`` (:data:`RUN_OPTIONS`: ``coupling``, ``mode``,
``robots``, ...) or a dotted world key that ``diffbot run --set`` takes
(``robots.follower.camera.noise.std``). Values are TOML (``0.5``, ``true``, ``"x"``,
``{std = 10.0}``); a bare word is a string. Commas inside ``{}``, ``[]`` or quotes do not
split values.
"""
from __future__ import annotations

import itertools
import re
from dataclasses import dataclass

from plant.world import tomllib

#: grid keys that are ``diffbot run`` options rather than world keys
RUN_OPTIONS = ("mode", "coupling", "physics", "robots", "controller-processes",
               "physics-process")


@dataclass(frozen=True)
class Axis:
    key: str
    texts: tuple[str, ...]          # the values as typed (what goes on the command line)
    values: tuple                   # parsed (what goes in the table)


def split_values(text: str) -> list[str]:
    """``0,10,{a = 1, b = 2}`` -> ``['0', '10', '{a = 1, b = 2}']``."""
    out, depth, quote, cur = [], 0, "", ""
    for ch in text:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(cur.strip())
            cur = ""
            continue
        cur += ch
    out.append(cur.strip())
    return out


def parse_value(text: str):
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_axis(item: str) -> Axis:
    key, sep, rest = item.partition("=")
    key = key.strip()
    if not sep or not key or not rest.strip():
        raise ValueError(f"--grid {item!r}: expected KEY=V1,V2,...")
    if key.replace("_", "-") not in RUN_OPTIONS and "." not in key:
        raise ValueError(f"--grid {item!r}: {key!r} is neither a `diffbot run` option "
                         f"({', '.join(RUN_OPTIONS)}) nor a dotted world key "
                         "(e.g. robots.robot1.motion.command_noise_std_radps)")
    texts = split_values(rest)
    if any(not t for t in texts):
        raise ValueError(f"--grid {item!r}: an empty value")
    if len(set(texts)) != len(texts):
        raise ValueError(f"--grid {item!r}: a value given twice")
    return Axis(key, tuple(texts), tuple(parse_value(t) for t in texts))


def parse_seeds(text: str) -> list[int]:
    """``0-3`` -> 0,1,2,3; ``5`` -> 5; ``1,4,9`` -> those."""
    seeds: list[int] = []
    for part in text.split(","):
        m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        if not m:
            raise ValueError(f"--seeds {text!r}: expected A-B, A or A,B,C (non-negative)")
        a, b = int(m.group(1)), int(m.group(2) or m.group(1))
        if b < a:
            raise ValueError(f"--seeds {text!r}: empty range {part.strip()!r}")
        seeds += [s for s in range(a, b + 1) if s not in seeds]
    return seeds


@dataclass(frozen=True)
class Point:
    """One run of the sweep: a value per axis and a seed."""
    texts: tuple[str, ...]
    values: tuple
    seed: int

    def run_id(self, axes: list[Axis]) -> str:
        parts = [f"{a.key}={t}" for a, t in zip(axes, self.texts)] + [f"seed={self.seed}"]
        return re.sub(r"[^A-Za-z0-9._=+-]", "_", ",".join(parts))

    def run_args(self, axes: list[Axis]) -> list[str]:
        """The ``diffbot run`` options this point adds."""
        out: list[str] = ["--seed", str(self.seed)]
        for a, t in zip(axes, self.texts):
            opt = a.key.replace("_", "-")
            if opt in RUN_OPTIONS:
                if opt == "physics-process":
                    out.append("--physics-process" if parse_value(t) in (True, "true", "on")
                               else "--no-physics-process")
                else:
                    out += [f"--{opt}", t]
            else:
                out += ["--set", f"{a.key}={t}"]
        return out


def points(axes: list[Axis], seeds: list[int]) -> list[Point]:
    out = []
    for combo in itertools.product(*[list(zip(a.texts, a.values)) for a in axes]):
        for seed in seeds:
            out.append(Point(tuple(t for t, _ in combo), tuple(v for _, v in combo), seed))
    return out
