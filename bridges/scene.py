"""The simulation as a 3-D scene for viewers: pure data from the plant's ``sim/info``.

Shared by the live view (``bridges/view.py``) and the recorder (``bridges/record.py``), so a
recording opened in Foxglove shows the same room as the live view. Everything here is a
standard ROS 2 message built with the ``rosbags`` type store (no foxglove import, no ROS
install), so Foxglove, RViz and ``ros2 bag play`` all understand it:

* ``/scene`` — ``visualization_msgs/msg/MarkerArray``: one marker per world object
  (floor, walls, furniture; namespace ``world``, frame ``world``, its size, pose and
  colour from the world file) and one per visual part of each robot (chassis, wheels,
  caster, carried parts such as the leader's green ball; namespace ``<robot>``, frame
  ``<robot>/base_link``, ``frame_locked``, so it moves with the robot's transform).
* ``/tf_static`` — ``tf2_msgs/msg/TFMessage``: ``world -> <robot>/odom`` (the robot's
  start pose: REP 105's odometry frame starts where the robot starts), and the sensor
  mounts ``<robot>/base_link -> <robot>/laser``, ``-> <robot>/camera`` (body convention,
  x forward) and ``<robot>/camera -> <robot>/camera_optical`` (REP 103's optical frame: z
  forward, x right, y down: the frame images are drawn in).
* ``/tf`` — ``tf2_msgs/msg/TFMessage``: ``world -> <robot>/base_link`` from each
  ground truth, every tick.

Frames are the bus's own (:func:`bus.keys.frame`): prefixed with the robot's name so
several robots' lasers and cameras never clash; the messages on the bus carry them.
"""
from __future__ import annotations

import math

import numpy as np

from bus import codec
from bus.codec import T
from bus.keys import WORLD_FRAME, frame  # noqa: F401  (scene.frame, scene.WORLD_FRAME)

SCENE_TOPIC = "scene"
TF_TOPIC = "tf"
TF_STATIC_TOPIC = "tf_static"
SCENE_TYPE = "visualization_msgs/msg/MarkerArray"
TF_TYPE = "tf2_msgs/msg/TFMessage"

_Marker = T["visualization_msgs/msg/Marker"]
_MarkerArray = T[SCENE_TYPE]
_TFMessage = T[TF_TYPE]
_TransformStamped = T["geometry_msgs/msg/TransformStamped"]
_Transform = T["geometry_msgs/msg/Transform"]
_Vector3 = T["geometry_msgs/msg/Vector3"]
_Point = T["geometry_msgs/msg/Point"]
_Quaternion = T["geometry_msgs/msg/Quaternion"]
_Pose = T["geometry_msgs/msg/Pose"]
_ColorRGBA = T["std_msgs/msg/ColorRGBA"]
_Duration = T["builtin_interfaces/msg/Duration"]
_UV = T["visualization_msgs/msg/UVCoordinate"]
_MeshFile = T["visualization_msgs/msg/MeshFile"]
_CompressedImage = T["sensor_msgs/msg/CompressedImage"]
_EMPTY_U8 = np.zeros(0, dtype=np.uint8)

#: camera body (x forward, y left, z up) -> optical (z forward, x right, y down): rpy(-pi/2, 0, -pi/2)
OPTICAL_QUATERNION = (-0.5, 0.5, -0.5, 0.5)


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


def rpy_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of R = Rz(yaw) Ry(pitch) Rx(roll) (ROS's fixed-axis roll, pitch, yaw)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


# ---------------------------------------------------------------------------- scene
def _scale(shape: str, size) -> tuple[float, float, float]:
    """Marker scale: box edges; cylinder and sphere diameters (and the cylinder's height)."""
    if shape == "box":
        return (float(size[0]), float(size[1]), float(size[2]))
    if shape == "cylinder":
        return (2 * float(size[0]), 2 * float(size[0]), float(size[1]))
    return (2 * float(size[0]),) * 3


_KIND = {"box": _Marker.CUBE, "cylinder": _Marker.CYLINDER, "sphere": _Marker.SPHERE}


def marker(ns: str, mid: int, frame_id: str, shape: str, size, position, quaternion, color,
           name: str = "", frame_locked: bool = False, t_ns: int = 0):
    """One solid as a ``visualization_msgs/Marker`` (``text`` holds the object's name)."""
    sx, sy, sz = _scale(shape, size)
    return _Marker(
        header=codec.header(t_ns, frame_id), ns=ns, id=int(mid), type=_KIND[shape],
        action=_Marker.ADD,
        pose=_Pose(position=_Point(x=float(position[0]), y=float(position[1]),
                                   z=float(position[2])),
                   orientation=_Quaternion(x=float(quaternion[0]), y=float(quaternion[1]),
                                           z=float(quaternion[2]), w=float(quaternion[3]))),
        scale=_Vector3(x=sx, y=sy, z=sz),
        color=_ColorRGBA(r=float(color[0]), g=float(color[1]), b=float(color[2]), a=1.0),
        lifetime=_Duration(sec=0, nanosec=0), frame_locked=bool(frame_locked), points=[],
        colors=[], texture_resource="", texture=_CompressedImage(
            header=codec.header(0), format="", data=_EMPTY_U8), uv_coordinates=[],
        text=name, mesh_resource="",
        mesh_file=_MeshFile(filename="", data=_EMPTY_U8), mesh_use_embedded_materials=False)


def world_markers(info: dict, t_ns: int = 0) -> list:
    """One marker per world object of ``sim/info`` (floor and walls included), frame world."""
    out = []
    for i, o in enumerate(info.get("objects", [])):
        x, y, z, yaw = o["pose"]
        out.append(marker("world", i, WORLD_FRAME, o["shape"], o["size"], (x, y, z),
                          yaw_quaternion(yaw), o["color"], o["name"], t_ns=t_ns))
    return out


def robot_markers(info: dict, t_ns: int = 0) -> list:
    """Each robot's visual parts in its ``<robot>/base_link`` frame (moving with /tf)."""
    out = []
    for robot, r in info.get("robots", {}).items():
        for i, part in enumerate(r.get("body", [])):
            out.append(marker(robot, i, frame(robot, "base_link"), part["shape"], part["size"],
                              part["position"], part["orientation"], part["color"],
                              part["name"], frame_locked=True, t_ns=t_ns))
    return out


def scene(info: dict, t_ns: int = 0):
    """The whole scene (world objects, then robots) as one MarkerArray."""
    return _MarkerArray(markers=world_markers(info, t_ns) + robot_markers(info, t_ns))


# ---------------------------------------------------------------------------- transforms
def transform(parent: str, child: str, xyz, quaternion, t_ns: int = 0):
    return _TransformStamped(
        header=codec.header(t_ns, parent), child_frame_id=child,
        transform=_Transform(
            translation=_Vector3(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])),
            rotation=_Quaternion(x=float(quaternion[0]), y=float(quaternion[1]),
                                 z=float(quaternion[2]), w=float(quaternion[3]))))


def sensor_transforms(info: dict, t_ns: int = 0) -> list:
    """base_link -> laser / camera (-> camera_optical) of every robot that has them."""
    out = []
    for robot, r in info.get("robots", {}).items():
        base = frame(robot, "base_link")
        sensors = r.get("sensors") or {}
        lidar, cam = sensors.get("lidar"), sensors.get("camera")
        if lidar:
            out.append(transform(base, frame(robot, "laser"),
                                 (lidar["mount_x_m"], lidar["mount_y_m"], lidar["mount_z_m"]),
                                 yaw_quaternion(lidar["mount_yaw_rad"]), t_ns))
        if cam:
            out.append(transform(base, frame(robot, "camera"),
                                 (cam["mount_x_m"], cam["mount_y_m"], cam["mount_z_m"]),
                                 rpy_quaternion(cam["mount_roll_rad"], cam["mount_pitch_rad"],
                                                cam["mount_yaw_rad"]), t_ns))
            out.append(transform(frame(robot, "camera"), frame(robot, "camera_optical"),
                                 (0.0, 0.0, 0.0), OPTICAL_QUATERNION, t_ns))
    return out


def odom_transforms(info: dict, t_ns: int = 0) -> list:
    """``world -> <robot>/odom`` of every robot: its start pose (``sim/info`` ``pose``)."""
    out = []
    for robot, r in info.get("robots", {}).items():
        x, y, yaw = (list(r.get("pose") or []) + [0.0, 0.0, 0.0])[:3]
        out.append(transform(WORLD_FRAME, frame(robot, "odom"), (x, y, 0.0),
                             yaw_quaternion(yaw), t_ns))
    return out


def static_tf(info: dict, t_ns: int = 0):
    """Every fixed transform: each robot's odometry origin and its sensor mounts."""
    return _TFMessage(transforms=odom_transforms(info, t_ns) + sensor_transforms(info, t_ns))


def to_world(start_pose, x: float, y: float, yaw: float = 0.0) -> tuple[float, float, float]:
    """A pose in ``<robot>/odom`` expressed in ``world``, through the robot's start pose
    ``(x0, y0, yaw0)`` (``sim/info`` ``robots.<robot>.pose``): where odometry is compared
    with GPS or ground truth."""
    x0, y0, th0 = start_pose[:3]
    c, s = math.cos(th0), math.sin(th0)
    return x0 + c * x - s * y, y0 + s * x + c * y, yaw + th0


def ground_truth_transform(robot: str, odom, t_ns: int | None = None):
    """``world -> <robot>/base_link`` from a ground-truth ``nav_msgs/Odometry``."""
    p, q = odom.pose.pose.position, odom.pose.pose.orientation
    t = codec.stamp_ns(odom.header.stamp) if t_ns is None else t_ns
    return transform(WORLD_FRAME, frame(robot, "base_link"), (p.x, p.y, p.z),
                     (q.x, q.y, q.z, q.w), t)


def tf(transforms: list):
    return _TFMessage(transforms=list(transforms))


def robot_of_ground_truth(keys, key: str) -> str | None:
    """The robot whose ground truth a concrete key carries, or None."""
    rt = keys.robot_topic_of(key)
    return rt[0] if rt and rt[1] == "ground_truth" else None

