"""``/tf`` and ``/tf_static`` over ROS 2, made by the bridge from the bus (REP 105).

The bus carries no transforms of its own: each robot's ``ground_truth`` (its true pose in
``world``) and ``odom`` (dead reckoning in ``<robot>/odom``, from the odometry node) are
enough. tf2 wants a tree (one parent per frame), so the chain is

* ``<robot>/odom -> <robot>/base_link``: the ``odom`` message, as a diff-drive
  controller publishes it;
* ``world -> <robot>/odom``: ground truth composed with the inverse of odometry, taken at
  the same stamp (``T_world_odom = T_world_base * T_odom_base^-1``): what a perfect
  localiser publishes as ``map -> odom``. It starts at the robot's start pose and moves as
  odometry drifts, so ``world -> <robot>/base_link`` through the chain *is* the ground
  truth at that stamp.

Both go out in one ``tf2_msgs/msg/TFMessage`` per robot and tick, stamped with the tick's
sim time, once both samples of that stamp are in (either order). Without an odometry node
(no ``odom`` within ``WAIT_TICKS`` ground truths) ``<robot>/odom`` is the start pose and
``odom -> base_link`` the true pose in it, so the tree stays whole; the first ``odom``
switches back. ``/tf_static`` (transient local, one message, as tf2's static broadcaster):
``<robot>/base_link -> <robot>/laser``, ``-> <robot>/camera -> <robot>/camera_optical``
from ``sim/info`` (the URDF's joints, :mod:`bridges.scene`).

rclpy is not imported here: the bridge hands over its node and message classes.
"""
from __future__ import annotations

import struct
import threading

from bus import codec

from . import scene
from bus.keys import WORLD_FRAME, frame

#: ground truths held waiting for the odometry of the same stamp before deciding that no
#: odometry node runs (0.5 s at a 20 ms tick)
WAIT_TICKS = 25

Pose = tuple[tuple[float, float, float], tuple[float, float, float, float]]

_CDR_LE = b"\x00\x01\x00\x00"
_STAMP = struct.Struct("<iI")
_U32 = struct.Struct("<I")
_D7 = struct.Struct("<7d")


# ---------------------------------------------------------------- rigid transforms
def _qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def _rotate(q, v):
    x, y, z, _ = _qmul(_qmul(q, (v[0], v[1], v[2], 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return (x, y, z)


def compose(a: Pose, b: Pose) -> Pose:
    """``a * b``: ``b`` expressed in ``a``'s parent frame."""
    (ta, qa), (tb, qb) = a, b
    r = _rotate(qa, tb)
    return (ta[0] + r[0], ta[1] + r[1], ta[2] + r[2]), _qmul(qa, qb)


def inverse(a: Pose) -> Pose:
    t, q = a
    qi = (-q[0], -q[1], -q[2], q[3])
    r = _rotate(qi, t)
    return (-r[0], -r[1], -r[2]), qi


# ---------------------------------------------------------------- CDR, straight
# (rosbags' decode and encode of an Odometry and a TFMessage: ~200 us a robot and tick;
# these read and write the same bytes in ~30 us, pinned against rosbags by the tests)
def _aligned(at: int, n: int) -> int:
    """``at`` moved up to a multiple of ``n`` counted after the encapsulation header."""
    return 4 + (at - 4 + n - 1) // n * n


def read_odometry(data: bytes) -> tuple[int, Pose] | None:
    """(stamp, pose) of a little-endian CDR nav_msgs/Odometry, or None if it is not one."""
    try:
        if data[:2] != _CDR_LE[:2]:
            m = codec.decode(data, "nav_msgs/msg/Odometry")     # big endian: the slow way
            return codec.stamp_ns(m.header.stamp), pose_of(m)
        sec, nsec = _STAMP.unpack_from(data, 4)
        at = 12 + _U32.unpack_from(data, 12)[0] + 4               # after header.frame_id
        at = _aligned(at, 4)
        at = _aligned(at + 4 + _U32.unpack_from(data, at)[0], 8)  # after child_frame_id
        x, y, z, qx, qy, qz, qw = _D7.unpack_from(data, at)
    except (struct.error, codec.CodecError):
        return None
    return sec * 1_000_000_000 + nsec, ((x, y, z), (qx, qy, qz, qw))


def _string(buf: bytearray, text: str) -> None:
    raw = text.encode() + b"\0"
    buf += bytes(_aligned(len(buf), 4) - len(buf))
    buf += _U32.pack(len(raw))
    buf += raw


def tf_bytes(transforms: list[tuple[str, str, int, Pose]]) -> bytes:
    """CDR of a tf2_msgs/msg/TFMessage of (parent, child, stamp, pose) transforms."""
    buf = bytearray(_CDR_LE)
    buf += _U32.pack(len(transforms))
    for parent, child, t_ns, ((x, y, z), (qx, qy, qz, qw)) in transforms:
        buf += bytes(_aligned(len(buf), 4) - len(buf))
        buf += _STAMP.pack(t_ns // 1_000_000_000, t_ns % 1_000_000_000)
        _string(buf, parent)
        _string(buf, child)
        buf += bytes(_aligned(len(buf), 8) - len(buf))
        buf += _D7.pack(x, y, z, qx, qy, qz, qw)
    return bytes(buf)


def pose_of(odom) -> Pose:
    """The pose of a nav_msgs/Odometry (its child frame in its frame)."""
    p, q = odom.pose.pose.position, odom.pose.pose.orientation
    return (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)


def start_pose(info: dict, robot: str) -> Pose:
    x, y, yaw = (list(info["robots"][robot].get("pose") or []) + [0.0, 0.0, 0.0])[:3]
    return (x, y, 0.0), scene.yaw_quaternion(yaw)


def chain(robot: str, t_ns: int, world_odom: Pose, odom_base: Pose) -> bytes:
    """The TFMessage ``world -> <robot>/odom -> <robot>/base_link`` stamped ``t_ns``."""
    odom = frame(robot, "odom")
    return tf_bytes([(WORLD_FRAME, odom, t_ns, world_odom),
                     (odom, frame(robot, "base_link"), t_ns, odom_base)])


def static_message(info: dict, robots: list[str]):
    """``/tf_static``: every bridged robot's sensor mounts, in one message."""
    mine = {"robots": {r: v for r, v in info.get("robots", {}).items() if r in robots}}
    return scene.tf(scene.sensor_transforms(mine))


class _Robot:
    """One robot's samples waiting for their partner of the same stamp."""

    def __init__(self, start: Pose) -> None:
        self.start = start
        self.gt: dict[int, Pose] = {}
        self.odom: dict[int, Pose] = {}
        self.last = -1                 # stamp of the last /tf sent
        self.odometry: bool | None = None    # None: not known yet whether odometry runs

    def clear(self) -> None:
        self.gt.clear()
        self.odom.clear()
        self.last = -1


class TfPublisher:
    """Subscribes each robot's ``ground_truth`` and ``odom`` on the bus and publishes
    ``/tf``; publishes ``/tf_static`` once (transient local)."""

    def __init__(self, node, ros, session, keys, info: dict, robots: list[str],
                 publish) -> None:
        self._publish = publish                    # the bridge's counted, shutdown-safe publish
        self._lock = threading.Lock()
        self.pub = node.create_publisher(ros.TFMessage, "/tf", ros.qos_tf)
        self.static_pub = node.create_publisher(ros.TFMessage, "/tf_static", ros.qos_latched)
        self._publish(self.static_pub, codec.encode(static_message(info, robots)))
        self.robots = {r: _Robot(start_pose(info, r)) for r in robots}
        self._subs = []
        for r in robots:
            for topic in ("ground_truth", "odom"):
                self._subs.append(session.declare_subscriber(
                    keys.topic(r, topic),
                    lambda s, r=r, truth=topic == "ground_truth": self._on(r, bytes(s.payload),
                                                                         truth)))

    def _on(self, robot: str, data: bytes, truth: bool) -> None:
        """A ground truth (``truth``) or an odometry sample of ``robot``: filed, and the
        chain published once both of a tick are in."""
        got = read_odometry(data)                  # garbage: None (counted elsewhere)
        if got is None:
            return
        t, pose = got
        with self._lock:
            st = self.robots[robot]
            if truth:
                if t <= st.last:                   # a reset: time starts again
                    st.clear()
                st.gt[t] = pose
            elif t <= st.last:     # sent already (or, after a reset, before its first truth)
                return
            else:
                st.odometry = True
                st.odom[t] = pose
            out = self._pair(robot, st, t)
            if out is None and truth and st.odometry is not True:
                out = self._without_odometry(robot, st)
        if out is not None:
            self._publish(self.pub, out)

    def _pair(self, robot: str, st: _Robot, t: int) -> bytes | None:
        """The chain at ``t`` if both samples of ``t`` are in (older ones are dropped)."""
        if t not in st.gt or t not in st.odom:
            if len(st.gt) > WAIT_TICKS and st.odometry:   # odometry stopped: say so below
                st.odometry = False
            for d in (st.gt, st.odom):
                while len(d) > 4 * WAIT_TICKS:
                    del d[min(d)]
            return None
        truth, odom = st.gt.pop(t), st.odom.pop(t)
        for d in (st.gt, st.odom):
            for s in [s for s in d if s < t]:
                del d[s]
        st.last = t
        return chain(robot, t, compose(truth, inverse(odom)), odom)

    def _without_odometry(self, robot: str, st: _Robot) -> bytes | None:
        """No odometry node: ``<robot>/odom`` is the start pose. Sent once it is clear that
        no odometry comes (``WAIT_TICKS`` ground truths unanswered), then at once."""
        if st.odometry is None and len(st.gt) <= WAIT_TICKS:
            return None
        st.odometry = False
        t = max(st.gt)
        truth = st.gt.pop(t)
        st.gt.clear()
        st.last = t
        return chain(robot, t, st.start, compose(inverse(st.start), truth))

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self._subs = []
