"""A dynamic world's robots' state rows read from DART (:meth:`plant.sim.Simulation.read_state`).

A row is a robot's base_link pose (the 4x4, row-major), body linear and angular velocity
(3 + 3) and wheel angles and speeds (2 + 2): the values :meth:`plant.sim.Simulation.state`
gives robot by robot, to the bit. DART computes a body's transform and velocities lazily,
when first asked after a step, so the velocities are read only where the tick needs them
(``velocities``): without them their six columns hold NaN until :func:`fill_velocities`
reads them into the same rows, the values a whole read gives.
"""
from __future__ import annotations

import math

import dartpy as dart
import numpy as np

#: the width of a robot's row
STATE_COLS = 26
#: from this many robots a world's rows are read all at once (:func:`chassis_rows`): 24
#: robots' rows in 211 us instead of 266, but one robot's in 14.6 us instead of 11.4
BATCH_ROWS_FROM = 4
_WORLD = dart.dynamics.Frame.World()
_NO_VELOCITIES = np.full(6, np.nan)


def finite(q: np.ndarray, dq: np.ndarray) -> bool:
    """Whether a skeleton's positions and velocities are all finite: their sum as Python
    floats (a third of numpy's calls) is finite only if every value is; one that overflows
    is checked value by value."""
    return math.isfinite(sum(q.tolist()) + sum(dq.tolist())) or bool(
        np.isfinite(q).all() and np.isfinite(dq).all())


def _body_velocities(rows: np.ndarray, chassis: list) -> None:
    """``rows``' body velocities (columns 16-21) from DART, of the poses in their first 16
    columns: both velocities in world coordinates through ``getSpatialVelocity(World,
    World)`` (angular then linear: what ``getAngularVelocity()`` and
    ``getLinearVelocity()`` give, in one call), rotated into the body as
    Robot.body_velocity does (rot.T @ v) in one matmul, each rot.T C-ordered as DART's
    tf[:3, :3].T is (numpy's same path: the same bits)."""
    n = len(chassis)
    vels = np.array([c.getSpatialVelocity(_WORLD, _WORLD) for c in chassis]).reshape(n, 6)
    rot_t = np.ascontiguousarray(rows[:, :16].reshape(n, 4, 4)[:, :3, :3].transpose(0, 2, 1))
    rows[:, 16:19] = np.matmul(rot_t, vels[:, 3:, None])[..., 0]
    rows[:, 19:22] = np.matmul(rot_t, vels[:, :3, None])[..., 0]


def chassis_rows(chassis: list, velocities: bool = True) -> np.ndarray:
    """State rows (R, 26) of the robots' ``chassis``, pose and (``velocities``) body
    velocities filled (the wheels' are the caller's): each kind of DART call in one list."""
    n = len(chassis)
    rows = np.empty((n, STATE_COLS))
    rows[:, :16] = np.array([c.getTransform().matrix() for c in chassis]).reshape(n, 16)
    if velocities:
        _body_velocities(rows, chassis)
    else:
        rows[:, 16:22] = np.nan
    return rows


def read_rows(robots: list, wheel_dofs: list, velocities: bool = True) -> tuple[np.ndarray, bool]:
    """(rows, whether every robot's positions and velocities are finite) of ``robots``
    (:class:`plant.robot.Robot`, their wheels' dofs ``wheel_dofs``). Per robot: the pose
    through ``getTransform()`` (the world transform, ~2 us cheaper a call in dartpy than
    ``getWorldTransform()``), the velocities where asked, and the skeleton's positions and
    velocities, whose sum is the finite check."""
    if len(robots) >= BATCH_ROWS_FROM:
        rows = chassis_rows([r.chassis for r in robots], velocities)
        ok = True
        for row, r, wheels in zip(rows, robots, wheel_dofs):
            q, dq = r.skeleton.getPositions(), r.skeleton.getVelocities()
            row[22:24], row[24:26] = q[wheels], dq[wheels]
            ok = ok and finite(q, dq)
        return rows, ok
    # a few robots: row by row, a matmul a robot (cheaper than stacking them for one to three)
    parts, ok, world = [], True, _WORLD
    for r, wheels in zip(robots, wheel_dofs):
        chassis, sk = r.chassis, r.skeleton
        tf = chassis.getTransform().matrix()
        q, dq = sk.getPositions(), sk.getVelocities()
        if velocities:
            rot_t = tf[:3, :3].T                  # (as Robot.body_velocity rotates them)
            vel = chassis.getSpatialVelocity(world, world)       # (angular, linear)
            parts += (tf.ravel(), rot_t @ vel[3:], rot_t @ vel[:3], q[wheels], dq[wheels])
        else:
            parts += (tf.ravel(), _NO_VELOCITIES, q[wheels], dq[wheels])
        ok = ok and finite(q, dq)
    return np.concatenate(parts).reshape(len(robots), STATE_COLS), ok


def fill_velocities(robots: list, rows: np.ndarray) -> None:
    """The body velocities of ``rows`` read without them (:func:`read_rows`), from DART in
    the same state: the values a read with them gives, to the bit."""
    if len(robots) >= BATCH_ROWS_FROM:
        _body_velocities(rows, [r.chassis for r in robots])
        return
    world = _WORLD
    for row, r in zip(rows, robots):
        # (DART hands its 4x4 column-major: the same layout, so numpy's same matmul path)
        rot_t = row[:16].reshape(4, 4).copy(order="F")[:3, :3].T
        vel = r.chassis.getSpatialVelocity(world, world)
        row[16:19], row[19:22] = rot_t @ vel[3:], rot_t @ vel[:3]
