"""Geometry shared by the physics world and the sensors.

A :class:`Shape` is one primitive solid placed in the world frame (x forward,
y left, z up; metres). The plant builds the list of shapes from the DART world
(static ones once, robots' every tick); the lidar and the camera cast rays
against that list, so sensors never depend on DART itself.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

KINDS = ("box", "cylinder", "sphere")


@dataclass
class Shape:
    """A primitive solid.

    kind: ``box`` (size = full extents lx, ly, lz), ``cylinder`` (size =
    radius, height; axis along the shape's local z), ``sphere`` (size = radius,).
    pose: 4x4 homogeneous transform shape->world. color: RGB in 0..1.
    owner: the robot name for robot parts, "" for the world.
    """

    kind: str
    size: tuple[float, ...]
    pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    color: tuple[float, float, float] = (0.7, 0.7, 0.7)
    name: str = ""
    owner: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown shape kind {self.kind!r}; expected one of {KINDS}")
        want = {"box": 3, "cylinder": 2, "sphere": 1}[self.kind]
        if len(self.size) != want:
            raise ValueError(f"{self.kind} needs {want} size values, got {len(self.size)}")
        self.pose = np.asarray(self.pose, dtype=float).reshape(4, 4)

    @classmethod
    def placed(cls, kind: str, size: tuple, pose: np.ndarray, color: tuple, name: str,
               owner: str) -> "Shape":
        """A shape whose fields are known good (``pose`` a float64 4x4 array): the plant's
        per-tick robot parts, made without the checks (a fifth of the cost)."""
        s = object.__new__(cls)
        s.kind, s.size, s.pose, s.color, s.name, s.owner = kind, size, pose, color, name, owner
        return s


def pose_matrix(x: float = 0.0, y: float = 0.0, z: float = 0.0,
                roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """4x4 transform from a position and roll-pitch-yaw (rad, applied as Rz*Ry*Rx)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    rot = np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = (x, y, z)
    return m
