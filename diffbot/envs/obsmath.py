"""The Avoid observation and ground truth of many one-robot worlds at once, to the bit what
the message path computes robot by robot (:meth:`controllers.learned.AvoidObserver.observation`,
the ``ground_truth`` message read back with :func:`bus.codec.pose_2d`).

Many worlds are one call of plant/kernels/ticks.c each (the same operations in the same
order, with libm's ``cos``, ``sin``, ``sqrt`` and ``atan2``, which Python's ``math`` calls:
numpy's ``atan2`` differs in the last bit); one world is computed in Python floats, cheaper
than a call. A distance to a goal stays ``math.hypot``'s (CPython's own algorithm, not
libm's), robot by robot, in the callers.
"""
from __future__ import annotations

import math

import numpy as np

from bus.codec import yaw_of
from controllers.learned import GOAL_LIMIT_M, ODOM_HIGH, in_frame, wrap
from plant import kernels


def observation(pose: np.ndarray, vel: np.ndarray, goal: np.ndarray,
                scans: np.ndarray) -> dict:
    """:meth:`AvoidObserver.observation` of every world at once: the odometry and goal
    parts in one call of plant/kernels/ticks.c (one world: with its own functions, Python
    floats, cheaper than a call)."""
    if len(pose) == 1:
        x, y, th = pose[0].tolist()
        v, om = vel[0].tolist()
        gx, gy = goal[0].tolist()
        odom = np.array([[x, y, wrap(th), v, om]], np.float32)
        in_robot = np.array([in_frame((x, y, th), gx, gy)], np.float32)
        return {"scan": scans.copy(), "odom": clip(odom, -ODOM_HIGH, ODOM_HIGH),
                "goal": clip(in_robot, -GOAL_LIMIT_M, GOAL_LIMIT_M)}
    odom, in_robot = kernels.ticks_observe(*(np.ascontiguousarray(a, float)
                                             for a in (pose, vel, goal)),
                                           ODOM_HIGH, GOAL_LIMIT_M)
    return {"scan": scans.copy(), "odom": odom, "goal": in_robot}


def clamp(x: np.ndarray, lim: float) -> np.ndarray:
    """:func:`plant.drive._clamp` (``max(-lim, min(lim, x))``) element by element."""
    return np.maximum(-lim, np.minimum(lim, x))


def clip(a: np.ndarray, lo, hi) -> np.ndarray:
    """``np.clip(a, lo, hi)``'s values (a NaN stays one) without its Python wrappers,
    which cost more than the clip of a row."""
    return np.minimum(np.maximum(a, lo), hi)


def truths(pose: np.ndarray) -> np.ndarray:
    """(x, y, yaw) (W, 3) of kinematic robots at ``pose`` (W, 3) as their ``ground_truth``
    messages give them: :meth:`plant.sim.Simulation.kin_state`'s rotation, its quaternion
    (:func:`plant.sim.rotation_to_quaternion`, both of its branches), back to a yaw
    (:func:`bus.codec.quaternion_to_yaw`, ``math.atan2``: numpy's differs in the last bit),
    all robots in one call of plant/kernels/ticks.c (libm's ``cos``, ``sin``, ``sqrt`` and
    ``atan2``: what ``math``'s call)."""
    if len(pose) == 1:
        return np.array([truth_of(*pose[0].tolist())])
    return kernels.ticks_truths(np.ascontiguousarray(pose, float))


def truth_of(x: float, y: float, yaw: float) -> tuple[float, float, float]:
    """:func:`truths` of one robot, in Python floats (``math``: what
    :meth:`plant.sim.Simulation.kin_state` and :func:`plant.sim.rotation_to_quaternion`
    compute with)."""
    c, s = math.cos(yaw), math.sin(yaw)
    tr = c + c + 1.0
    if tr > 0:
        s1 = math.sqrt(tr + 1.0) * 2
        qx = qy = 0.0 / s1
        qz, qw = (s - -s) / s1, 0.25 * s1
    else:
        s2 = math.sqrt(1.0 + 1.0 - c - c) * 2
        qx = qy = 0.0 / s2
        qz, qw = 0.25 * s2, (s - -s) / s2
    return x, y, yaw_of(qx, qy, qz, qw)
