"""Checks on the samples a node receives: stamps on the tick grid, finite and sane values.

A sample that fails is rejected and counted by the runtime (:mod:`bus.runtime`); a
controller with ``check_inputs = False`` gets the values unchecked.
"""
from __future__ import annotations

import math
from operator import attrgetter, itemgetter

import numpy as np

from . import codec
from .controller import WHEEL_JOINTS
from .made import ZERO_COVARIANCE

#: input values beyond this magnitude are absurd (m, rad, m/s, rad/s ...): rejected
ABSURD_INPUT = 1e9


def stamp_of(msg, tick_ns: int, att: bytes | None = None,
             last_clock: int | None = None) -> tuple[int, str | None]:
    """(stamp in ns, problem or None): stamps must be valid times on the tick grid. A
    message with no header (std_msgs) has the attachment's stamp, or without one the
    last clock tick (it came "now")."""
    head = getattr(msg, "header", None)       # (asked once: every input sample comes here)
    if head is not None or hasattr(msg, "clock"):
        st = head.stamp if head is not None else msg.clock
        sec, nanosec = st.sec, st.nanosec
        if sec < 0 or not 0 <= nanosec < 1_000_000_000:
            return 0, f"invalid stamp ({sec} s, {nanosec} ns)"
        t_ns = int(sec) * 1_000_000_000 + int(nanosec)      # (codec.stamp_ns, inline)
    else:
        a = codec.parse_attachment(att)
        t_ns = a.t_ns if a else (last_clock or 0)
    if tick_ns and t_ns % tick_ns:
        return t_ns, (f"stamp t={t_ns * 1e-9:.9f} s is not on the {tick_ns * 1e-6:g} ms "
                      "tick grid")
    return t_ns, None


#: fields where inf / NaN are legitimate (REP 117: no return) or that are not numbers
_FREE_FIELDS = {"ranges", "intensities", "data"}


def check_input(topic: str, msg) -> str | None:
    """Why an input message is unusable (non-finite or absurd numbers, wrong joint names),
    or None. Laser ranges may be inf or NaN (no return); covariances need only be finite."""
    if topic == "joint_states":
        names = list(msg.name)
        if names != list(WHEEL_JOINTS):
            return f"joint names {names} are not {list(WHEEL_JOINTS)}"
        if len(msg.position) != 2 or len(msg.velocity) not in (0, 2):
            return (f"expected 2 positions (and 0 or 2 velocities), got {len(msg.position)} "
                    f"and {len(msg.velocity)}")
    plan = _PLANS.get(type(msg), _UNKNOWN)
    if plan is _UNKNOWN:
        plan = _PLANS[type(msg)] = _Plan.of(msg)
    if plan is not None and plan.passes(msg):
        return None
    return numbers_problem(msg, "")


_UNKNOWN = object()
#: float arrays up to this size are checked as Python floats (cheaper than numpy's calls)
_SMALL = 64
_PLANS: dict[type, "_Plan | None"] = {}
#: float tuples a plan keeps as passed (values that change every message fill it once)
_PASSED_MAX = 32
#: the Python type rosbags decodes each base type to (the rest: int)
_DECODED = {"float32": float, "float64": float, "string": str, "bool": bool}


class _Plan:
    """What :func:`numbers_problem` looks at in one message type, laid out from the type's
    definition: every leaf it may visit read in one ``attrgetter`` call, with the Python
    type each has in a decoded message. :meth:`passes` is a quick test of a message: True
    only where :func:`numbers_problem` finds nothing (every leaf of its decoded type, the
    floats and float arrays within bounds). Anything else (a message built by hand with
    other types, a value out of bounds) goes to :func:`numbers_problem`, which says what is
    wrong, so the answers are the same."""

    def __init__(self, paths: list[str], types: tuple, arrays: list[tuple[int, bool]]):
        self.get = attrgetter(*paths) if len(paths) > 1 else (lambda m: (attrgetter(*paths)(m),))
        self.types = types
        floats = [i for i, t in enumerate(types) if t is float]
        self.floats = itemgetter(*floats) if len(floats) > 1 else \
            (lambda v: (v[floats[0]],)) if floats else (lambda v: ())
        self.arrays = arrays          # (index, bounded: not a covariance)
        #: a type without float arrays: float values that passed, as a tuple (a lidar's
        #: constants, the same in every scan, are then checked once: a set lookup)
        self.passed: set | None = None if arrays else set()

    @classmethod
    def of(cls, msg) -> "_Plan | None":
        from . import codec
        paths, types, arrays = [], [], []
        try:
            cls._walk(codec.TYPESTORE.fielddefs, msg.__msgtype__, "", paths, types, arrays)
        except (_Unplanned, KeyError, AttributeError):
            return None                    # (lists of messages, types not in the store)
        return cls(paths, tuple(types), arrays) if paths else None

    @classmethod
    def _walk(cls, defs, msgtype: str, where: str, paths, types, arrays) -> None:
        for name, (kind, data) in defs[msgtype][1]:
            if name.startswith("__") or name in _FREE_FIELDS:
                continue
            path = where + name
            if kind == 2:                                     # a nested message
                cls._walk(defs, data, path + ".", paths, types, arrays)
            elif kind == 1:                                   # a base type
                paths.append(path)
                types.append(_DECODED.get(data[0], int))
            elif data[0][0] == 1:                             # an array of a base type
                paths.append(path)
                if data[0][1][0] == "string":
                    types.append(list)
                else:
                    types.append(np.ndarray)
                    if data[0][1][0] in ("float32", "float64"):
                        arrays.append((len(paths) - 1, "covariance" not in name))
            else:
                raise _Unplanned

    def passes(self, msg) -> bool:
        vals = self.get(msg)
        if tuple(map(type, vals)) != self.types:
            return False
        passed = self.passed
        if passed is not None:                     # (no arrays: the floats alone decide)
            got = self.floats(vals)
            if got in passed:                      # (NaN never passes, so never matches)
                return True
            ok = not got or (math.isfinite(sum(got)) and max(got) <= ABSURD_INPUT
                             and min(got) >= -ABSURD_INPUT)
            if ok and len(passed) < _PASSED_MAX:
                passed.add(got)
            return ok
        floats = list(self.floats(vals))
        for i, bounded in self.arrays:
            a = vals[i]
            if a is ZERO_COVARIANCE:               # (read-only zeros: bus/made.py's)
                continue
            if a.size > _SMALL:                    # (numpy's loops pay from here on)
                if not (np.abs(a).max() <= ABSURD_INPUT if bounded else np.isfinite(a).all()):
                    return False                   # ("<=" is False for NaN too)
            elif bounded:
                floats += a.tolist()
            elif not math.isfinite(sum(a.tolist())):   # finite only if every value is
                return False
        # finite only if every value is (a sum that overflows is checked in full)
        return not floats or (math.isfinite(sum(floats)) and max(floats) <= ABSURD_INPUT
                              and min(floats) >= -ABSURD_INPUT)


class _Unplanned(Exception):
    """A message type :class:`_Plan` does not lay out (lists of messages)."""


def numbers_problem(msg, where: str) -> str | None:
    for name in msg.__dataclass_fields__:
        if name.startswith("__") or name in _FREE_FIELDS:
            continue
        v = getattr(msg, name)
        path = f"{where}{name}"
        if isinstance(v, float):
            if not math.isfinite(v) or abs(v) > ABSURD_INPUT:
                return f"{path} = {v!r}"
        elif isinstance(v, np.ndarray):
            if v.dtype.kind == "f" and v.size:
                if not np.isfinite(v).all():
                    return f"{path} is not finite"
                if "covariance" not in name and np.abs(v).max() > ABSURD_INPUT:
                    return f"{path} has absurd values (max |v| {np.abs(v).max():.3g})"
        elif hasattr(v, "__dataclass_fields__"):
            if (p := numbers_problem(v, path + ".")) is not None:
                return p
        elif isinstance(v, list):
            for i, item in enumerate(v):
                if hasattr(item, "__dataclass_fields__") and \
                        (p := numbers_problem(item, f"{path}[{i}].")) is not None:
                    return p
    return None


