"""What the live view derives from the bus for Foxglove (bridges/view.py): each robot's
trails (ground truth, odometry), metrics (odometry error, the follower's tracking
distance), /tf from ground truth, and the follower's camera with its detection drawn."""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from bus import codec

from . import scene
from bus.keys import TOPICS

#: paths: a point is added once the robot moved this far from the last one; at most this many
PATH_STEP_M = 0.02
PATH_MAX_POINTS = 5000


def quaternion_matrix(q) -> np.ndarray:
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def pose_of(odom) -> tuple[np.ndarray, np.ndarray]:
    """(position, rotation matrix) of an Odometry message."""
    p, q = odom.pose.pose.position, odom.pose.pose.orientation
    return np.array([p.x, p.y, p.z]), quaternion_matrix((q.x, q.y, q.z, q.w))


def tracking_pairs(info: dict) -> list[tuple[str, np.ndarray, str, np.ndarray]]:
    """(watcher, camera position on it, target, ball position on it): every robot with a
    camera against every other robot that carries a sphere part (the follow task's ball)."""
    out = []
    robots = info.get("robots", {})
    for a, ra in robots.items():
        cam = (ra.get("sensors") or {}).get("camera")
        if not cam:
            continue
        mount = np.array([cam["mount_x_m"], cam["mount_y_m"], cam["mount_z_m"]])
        for b, rb in robots.items():
            parts = {f"{b}_{p}" for p in rb.get("parts", [])}
            balls = [v for v in rb.get("body", []) if v["shape"] == "sphere" and v["name"] in parts]
            if b != a and balls:
                out.append((a, mount, b, np.array(balls[0]["position"])))
    return out


class Path:
    """A decimated, bounded trail of positions."""

    def __init__(self) -> None:
        self.points: deque[tuple[int, float, float, float]] = deque(maxlen=PATH_MAX_POINTS)
        self.dirty = False

    def add(self, t_ns: int, x: float, y: float, z: float) -> None:
        if self.points:
            _, px, py, pz = self.points[-1]
            if math.hypot(x - px, y - py) < PATH_STEP_M:
                return
        self.points.append((t_ns, x, y, z))
        self.dirty = True

    def message(self, frame_id: str = scene.WORLD_FRAME):
        T = codec.T
        poses = [T["geometry_msgs/msg/PoseStamped"](
            header=codec.header(t, frame_id),
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
            for t, x, y, z in self.points]
        t_last = self.points[-1][0] if self.points else 0
        return T["nav_msgs/msg/Path"](header=codec.header(t_last, frame_id), poses=poses)


class Derived:
    """The :class:`bridges.view.View` methods that derive topics from what came (a part
    of the view, not used alone: it relies on the view's ``send``, ``wanted``, ``decode``,
    ``unpack``, ``topic_name``, ``info``, ``_paths``, ``_gt``, ``_pairs``, ``_debug``,
    ``_deps``, ``rejects``)."""

    def path(self, robot: str, kind: str) -> Path:
        return self._paths.setdefault(f"{robot}/path/{kind}", Path())

    def ground_truth_at(self, robot: str, t: int):
        """A robot's ground truth stamped ``t`` (decoded), if it is among the last ones."""
        for item in reversed(self._gt.get(robot, ())):
            payload, t_item = self.unpack(item)
            if t_item == t:
                return self.decode(payload, TOPICS["ground_truth"].msgtype, f"{robot}/ground_truth")
            if t_item < t:
                return None
        return None

    def on_ground_truth(self, robot: str, payload: bytes, t: int) -> None:
        m = self.decode(payload, TOPICS["ground_truth"].msgtype, f"{robot}/ground_truth")
        if m is None:
            return
        tf_topic = self.topic_name(scene.TF_TOPIC)
        if self.wanted(tf_topic, scene.TF_TYPE):
            self.send(tf_topic, scene.TF_TYPE,
                      codec.encode(scene.tf([scene.ground_truth_transform(robot, m, t)])), t)
        if self.wanted(self.topic_name(f"{robot}/path/ground_truth"), "nav_msgs/msg/Path"):
            p = m.pose.pose.position
            self.path(robot, "ground_truth").add(t, p.x, p.y, p.z)
        for a, mount, b, ball in self._pairs:
            if robot not in (a, b) or not self.wanted(
                    self.topic_name(f"{a}/metrics/tracking_distance_m"), "std_msgs/msg/Float64"):
                continue
            ga = m if a == robot else self.ground_truth_at(a, t)
            gb = m if b == robot else self.ground_truth_at(b, t)
            if ga is None or gb is None:
                continue
            pa, ra = pose_of(ga)
            pb, rb = pose_of(gb)
            d = float(np.linalg.norm((pa + ra @ mount) - (pb + rb @ ball)))
            self.metric(a, "tracking_distance_m", d, t)

    def on_odom(self, robot: str, payload: bytes, t: int) -> None:
        m = self.decode(payload, TOPICS["odom"].msgtype, f"{robot}/odom")
        if m is None:
            return
        p = m.pose.pose.position
        if self.wanted(self.topic_name(f"{robot}/path/odom"), "nav_msgs/msg/Path"):
            self.path(robot, "odom").add(t, p.x, p.y, p.z)
        if self.wanted(self.topic_name(f"{robot}/metrics/odometry_error_m"),
                       "std_msgs/msg/Float64"):
            gt = self.ground_truth_at(robot, t)
            if gt is not None:             # odometry is in <robot>/odom: compared in world
                g = gt.pose.pose.position
                x, y, _ = scene.to_world(self.info["robots"][robot]["pose"], p.x, p.y)
                self.metric(robot, "odometry_error_m", math.hypot(x - g.x, y - g.y), t)

    def metric(self, robot: str, name: str, value: float, t: int) -> None:
        topic = self.topic_name(f"{robot}/metrics/{name}")
        if self.wanted(topic, "std_msgs/msg/Float64"):
            self.send(topic, "std_msgs/msg/Float64",
                      codec.encode(codec.T["std_msgs/msg/Float64"](data=float(value))), t)

    def annotated(self, robot: str, payload: bytes, t: int) -> None:
        """The image with the follower's detection (circle, centre, distance) drawn on it."""
        topic = self.topic_name(f"{robot}/camera/image_annotated")
        msgtype = TOPICS["camera/image_raw"].msgtype
        if topic not in self._deps or not self.wanted(topic, msgtype):   # no follower: none
            return
        m = self.decode(payload, msgtype, f"{robot}/camera/image_raw")
        if m is None:
            return
        try:
            rgb = codec.image_to_array(m).copy()
        except ValueError as exc:
            self.rejects.reject(f"{robot}/camera/image_raw", str(exc))
            return
        dbg = None
        if robot in self._debug:
            raw, t_dbg = self.unpack(self._debug[robot])
            d = self.decode(raw, TOPICS["follower/debug"].msgtype, f"{robot}/follower/debug") \
                if abs(t_dbg - t) <= 0.2e9 else None
            dbg = (t, [float(v) for v in d.data]) if d is not None else None
        if dbg is not None and len(dbg[1]) >= 4 and dbg[1][0] > 0:
            import cv2
            _, u, v, r = dbg[1][:4]
            if all(math.isfinite(x) for x in (u, v, r)):
                c = (int(round(u)), int(round(v)))
                cv2.circle(rgb, c, max(1, int(round(r))), (255, 0, 255), 1)
                cv2.drawMarker(rgb, c, (255, 0, 255), cv2.MARKER_CROSS, 6, 1)
                if len(dbg[1]) >= 5 and math.isfinite(dbg[1][4]):
                    cv2.putText(rgb, f"{dbg[1][4]:.2f} m", (2, rgb.shape[0] - 4),
                                cv2.FONT_HERSHEY_PLAIN, 0.8, (255, 0, 255), 1)
        out = codec.image(t, rgb, m.header.frame_id)
        self.send(topic, msgtype, codec.encode(out), t)

    def flush_paths(self) -> None:
        for name, p in self._paths.items():
            if p.dirty:
                p.dirty = False
                robot, _, kind = name.partition("/path/")
                frame = scene.frame(robot, "odom") if kind == "odom" else scene.WORLD_FRAME
                self.send(self.topic_name(name), "nav_msgs/msg/Path",
                          codec.encode(p.message(frame)), p.points[-1][0])
