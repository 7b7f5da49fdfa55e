"""argparse types for numeric and name options: a bad value is one clear error line and
exit 2.

``--duration -5`` or ``--rate nan`` used to be taken as given and end in a run of zero
ticks (exit 0) or a NaN in ``summary.json``. Every numeric option of the project uses
one of these instead of a bare ``float``/``int``; every robot or node name option one of
:func:`name_arg`, :func:`names_arg` (the checks of :mod:`bus.keys`).
"""
from __future__ import annotations

import argparse
import difflib
import math
from typing import Callable, Iterable

from .keys import check_name, split_names


def _number(kind: type, what: str, ok: Callable[[float], bool]) -> Callable[[str], float]:
    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {'an integer' if kind is int else 'a number'}, got {text!r}") from None
        if not math.isfinite(v) or not ok(v):
            raise argparse.ArgumentTypeError(f"must be {what}, got {text}")
        return v
    parse.__name__ = f"{what} {kind.__name__}"    # argparse names the type in some errors
    return parse


#: > 0 and finite: durations, rates, timeouts, periods
positive_float = _number(float, "a finite number > 0", lambda v: v > 0)
#: >= 0 and finite: delays, grace periods, gains that may be zero
nonneg_float = _number(float, "a finite number >= 0", lambda v: v >= 0)
#: any finite number (speeds that may be negative)
finite_float = _number(float, "a finite number", lambda v: True)
#: >= 1: counts, repeats, jobs
positive_int = _number(int, "an integer >= 1", lambda v: v >= 1)
#: >= 0: seeds
nonneg_int = _number(int, "an integer >= 0", lambda v: v >= 0)
#: a TCP port, 0 for "any free one"
port = _number(int, "a port in 0..65535", lambda v: 0 <= v <= 65535)


def name_arg(what: str) -> Callable[[str], str]:
    """argparse type: a name that is one safe key segment (:func:`bus.keys.check_name`)."""
    def check(value: str) -> str:
        try:
            return check_name(value, what)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    check.__name__ = what
    return check


def names_arg(value: str) -> list[str]:
    """argparse type: comma-separated robot names, each one safe key segment, no repeats
    (:func:`bus.keys.split_names`)."""
    try:
        return split_names(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``choices``, or an empty string."""
    close = difflib.get_close_matches(word, list(choices), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose errors are one line, ``prog: error: reason (see prog --help)``, exit 2,
    like every other input error of the project (the usage block buries the reason)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")
