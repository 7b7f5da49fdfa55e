"""The lockstep command book's robots kept as arrays: :class:`CommandRows`.

A composed member driving many robots answers a tick with one Twist per robot, all for the
same tick. :class:`plant.commands.CommandBook` files such an answer here in a few array
operations (:meth:`CommandRows.file`), and picks the commands that act at a tick for all
these robots at once (:meth:`CommandRows.pick`), where robot by robot each of them would
be a :class:`plant.commands.Command` in a dict per robot. The rule is the book's: per robot
the commands of its last ``RECENT_TICKS`` tick stamps, one per stamp, the oldest dropped;
the latest filed kept apart. A robot whose commands need anything else (a second command
for a stamp, a wheel command, a command forgotten after its timeout, a look at its
commands one by one) leaves the arrays for the book's dicts with what it has
(:meth:`CommandRows.take_out`), until a member's Twists for it come again as arrays
(:meth:`CommandRows.take_in`).
"""
from __future__ import annotations

import numpy as np

from bus.lockstep import RECENT_TICKS

#: a free slot's stamp (below every stamp: tick stamps are >= 0)
EMPTY = np.iinfo(np.int64).min
_TOP = np.iinfo(np.int64).max


class CommandRows:
    """Twist commands of the robots ``names`` (rows in that order): per robot ``RECENT_TICKS
    + 1`` slots of (stamp, linear, angular, wall time, member), and its latest filed.
    ``inside[i]``: robot i's commands are here (else in the book's dicts)."""

    def __init__(self, names) -> None:
        self.names = tuple(names)
        self.row = {n: i for i, n in enumerate(self.names)}
        R, K = len(self.names), RECENT_TICKS + 1
        self.stamp = np.full((R, K), EMPTY, np.int64)
        self.value = np.zeros((R, K, 2))             # (linear, angular)
        self.wall = np.zeros((R, K))
        self.member = np.zeros((R, K), np.int64)     # index into members
        self.latest = np.zeros((R, 4))               # (linear, angular, wall, member)
        self.latest_t = np.full(R, EMPTY, np.int64)  # EMPTY: none
        self.inside = np.ones(R, bool)
        self.members: list[str | None] = []
        self._member_ix: dict[str | None, int] = {}
        self._all = np.arange(R)

    def member_ix(self, member: str | None) -> int:
        ix = self._member_ix.get(member)
        if ix is None:
            ix = self._member_ix[member] = len(self.members)
            self.members.append(member)
        return ix

    # ------------------------------------------------------------------ filing
    def file(self, rows: np.ndarray, t_ns: int, value: np.ndarray, wall: float,
             member: str | None) -> np.ndarray:
        """File robot ``rows``' commands ``value`` ((n, 2): linear, angular) stamped
        ``t_ns`` from ``member``, received at ``wall``, as the book would one by one; the
        rows it could not (not inside, or holding a command for ``t_ns`` already: the book
        files those one by one) as a bool mask over ``rows``."""
        stamp = self.stamp[rows]
        left = ~self.inside[rows] | (stamp == t_ns).any(axis=1)
        if left.any():
            rows, value = rows[~left], value[~left]
            stamp = stamp[~left]
        if not len(rows):
            return left
        slot = stamp.argmin(axis=1)                  # a free slot (at most RECENT_TICKS used)
        m = self.member_ix(member)
        self.stamp[rows, slot] = t_ns
        self.value[rows, slot] = value
        self.wall[rows, slot] = wall
        self.member[rows, slot] = m
        self.latest_t[rows] = t_ns
        self.latest[rows, :2] = value
        self.latest[rows, 2] = wall
        self.latest[rows, 3] = m
        full = (self.stamp[rows] != EMPTY).sum(axis=1) > RECENT_TICKS
        if full.any():                               # the oldest stamp dropped
            over = rows[full]
            self.stamp[over, self.stamp[over].argmin(axis=1)] = EMPTY   # (argmin: no EMPTY)
        return left

    # ------------------------------------------------------------------ a tick's commands
    def pick(self, upto_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For every robot (rows in order): (whether it has a command for a tick at or before
        ``upto_ns``, the stamp of the latest such, its slot), the older ones dropped: the
        book's ``for_tick`` of each robot inside (a robot outside has none here)."""
        stamp = self.stamp
        at = np.where(stamp <= upto_ns, stamp, EMPTY)
        slot = at.argmax(axis=1)
        best = at[self._all, slot]
        has = best != EMPTY
        old = (stamp < best[:, None]) & (stamp != EMPTY)     # (none past upto_ns)
        if old.any():
            stamp[old] = EMPTY
        return has, best, slot

    def values(self, slot: np.ndarray) -> np.ndarray:
        """(R, 2): every robot's command in ``slot`` (one slot per robot)."""
        return self.value[self._all, slot]

    # ------------------------------------------------------------------ leaving the arrays
    def take_out(self, i: int) -> tuple[dict[int, tuple], tuple | None]:
        """Robot ``i``'s commands, out of the arrays for good: ({stamp: (linear, angular,
        wall, member)} in filing order of stamps, the latest filed or None)."""
        self.inside[i] = False
        kept = {}
        for k in np.argsort(self.stamp[i], kind="stable"):
            t = int(self.stamp[i, k])
            if t != EMPTY:
                kept[t] = self._entry(self.value[i, k], self.wall[i, k], self.member[i, k])
        self.stamp[i] = EMPTY
        latest = None
        if self.latest_t[i] != EMPTY:
            latest = (int(self.latest_t[i]),) + self._entry(
                self.latest[i, :2], self.latest[i, 2], self.latest[i, 3])
            self.latest_t[i] = EMPTY
        return kept, latest

    def take_in(self, i: int, kept: list[tuple], latest: tuple | None) -> None:
        """Robot ``i``'s commands back into the arrays (it has none here): ``kept``, (stamp,
        linear, angular, wall, member) of each (at most ``RECENT_TICKS``); ``latest``, the
        same of the latest filed, or None."""
        self.inside[i] = True
        for k, (t, a, b, w, m) in enumerate(kept):
            self.stamp[i, k] = t
            self.value[i, k] = a, b
            self.wall[i, k] = w
            self.member[i, k] = self.member_ix(m)
        if latest is not None:
            t, a, b, w, m = latest
            self.latest_t[i] = t
            self.latest[i] = a, b, w, self.member_ix(m)

    def forget(self, i: int, upto_ns: int) -> None:
        """Robot ``i``'s commands stamped ``upto_ns`` or before dropped, and its latest if
        it is one of them (the book's ``forget``)."""
        stamp = self.stamp[i]
        stamp[stamp <= upto_ns] = EMPTY
        if self.latest_t[i] <= upto_ns:
            self.latest_t[i] = EMPTY

    def _entry(self, value, wall, member) -> tuple:
        return float(value[0]), float(value[1]), float(wall), self.members[int(member)]

    def clear(self) -> None:
        """No command for anyone; every robot's commands here again."""
        self.stamp[...] = EMPTY
        self.latest_t[...] = EMPTY
        self.inside[...] = True
