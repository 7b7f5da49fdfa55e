"""A many-robot controller's scans as one array and its commands as arrays.

A controller that drives many robots on the lidar alone may define, beside ``step_many``,
``step_scans(scans)``: it is handed its robots' latest scans as one :class:`Scans` (a
``(robots, rays)`` array, one row per robot in the robots' order) and returns the robots'
commands as two arrays ``(linear, angular)``, shape ``(robots,)``. Composed into the plant's
process, such a member takes the tick's scans as the plant holds them, one array for all
its robots, instead of one LaserScan message per robot (:class:`ScanRows`); over the bus it
is stepped with ``step_many`` as before. Either way it gets the same values: the ranges
are the float32 values the LaserScan carries, the scan's other fields the floats a decoder
reads, and the stale rule is :func:`bus.observe.observations`'.

``step_many`` itself may also return ``(linear, angular)`` arrays in the observations'
order instead of ``{robot: Twist}`` (:func:`commands_of`).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .controller import Twist
from .observe import STALE_S

#: the mark a member's input buffer holds for a scan filed as a row of a :class:`ScanRows`
#: batch (its lockstep bookkeeping sees the sample; the values are in the batch)
ROW = object()
#: scan batches kept by stamp (the one shown, newer ones)
_KEPT = 4


class Scans(NamedTuple):
    """The latest scans of a controller's robots at tick ``t_ns``: ``ranges`` (robots, rays),
    float32, read-only, row ``i`` robot ``robots[i]``'s (None: no scan yet, or stale), and
    the fields every robot's LaserScan shares (``angle_min`` .. ``range_max``: rad, m)."""
    t_ns: int
    robots: tuple
    ranges: np.ndarray | None
    angle_min: float = 0.0
    angle_max: float = 0.0
    angle_increment: float = 0.0
    time_increment: float = 0.0
    scan_time: float = 0.0
    range_min: float = 0.0
    range_max: float = 0.0


def commands_of(ctrl, out, robots) -> dict:
    """``step_many``'s answer ``out`` as ``{robot: command}``: a dict as it is, or
    ``(linear, angular)`` arrays in the order of ``robots`` as one Twist each."""
    if isinstance(out, dict):
        return out
    v, w = arrays_of(ctrl, out, len(robots), "step_many")
    return dict(zip(robots, map(Twist, v, w)))


def arrays_of(ctrl, out, n: int, method: str) -> tuple[list, list]:
    """``(linear, angular)`` arrays of ``n`` numbers each as two lists of Python floats;
    TypeError (naming ``ctrl``'s ``method``) for anything else."""
    if type(out) is tuple and len(out) == 2:       # (the usual: two float64 arrays of n)
        v, w = out
        if type(v) is type(w) is np.ndarray and v.dtype == w.dtype == np.float64 \
                and v.shape == w.shape == (n,):
            return v.tolist(), w.tolist()
    name = type(ctrl).__name__
    if not isinstance(out, tuple) or len(out) != 2:
        raise TypeError(f"{name}.{method}() returned {type(out).__name__}; expected a dict "
                        "{robot: command} or two arrays (linear, angular)")
    try:
        v, w = (np.asarray(a, dtype=np.float64) for a in out)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name}.{method}(): (linear, angular) are not numbers: {exc}") from None
    if v.shape != (n,) or w.shape != (n,):
        raise TypeError(f"{name}.{method}(): (linear, angular) have shapes {v.shape}, "
                        f"{w.shape}; expected ({n},) each, one per robot")
    return v.tolist(), w.tolist()


class ScanRows:
    """A composed member's scans filed a tick at a time as one array (module docstring).

    Used where the member's robots all share one controller with ``step_scans`` whose only
    input is ``scan``, in lockstep (:meth:`of`). The member's lockstep bookkeeping
    (:meth:`bus.member.MemberTick.next_due`) sees each robot's scan as a :data:`ROW` mark
    in its input buffer; the values stay here, one batch per stamp."""

    def __init__(self, member) -> None:
        self.member = member
        slots = member.slots
        self.ctrl = slots[0].controller
        self.robots = tuple(s.robot for s in slots)
        self.keys = [member.key(r, "scan") for r in self.robots]
        period = slots[0].periods["scan"]
        self.stale_ns = max(STALE_S * 1e9, 3 * period * member.tick_ns)
        self.batches: dict[int, tuple] = {}      # stamp -> (ranges, the scan's fields)
        self._buf = member.buf
        self._at: tuple | None = None            # (plant rows, their positions here)

    @classmethod
    def of(cls, member) -> "ScanRows | None":
        """The member's ScanRows where it may take its scans so (configured), else None."""
        slots = member.slots
        if not slots or not member.sync or member.tick_ns <= 0:
            return None
        ctrl = slots[0].controller
        if not callable(getattr(ctrl, "step_scans", None)):
            return None
        if any(s.controller is not ctrl or s.inputs != ["scan"] or "scan" not in s.periods
               or s.periods["scan"] != slots[0].periods["scan"] for s in slots):
            return None
        if member.lag_ns.get("scan", 0) != 0:
            return None
        return cls(member)

    def file(self, t_ns: int, plant_rows: np.ndarray, ranges: np.ndarray,
             head: tuple, index: dict) -> bool:
        """The plant's scans of tick ``t_ns``: ``ranges`` (rows, rays), row ``j`` the scan of
        the plant's robot ``plant_rows[j]`` (``index``: robot -> plant row), ``head`` the
        LaserScan's fields angle_min .. range_max. Filed as one batch for this member's
        robots (True), or nothing where one of them has no row (False)."""
        at = self._at
        if at is None or at[0] is not plant_rows:
            if at is not None and np.array_equal(at[0], plant_rows):
                at = self._at = (plant_rows, at[1])      # (the same rows, a new array)
            else:
                where = {i: j for j, i in enumerate(plant_rows.tolist())}
                pos = [where.get(index.get(r, -1)) for r in self.robots]
                if None in pos:
                    return False
                same = pos == list(range(len(plant_rows)))
                at = self._at = (plant_rows, None if same else np.array(pos, np.intp))
        mine = ranges if at[1] is None else ranges[at[1]]
        if mine.flags.writeable:
            mine = mine.view()
            mine.flags.writeable = False
        m = self.member
        if m.buf is not self._buf:          # (the member was reset: the old world's go)
            self.batches.clear()
            self._buf = m.buf
        batches = self.batches
        if batches and max(batches) > t_ns:        # (the world went back: the old one's go)
            for s in [s for s in batches if s > t_ns]:
                del batches[s]
        batches[t_ns] = (mine, head)
        if len(batches) > _KEPT:
            del batches[min(batches)]
        bufs = m.buf
        for key in self.keys:
            buf = bufs.get(key)
            if buf is None:
                bufs[key] = {t_ns: ROW}
                continue
            if len(buf) > 1 or (buf and next(iter(buf)) > t_ns):
                for s in [s for s in buf if s > t_ns]:
                    del buf[s]
            buf[t_ns] = ROW
            if len(buf) > 2:
                del buf[min(buf)]
        return True

    def scans(self, t_ns: int) -> Scans:
        """What :func:`bus.observe.observations` shows of the scans at tick ``t_ns``: the
        latest batch stamped at or before it unless stale; the older ones dropped."""
        m = self.member
        if m.buf is not self._buf:
            self.batches.clear()
            self._buf = m.buf
        batches = self.batches
        best = max((s for s in batches if s <= t_ns), default=None)
        if best is None:
            return Scans(t_ns, self.robots, None)
        for s in [s for s in batches if s < best]:
            del batches[s]
        if t_ns - best > self.stale_ns:
            return Scans(t_ns, self.robots, None)
        ranges, head = batches[best]
        return Scans(t_ns, self.robots, ranges, *head)

    def step(self, t_ns: int) -> tuple[list, list]:
        """The controller's ``step_scans`` at ``t_ns``: (linear, angular) as Python floats."""
        ctrl = self.ctrl
        out = ctrl.step_scans(self.scans(t_ns))
        return arrays_of(ctrl, out, len(self.robots), "step_scans")
