"""The lockstep command book's usual commands kept by tick: :class:`CommandRows`.

A composed member driving many robots answers a tick with one Twist per robot, all for the
same tick, and at the tick they act every robot has one for exactly that tick.
:class:`plant.commands.CommandBook` keeps such answers here whole, one page per tick stamp
(:meth:`CommandRows.file`: a few set and list operations, whatever the number of robots),
and hands the tick's commands of all robots over as one array (:meth:`CommandRows.pick`),
where robot by robot each would be a :class:`plant.commands.Command` in a dict per robot.
The rule is the book's (per robot one command per stamp, the older ones dropped once a
newer one acts, its latest kept). Anything else (a second command for a robot's stamp, a
robot without the tick's own command, a command forgotten, a look at one robot's commands)
takes the robots concerned out to the book's dicts with what they have
(:meth:`CommandRows.take_out`), until a member's Twists for them come again
(:meth:`CommandRows.take_in`).
"""
from __future__ import annotations

import itertools

import numpy as np

from bus.lockstep import RECENT_TICKS


class _Batch:
    """One member's Twists for robots ``rows`` (in order) stamped ``t_ns`` (``linear``
    None: a robot's "no latest command")."""
    __slots__ = ("rows", "ix", "t_ns", "linear", "angular", "wall", "member", "seq")

    def __init__(self, rows, t_ns, linear, angular, wall, member, seq, ix=None) -> None:
        self.rows, self.t_ns, self.linear, self.angular = rows, t_ns, linear, angular
        self.wall, self.member, self.seq = wall, member, seq
        self.ix = np.array(rows, np.intp) if ix is None else ix     # (rows, for numpy)

    def entry(self, i: int) -> tuple:
        j = self.rows.index(i)
        return (float(self.linear[j]), float(self.angular[j]), self.wall, self.member)


class CommandRows:
    """Twist commands of the robots ``names`` (rows in that order) filed whole: per stamp a
    page (the rows it holds a command for, its batches), and per set of rows the batch filed
    last (the robots' latest). Robots in :attr:`apart` are kept in the book's dicts."""

    def __init__(self, names) -> None:
        self.names = tuple(names)
        self.row = {n: i for i, n in enumerate(self.names)}
        self.pages: dict[int, tuple[set, list[_Batch]]] = {}
        self.last: dict[frozenset, _Batch] = {}
        self.apart: set[int] = set()
        self._seq = itertools.count()

    # ------------------------------------------------------------------ filing
    def file(self, rows: tuple, rowset: frozenset, t_ns: int, linear, angular, wall: float,
             member: str | None, ix: np.ndarray | None = None) -> bool:
        """File robots ``rows``' commands (``linear[j]``, ``angular[j]``) stamped ``t_ns``
        from ``member``, received at ``wall`` (``rowset``, ``ix``: the rows as a set, as an
        array), as the book would one by one: True; False, with nothing filed, where one of
        them has a command for ``t_ns`` already or is apart, or the book would drop an old
        stamp (then they go one by one)."""
        page = self.pages.get(t_ns)
        if page is None:
            if len(self.pages) >= RECENT_TICKS or not self.apart.isdisjoint(rowset):
                return False
            page = self.pages[t_ns] = (set(), [])
        elif not page[0].isdisjoint(rowset) or not self.apart.isdisjoint(rowset):
            return False
        batch = _Batch(rows, t_ns, linear, angular, wall, member, next(self._seq), ix)
        page[0].update(rowset)
        page[1].append(batch)
        self.last[rowset] = batch
        return True

    # ------------------------------------------------------------------ a tick's commands
    def pick(self, upto_ns: int, value: np.ndarray) -> bool:
        """Where every robot not apart has a command for exactly ``upto_ns`` (or ``upto_ns`` <
        0: none has any): those commands into ``value`` ((R, 2), zero for the others), the
        older ones dropped, True: the book's ``for_tick`` of each of them. Else False, with
        nothing changed."""
        value[...] = 0.0
        if upto_ns < 0:
            return True
        page = self.pages.get(upto_ns)
        if page is None or len(page[0]) + len(self.apart) != len(self.names):
            return False
        for b in page[1]:
            value[b.ix, 0] = b.linear
            value[b.ix, 1] = b.angular
        for t in [t for t in self.pages if t < upto_ns]:
            del self.pages[t]
        return True

    # ------------------------------------------------------------------ robot by robot
    def entries(self, i: int) -> dict[int, tuple]:
        """Robot ``i``'s commands: {stamp: (linear, angular, wall, member)}, by stamp."""
        return {t: next(b for b in reversed(page[1]) if i in b.rows).entry(i)
                for t, page in sorted(self.pages.items()) if i in page[0]}

    def latest(self, i: int) -> tuple | None:
        """Robot ``i``'s latest command filed here: (stamp, linear, angular, wall, member),
        or None."""
        best = None
        for rowset, b in self.last.items():
            if i in rowset and (best is None or b.seq > best.seq):
                best = b
        if best is None or best.linear is None:
            return None
        return (best.t_ns,) + best.entry(i)

    def take_in(self, i: int, kept: dict[int, tuple], latest: tuple | None) -> None:
        """Robot ``i``'s commands from the book's dicts (apart, it has none here): ``kept``
        {stamp: (linear, angular, wall, member)}, ``latest`` (stamp, linear, angular, wall,
        member) or None."""
        self.apart.discard(i)
        for t, (a, b, w, m) in kept.items():
            page = self.pages.setdefault(t, (set(), []))
            page[0].add(i)
            page[1].append(_Batch((i,), t, (a,), (b,), w, m, next(self._seq)))
        t, a, b, w, m = latest if latest is not None else (0, None, None, 0.0, None)
        self.last[frozenset((i,))] = _Batch((i,), t, a if a is None else (a,),
                                            (b,), w, m, next(self._seq))

    def take_out(self, i: int) -> tuple[dict[int, tuple], tuple | None]:
        """Robot ``i``'s commands, out to the book's dicts: (:meth:`entries`, its latest or
        None); it is apart from now on."""
        kept, latest = self.entries(i), self.latest(i)
        for t, page in list(self.pages.items()):
            page[0].discard(i)
            if not page[0]:                  # (nobody's command left on it)
                del self.pages[t]
        self.apart.add(i)
        return kept, latest

    def clear(self) -> None:
        """No command for anyone, nobody apart."""
        self.pages.clear()
        self.last.clear()
        self.apart.clear()
