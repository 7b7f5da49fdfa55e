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
        ``within`` = (lo, hi) from ``within_of``."""
        need = FOOTPRINT_RADIUS_M + margin_m
        for _ in range(tries):
            p = rng.uniform(-self.half + need, self.half - need)
            if self.clearance(p) < need:
                continue
            if any(np.hypot(*(p - q)) < away_m for q in avoid):
                continue
            if within is not None:
                q, lo, hi = within
                if not lo <= np.hypot(*(p - q)) <= hi:
                    continue
            return p
        raise RuntimeError("no free point found: the world is too crowded for the robots")
