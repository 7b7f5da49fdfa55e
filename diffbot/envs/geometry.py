"""Where a robot may stand and when it touches something, judged on ground truth.

A robot's footprint is the swarm analysis's conservative circle (radius
``FOOTPRINT_RADIUS_M`` round the chassis centre); a *contact* is that circle coming within
``CONTACT_MARGIN_M`` of a wall, of an object that reaches below the robot's top, or of
another robot's footprint. Start poses and goals are drawn where the footprint keeps a
margin from all of them.
"""
from __future__ import annotations

import numpy as np

from plant.footprint import (CONTACT_MARGIN_M, FOOTPRINT_RADIUS_M, ROBOT_TOP_M,  # noqa: F401
                             Footprints as _Static)


#: the candidate points :meth:`Footprints.free_point` tests at once (most calls take the
#: first few)
_BLOCK = 8


class Footprints(_Static):
    """The static world's footprint test (:class:`plant.footprint.Footprints`), with the
    environments' contacts between robots and their free points."""

    def contacts(self, centres: dict[str, np.ndarray]) -> set[str]:
        """The robots (name -> footprint centre) touching a wall, an object or each other."""
        return self.contacts_of([centres])[0]

    def touching(self, centres: np.ndarray) -> np.ndarray:
        """Whether each footprint centre (M, 2) touches a wall or a low object (M,)."""
        return self.clearances(centres) < FOOTPRINT_RADIUS_M + CONTACT_MARGIN_M

    def contacts_of(self, worlds: list[dict[str, np.ndarray]]) -> list[set[str]]:
        """:meth:`contacts` of several worlds' robots (a batch's), the static test of all
        in one call (element by element: each world's answer is its own)."""
        rows = [(k, n) for k, w in enumerate(worlds) for n in w]
        out: list[set[str]] = [set() for _ in worlds]
        if rows:
            pts = np.array([worlds[k][n] for k, n in rows], float).reshape(-1, 2)
            for (k, n), hit in zip(rows, self.touching(pts)):
                if hit:
                    out[k].add(n)
        for w, touch in zip(worlds, out):
            names = list(w)
            for i, a in enumerate(names):
                for b in names[i + 1:]:
                    if np.hypot(*(w[a] - w[b])) < 2 * FOOTPRINT_RADIUS_M + CONTACT_MARGIN_M:
                        touch |= {a, b}
        return out

    def free_point(self, rng: np.random.Generator, margin_m: float, avoid=(),
                   away_m: float = 0.0, within=None, tries: int = 2000) -> np.ndarray:
        """A point whose footprint keeps ``margin_m`` from walls and low objects, ``away_m``
        from each point of ``avoid``, and (if given) lies at a distance in the range
        ``within`` = (lo, hi) from ``within_of``: the first of ``rng``'s uniform draws in
        the room that does, ``rng`` left just after it.

        The draws are tested :data:`_BLOCK` at a time (one call of the clearance kernel, the
        distances as arrays: the same numbers as one by one), and ``rng`` is taken back to
        the state after the one chosen, so it draws what drawing them one by one draws."""
        need = FOOTPRINT_RADIUS_M + margin_m
        low, high = -self.half + need, self.half - need
        made = 0
        while made < tries:
            k = min(_BLOCK, tries - made)
            state = rng.bit_generator.state
            ps = rng.uniform(low, high, (k, 2))
            ok = ~(self.clearances(ps) < need)
            for q in avoid:
                ok &= ~(np.hypot(ps[:, 0] - q[0], ps[:, 1] - q[1]) < away_m)
            if within is not None:
                q, lo, hi = within
                d = np.hypot(ps[:, 0] - q[0], ps[:, 1] - q[1])
                ok &= (lo <= d) & (d <= hi)
            hit = np.flatnonzero(ok)
            if hit.size:
                j = int(hit[0])
                if j + 1 < k:                  # (the draws after it: not made)
                    rng.bit_generator.state = state
                    rng.uniform(low, high, (j + 1, 2))
                return ps[j].copy()
            made += k
        raise RuntimeError("no free point found: the world is too crowded for the robots")
