"""Where a robot may stand and when it touches something, judged on ground truth.

A robot's footprint is the swarm analysis's conservative circle (radius
``FOOTPRINT_RADIUS_M`` round the chassis centre); a *contact* is that circle coming within
``CONTACT_MARGIN_M`` of a wall, of an object that reaches below the robot's top, or of
another robot's footprint. Start poses and goals are drawn where the footprint keeps a
margin from all of them.
"""
from __future__ import annotations

import math

import numpy as np

from diffbot.analysis_swarm import CHASSIS_CENTRE_X_M, CONTACT_MARGIN_M, FOOTPRINT_RADIUS_M
from plant.world import WorldSpec

#: objects whose underside is above this (m) pass over the robot (table tops, the TV)
ROBOT_TOP_M = 0.32


def _bottom(o) -> float:
    z = o.pose[2]
    if o.shape == "box":
        return z - o.size[2] / 2
    if o.shape == "cylinder":
        return z - o.size[1] / 2
    return z - o.size[0]


class Footprints:
    """The static world as the footprint test sees it: boxes, circles and the walls."""

    def __init__(self, spec: WorldSpec) -> None:
        low = [o for o in spec.objects if o.static and _bottom(o) < ROBOT_TOP_M]
        boxes = [o for o in low if o.shape == "box"]
        circles = [o for o in low if o.shape != "box"]
        self.box_c = np.array([o.pose[:2] for o in boxes], float).reshape(-1, 2)
        yaw = np.array([o.pose[3] for o in boxes], float)
        self.box_cos, self.box_sin = np.cos(yaw), np.sin(yaw)
        self.box_half = np.array([o.size[:2] for o in boxes], float).reshape(-1, 2) / 2
        self.circ_c = np.array([o.pose[:2] for o in circles], float).reshape(-1, 2)
        self.circ_r = np.array([o.size[0] for o in circles], float)
        self.half = np.asarray(spec.floor_size_m, float) / 2

    @staticmethod
    def centre(x: float, y: float, yaw: float) -> np.ndarray:
        return np.array([x + CHASSIS_CENTRE_X_M * math.cos(yaw),
                         y + CHASSIS_CENTRE_X_M * math.sin(yaw)])

    def clearance(self, c: np.ndarray) -> float:
        """Distance (m) from point ``c`` to the nearest wall or low object."""
        out = float(np.min(self.half - np.abs(c)))
        if len(self.box_c):
            d = c - self.box_c
            lx = d[:, 0] * self.box_cos + d[:, 1] * self.box_sin
            ly = -d[:, 0] * self.box_sin + d[:, 1] * self.box_cos
            q = np.maximum(np.abs(np.stack([lx, ly], 1)) - self.box_half, 0.0)
            out = min(out, float(np.min(np.hypot(q[:, 0], q[:, 1]))))
        if len(self.circ_c):
            d = np.hypot(*(c - self.circ_c).T) - self.circ_r
            out = min(out, float(np.min(np.maximum(d, 0.0))))
        return out

    def contacts(self, centres: dict[str, np.ndarray]) -> set[str]:
        """The robots (name -> footprint centre) touching a wall, an object or each other."""
        touch = {n for n, c in centres.items()
                 if self.clearance(c) < FOOTPRINT_RADIUS_M + CONTACT_MARGIN_M}
        names = list(centres)
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                if np.hypot(*(centres[a] - centres[b])) < 2 * FOOTPRINT_RADIUS_M + CONTACT_MARGIN_M:
                    touch |= {a, b}
        return touch

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
