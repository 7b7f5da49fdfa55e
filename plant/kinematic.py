"""The kinematic world (``world.mode = "kinematic"``): ideal unicycles stopped by their footprints.

No physics engine steps a kinematic robot. Each control tick it moves along the exact arc
of the (v, w) its wheel speeds give (``v = r (wr + wl) / 2``, ``w = r (wr - wl) / d``,
held for the tick: the drive limiter's ramps and the command noise act on the wheel
speeds before, as in the dynamic world). Its footprint (:mod:`plant.footprint`: a 0.24 m
circle round the chassis centre) stops it: a move that would bring the footprint within
the radius of a wall or a low object, or within two radii of another robot's footprint of
the same world, while coming closer, is not made; the robot stays where it was for that
tick, reports no velocity, and its wheels still turn (the encoders see them spin, as a
robot pushing a wall). Moving away from or along an obstacle is always allowed, so a
robot that touched one can leave.

:class:`Kinematics` holds one world's robots as arrays; :func:`join` lays several worlds'
robots (a batched environment's N copies of a world) in one set of arrays and steps them
all with one call of the same arithmetic, so each world moves to the bit as it would
alone (every operation is element by element; the robot-robot test pairs robots of the
same world only).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from . import kernels
from .footprint import CHASSIS_CENTRE_X_M, FOOTPRINT_RADIUS_M, Footprints, footprint_centres
from .world import WorldSpec

_FIELDS = ("pose", "wheels", "speeds", "vel", "radius", "separation", "world")


class Kinematics:
    """One world's robots (in ``spec.robots`` order): pose (x, y, yaw), wheel angles and
    speeds, body velocity (v, w) of the last tick, and the footprint test."""

    def __init__(self, spec: WorldSpec) -> None:
        n = len(spec.robots)
        self.names = [r.name for r in spec.robots]
        self.pose = np.array([r.pose for r in spec.robots], float).reshape(n, 3)
        self.wheels = np.zeros((n, 2))
        self.speeds = np.zeros((n, 2))
        self.vel = np.zeros((n, 2))
        self.radius = np.array([r.drive.wheel_radius_m for r in spec.robots], float)
        self.separation = np.array([r.drive.wheel_separation_m for r in spec.robots], float)
        self.world = np.zeros(n, np.int64)
        self.tick_s = spec.control_tick_s
        self.foot = Footprints(spec)
        self.batch: _Batch | None = None
        self._kernel_args: tuple | None = None     # step_arrays': the arrays' addresses

    def __len__(self) -> int:
        return len(self.names)

    def restart(self, spec: WorldSpec) -> None:
        """Back at rest at ``spec``'s start poses, as ``Kinematics(spec)`` would be (in place:
        a batch holding these arrays keeps them)."""
        self.pose[:] = np.array([r.pose for r in spec.robots], float).reshape(-1, 3)
        for a in (self.wheels, self.speeds, self.vel):
            a[:] = 0.0

    def step(self, targets: np.ndarray) -> None:
        """One control tick with the wheel-speed targets (n, 2) (rad/s, left, right)."""
        step_arrays(self, np.asarray(targets, float).reshape(-1, 2))

    def transforms(self) -> np.ndarray:
        """base_link -> world of every robot, (n, 4, 4) (base_link at the axle's height)."""
        pose, radius = self.pose, self.radius
        n = len(pose)
        yaw = pose[:, 2]
        c, s = np.cos(yaw), np.sin(yaw)
        tf = np.zeros((n, 4, 4))
        tf[:, 0, 0], tf[:, 0, 1], tf[:, 0, 3] = c, -s, pose[:, 0]
        tf[:, 1, 0], tf[:, 1, 1], tf[:, 1, 3] = s, c, pose[:, 1]
        tf[:, 2, 2], tf[:, 2, 3], tf[:, 3, 3] = 1.0, radius, 1.0
        return tf

    def finite(self) -> bool:
        """Whether every robot's pose and wheel angles are finite (one robot: Python floats,
        a fifth of the time of numpy's two reductions)."""
        if len(self.pose) == 1:
            return all(map(math.isfinite, self.pose[0].tolist() + self.wheels[0].tolist()))
        return bool(np.isfinite(self.pose).all() and np.isfinite(self.wheels).all())


def step_arrays(k, targets: np.ndarray) -> None:
    """Every robot of ``k`` (a :class:`Kinematics` or a batch of them) one tick on, in one
    call of plant/kernels/kinematic.c (:func:`reference_step` is the same in numpy)."""
    targets = np.ascontiguousarray(targets, np.float64)
    robots, pairs = kernel_state(k)
    kernels.kinematic_step(len(k.pose), k.tick_s, targets, robots, k.foot.kernel_args(),
                           FOOTPRINT_RADIUS_M, CHASSIS_CENTRE_X_M, pairs)


def kernel_state(k) -> tuple[tuple[int, ...], bool]:
    """The addresses of ``k``'s arrays as plant/kernels/kinematic.c takes them (radius,
    separation, world, pose, wheels, speeds, vel) and whether some world has two robots,
    taken again only when ``k`` has new arrays."""
    arrays = (k.radius, k.separation, k.world, k.pose, k.wheels, k.speeds, k.vel)
    kept = k._kernel_args
    if kept is None or any(a is not b for a, b in zip(kept[0], arrays)):
        n, w = len(k.pose), k.world          # (the kernel reads n rows of each)
        assert all(len(a) == n for a in arrays) and w.dtype == np.int64 and all(
            a.dtype == np.float64 for a in arrays if a is not w), "kinematic arrays"
        pairs = len(w) > 1 and (w.size == 0 or bool(np.any(w[1:] == w[:-1])))
        kept = k._kernel_args = (arrays, tuple(map(kernels.ptr, arrays)), pairs)
    return kept[1], kept[2]


def reference_step(k, targets: np.ndarray) -> None:
    """:func:`step_arrays` in numpy, operation by operation (the kernel's reference:
    tests/plant/test_kernels.py compares them to the bit)."""
    T = k.tick_s
    wl, wr = targets[:, 0], targets[:, 1]
    r = k.radius
    v = r * (wr + wl) / 2.0
    w = r * (wr - wl) / k.separation
    x, y, yaw = k.pose[:, 0], k.pose[:, 1], k.pose[:, 2]
    h = w * (T / 2.0)
    safe = np.where(h != 0.0, h, 1.0)
    chord = v * T * np.where(h != 0.0, np.sin(safe) / safe, 1.0)   # the arc's chord
    mid = yaw + h
    nx = x + chord * np.cos(mid)
    ny = y + chord * np.sin(mid)
    nyaw = yaw + 2.0 * h
    blocked = _blocked(k, x, y, yaw, nx, ny, nyaw)
    k.pose[:] = np.where(blocked[:, None], k.pose, np.stack([nx, ny, nyaw], 1))
    k.vel[:, 0] = np.where(blocked, 0.0, v)
    k.vel[:, 1] = np.where(blocked, 0.0, w)
    k.wheels += targets * T
    k.speeds[:] = targets


def _blocked(k, x, y, yaw, nx, ny, nyaw) -> np.ndarray:
    """Which robots may not make their move."""
    old, new = footprint_centres(x, y, yaw), footprint_centres(nx, ny, nyaw)
    c_old, c_new = k.foot.reference_clearances(old), k.foot.reference_clearances(new)
    blocked = (c_new < FOOTPRINT_RADIUS_M) & (c_new < c_old)
    n = len(x)
    if n > 1 and (k.world.size == 0 or np.any(k.world[1:] == k.world[:-1])):
        same = (k.world[:, None] == k.world[None, :]) & ~np.eye(n, dtype=bool)
        d_old = np.hypot(old[:, None, 0] - old[None, :, 0], old[:, None, 1] - old[None, :, 1])
        d_new = np.hypot(new[:, None, 0] - new[None, :, 0], new[:, None, 1] - new[None, :, 1])
        near = same & (d_new < 2 * FOOTPRINT_RADIUS_M) & (d_new < d_old)
        blocked |= near.any(axis=1)
    return blocked


class _Batch:
    """Several worlds' robots in one set of arrays (:func:`join`)."""

    def __init__(self, members: Sequence[Kinematics]) -> None:
        first = members[0]
        for m in members:
            if m.foot.key != first.foot.key or m.tick_s != first.tick_s:
                raise ValueError("a kinematic batch steps copies of one world only")
        self.members = list(members)
        self.tick_s = first.tick_s
        self.foot = first.foot
        for f in _FIELDS[:-1]:
            setattr(self, f, np.concatenate([getattr(m, f) for m in members]))
        self.world = np.concatenate([np.full(len(m), i, np.int64) for i, m in enumerate(members)])
        self._kernel_args: tuple | None = None
        start = 0
        for m in members:               # each world's arrays become views of the batch's
            stop = start + len(m)
            for f in _FIELDS:
                setattr(m, f, getattr(self, f)[start:stop])
            m.world = np.zeros(len(m), np.int64)
            m.batch = self
            start = stop

    def step(self, targets: np.ndarray) -> None:
        step_arrays(self, targets)

    def finite(self) -> bool:
        return Kinematics.finite(self)

    def transforms(self) -> np.ndarray:
        return Kinematics.transforms(self)


def join(members: Sequence[Kinematics]) -> _Batch:
    """One batch of ``members`` (copies of one world), reused while they all stay in it."""
    b = members[0].batch if members else None
    if b is not None and len(b.members) == len(members) and all(
            m.batch is b and x is m for x, m in zip(b.members, members)):
        return b
    return _Batch(members)
