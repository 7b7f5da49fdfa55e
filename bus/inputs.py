"""Checks on the samples a node receives: stamps on the tick grid, finite and sane values.

A sample that fails is rejected and counted by the runtime (:mod:`bus.runtime`); a
controller with ``check_inputs = False`` gets the values unchecked.
"""
from __future__ import annotations

import math

import numpy as np

from . import codec
from .controller import WHEEL_JOINTS

#: input values beyond this magnitude are absurd (m, rad, m/s, rad/s ...): rejected
ABSURD_INPUT = 1e9


def stamp_of(msg, tick_ns: int, att: bytes | None = None,
             last_clock: int | None = None) -> tuple[int, str | None]:
    """(stamp in ns, problem or None): stamps must be valid times on the tick grid. A
    message with no header (std_msgs) has the attachment's stamp, or without one the
    last clock tick (it came "now")."""
    if hasattr(msg, "header") or hasattr(msg, "clock"):
        st = msg.header.stamp if hasattr(msg, "header") else msg.clock
        if st.sec < 0 or not 0 <= st.nanosec < 1_000_000_000:
            return 0, f"invalid stamp ({st.sec} s, {st.nanosec} ns)"
        t_ns = codec.stamp_ns(st)
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
    return numbers_problem(msg, "")


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


