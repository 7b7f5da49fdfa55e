"""A robot's footprint and the static world as the footprint sees it.

A robot's footprint is a conservative circle: radius :data:`FOOTPRINT_RADIUS_M` round its
chassis box's centre (:data:`CHASSIS_CENTRE_X_M` along its heading from base_link), which
holds the whole 0.40 x 0.26 m box. It meets the walls and every static object that
reaches below the robot's top (:data:`ROBOT_TOP_M`: table tops and the TV pass over it).
The kinematic world stops robots with it (:mod:`plant.kinematic`), the environments judge
contacts with it (:mod:`diffbot.envs.geometry`) and the swarm's analysis counts
collisions with it.
"""
from __future__ import annotations

import math

import numpy as np

from .world import WorldSpec

FOOTPRINT_RADIUS_M = 0.24
CHASSIS_CENTRE_X_M = -0.05
#: two footprints (or a footprint and an obstacle) closer than this touch
CONTACT_MARGIN_M = 0.01
#: objects whose underside is above this (m) pass over the robot (table tops, the TV)
ROBOT_TOP_M = 0.32


def bottom(o) -> float:
    z = o.pose[2]
    if o.shape == "box":
        return z - o.size[2] / 2
    if o.shape == "cylinder":
        return z - o.size[1] / 2
    return z - o.size[0]


def footprint_centres(x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """The footprint centres (..., 2) of robots at base_link poses x, y, yaw (arrays)."""
    out = np.empty(np.shape(x) + (2,))
    out[..., 0] = x + CHASSIS_CENTRE_X_M * np.cos(yaw)
    out[..., 1] = y + CHASSIS_CENTRE_X_M * np.sin(yaw)
    return out


class Footprints:
    """The static world as the footprint test sees it: boxes, circles and the walls."""

    def __init__(self, spec: WorldSpec) -> None:
        low = [o for o in spec.objects if o.static and bottom(o) < ROBOT_TOP_M]
        boxes = [o for o in low if o.shape == "box"]
        circles = [o for o in low if o.shape != "box"]
        self.box_c = np.array([o.pose[:2] for o in boxes], float).reshape(-1, 2)
        yaw = np.array([o.pose[3] for o in boxes], float)
        self.box_cos, self.box_sin = np.cos(yaw), np.sin(yaw)
        self.box_half = np.array([o.size[:2] for o in boxes], float).reshape(-1, 2) / 2
        self.circ_c = np.array([o.pose[:2] for o in circles], float).reshape(-1, 2)
        self.circ_r = np.array([o.size[0] for o in circles], float)
        self.half = np.asarray(spec.floor_size_m, float) / 2
        #: what makes two worlds' footprint tests the same
        self.key = tuple(a.tobytes() for a in (self.box_c, yaw, self.box_half, self.circ_c,
                                                self.circ_r, self.half))
        self._kernel_args: tuple | None = None

    def kernel_args(self) -> tuple:
        """The test's arrays as plant/kernels/kinematic.c takes them (counts and addresses;
        this object keeps the arrays)."""
        if self._kernel_args is None:
            from .kernels import ptr
            self._kernel_args = (len(self.box_c), *map(ptr, (self.box_c, self.box_cos,
                                                               self.box_sin, self.box_half)),
                                 len(self.circ_c), *map(ptr, (self.circ_c, self.circ_r,
                                                                self.half)))
        return self._kernel_args

    @staticmethod
    def centre(x: float, y: float, yaw: float) -> np.ndarray:
        return np.array([x + CHASSIS_CENTRE_X_M * math.cos(yaw),
                         y + CHASSIS_CENTRE_X_M * math.sin(yaw)])

    def clearance(self, c: np.ndarray) -> float:
        """Distance (m) from point ``c`` to the nearest wall or low object."""
        return float(self.clearances(np.asarray(c, float).reshape(1, 2))[0])

    def clearances(self, cs: np.ndarray) -> np.ndarray:
        """:meth:`clearance` of M points ``cs`` (M, 2) at once, (M,): one call of
        plant/kernels/kinematic.c, :meth:`reference_clearances`' arithmetic."""
        from .kernels import clearances
        return clearances(np.ascontiguousarray(cs, np.float64).reshape(-1, 2),
                          self.kernel_args())

    def reference_clearances(self, cs: np.ndarray) -> np.ndarray:
        """:meth:`clearances` in numpy (the kernel's reference: tests/plant/test_kernels.py
        compares them to the bit)."""
        least = np.minimum.reduce          # (np.min without its wrapper: the same minimum)
        out = least(self.half - np.abs(cs), axis=1)
        if len(self.box_c):
            dx = cs[:, 0, None] - self.box_c[:, 0]
            dy = cs[:, 1, None] - self.box_c[:, 1]
            qx = np.maximum(np.abs(dx * self.box_cos + dy * self.box_sin) - self.box_half[:, 0], 0.0)
            qy = np.maximum(np.abs(-dx * self.box_sin + dy * self.box_cos) - self.box_half[:, 1], 0.0)
            out = np.minimum(out, least(np.hypot(qx, qy), axis=1))
        if len(self.circ_c):
            d = np.hypot(cs[:, 0, None] - self.circ_c[:, 0],
                         cs[:, 1, None] - self.circ_c[:, 1]) - self.circ_r
            out = np.minimum(out, least(np.maximum(d, 0.0), axis=1))
        return out
