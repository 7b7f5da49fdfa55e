"""Messages built from the values their bytes are packed from, as decoding gives them.

A member composed into the plant's process reads the messages other parts of that process
publish. Where the producer packed a message's bytes from values it still holds (an
odometry node's outputs, the plant's encoder readings), the message is built here from
those values instead of decoding the bytes: the object :func:`bus.codec.decode` gives of
them, field for field (the classes built positionally as :mod:`bus.cdrfast` builds them,
the same Python types, float64 values exactly as CDR carries them, arrays read-only as a
decoded message's views of its payload are). The bytes still go to whoever else reads them.
"""
from __future__ import annotations

import numpy as np

from . import codec

_T = codec.T
_TIME = _T["builtin_interfaces/msg/Time"]
_HEADER = _T["std_msgs/msg/Header"]
_VECTOR3 = _T["geometry_msgs/msg/Vector3"]
_POINT = _T["geometry_msgs/msg/Point"]
_QUATERNION = _T["geometry_msgs/msg/Quaternion"]
_POSE = _T["geometry_msgs/msg/Pose"]
_TWIST = _T["geometry_msgs/msg/Twist"]
_POSE_WC = _T["geometry_msgs/msg/PoseWithCovariance"]
_TWIST_WC = _T["geometry_msgs/msg/TwistWithCovariance"]
_ODOMETRY = _T["nav_msgs/msg/Odometry"]
_JOINT_STATE = _T["sensor_msgs/msg/JointState"]
_POINT_STAMPED = _T["geometry_msgs/msg/PointStamped"]


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


#: the covariance a packed Odometry carries (zeros), read-only: shared by every message
ZERO_COVARIANCE = _frozen(np.zeros(36))
#: an empty float64[] (a JointState's effort), read-only
EMPTY = _frozen(np.zeros(0))


def odometry(t_ns: int, frame_id: str, child_frame_id: str, x: float, y: float, z: float,
             quaternion: tuple, linear: float, angular: float):
    """The nav_msgs/msg/Odometry that decoding :func:`bus.packed.odometry`'s bytes of the
    same arguments gives (zero covariances; the values Python floats)."""
    sec, nanosec = divmod(t_ns, 1_000_000_000)
    return odometry_of(sec, nanosec, frame_id, child_frame_id, (x, y, z, *quaternion),
                       ZERO_COVARIANCE, (linear, 0.0, 0.0, 0.0, 0.0, angular), ZERO_COVARIANCE)


def joint_state(sec: int, nanosec: int, frame_id: str, names, position: np.ndarray,
                velocity: np.ndarray):
    """A sensor_msgs/msg/JointState as decoded: ``position``/``velocity`` float64 arrays
    the caller made read-only (views of bytes), no effort."""
    return _JOINT_STATE(_HEADER(_TIME(sec, nanosec), frame_id), list(names), position,
                        velocity, EMPTY)


def point_stamped(sec: int, nanosec: int, frame_id: str, x: float, y: float, z: float):
    """A geometry_msgs/msg/PointStamped as decoded."""
    return _POINT_STAMPED(_HEADER(_TIME(sec, nanosec), frame_id), _POINT(x, y, z))


def odometry_of(sec: int, nanosec: int, frame_id: str, child_frame_id: str, pose7, pose_cov,
                twist6, twist_cov):
    """A nav_msgs/msg/Odometry as decoded, of its pose (x, y, z, qx, qy, qz, qw), twist
    (linear x, y, z, angular x, y, z) and covariances (float64 arrays the caller made
    read-only, views of bytes)."""
    x, y, z, qx, qy, qz, qw = pose7
    lx, ly, lz, ax, ay, az = twist6
    return _ODOMETRY(_HEADER(_TIME(sec, nanosec), frame_id), child_frame_id,
                     _POSE_WC(_POSE(_POINT(x, y, z), _QUATERNION(qx, qy, qz, qw)), pose_cov),
                     _TWIST_WC(_TWIST(_VECTOR3(lx, ly, lz), _VECTOR3(ax, ay, az)), twist_cov))
