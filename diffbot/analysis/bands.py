"""The numbers the follow scenario is judged by, and the geometry to measure them, apart
from the plots: the follow environment (:mod:`diffbot.envs.follow`) rewards the same band
the scenario's analysis reports, and must not pull in matplotlib or OpenCV for it."""
from __future__ import annotations

import numpy as np

#: seconds after the start before the distance must hold its band
SETTLE_S = 5.0
#: the camera-to-ball distance band (m) and its centre, the follower's target
BAND_M = (0.60, 0.70)
TARGET_M = 0.65
#: the robots' names in the follow world
LEADER, FOLLOWER = "leader", "follower"


def pose_matrix_of(odom) -> np.ndarray:
    """The 4x4 pose of an Odometry message (ground truth), for 3-D points on the robot."""
    p, q = odom.pose.pose.position, odom.pose.pose.orientation
    x, y, z, w = q.x, q.y, q.z, q.w
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = (p.x, p.y, p.z)
    return m


def ball_offset(world) -> np.ndarray:
    """The leader's ball centre in the leader's frame (homogeneous), from its world file."""
    for part in world.robot(LEADER).parts:
        if part.shape == "sphere":
            return np.array([part.pose[0], part.pose[1], part.pose[2], 1.0])
    raise ValueError(f"{world.path}: the leader carries no ball (a sphere part)")
