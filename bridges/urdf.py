"""A robot's URDF (``robot_description``) generated from the plant's ``sim/info``.

Pure data from the world's robot spec, as RViz's RobotModel and Foxglove's URDF layer
read it: the chassis and the caster on ``<robot>/base_link``, a link per wheel on a
``continuous`` joint named as in ``<robot>/joint_states`` (``left_wheel_joint``,
``right_wheel_joint``, axis +y), a fixed link per sensor (``<robot>/laser``,
``<robot>/camera`` and its REP 103 optical frame ``<robot>/camera_optical``) and per
carried part (the leader's ball). Link names carry the robot's prefix, so they are the
frames the bus's messages and ``/tf`` use (with ``robot_state_publisher`` leave its
``frame_prefix`` empty). Masses are nominal: the URDF is for looking at, not for
simulating.
"""
from __future__ import annotations

import math
from xml.sax.saxutils import quoteattr

from bus.keys import frame

DESCRIPTION_TYPE = "std_msgs/msg/String"
#: the topic under ``/<robot>/`` (ROS 2's robot_state_publisher publishes ``robot_description``)
DESCRIPTION_TOPIC = "robot_description"
WHEELS = {"left_wheel_joint": "left_wheel", "right_wheel_joint": "right_wheel"}
#: camera body (x forward) -> optical (z forward, x right, y down) as URDF rpy
OPTICAL_RPY = (-math.pi / 2, 0.0, -math.pi / 2)


def _f(v: float) -> str:
    """Rounded to 1e-6 (m, rad): the parts' poses come from a snapshot of the running world,
    whose numerical dust (1e-35 rad) must not make one robot's URDF differ from query to
    query."""
    return f"{round(float(v), 6) + 0.0:.9g}"


def _xyz(v) -> str:
    return " ".join(_f(a) for a in v)


def quaternion_rpy(q) -> tuple[float, float, float]:
    """URDF's fixed-axis (roll, pitch, yaw) of a quaternion (x, y, z, w)."""
    x, y, z, w = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def _geometry(shape: str, size) -> str:
    if shape == "box":
        return f'<box size="{_xyz(size)}"/>'
    if shape == "cylinder":
        return f'<cylinder radius="{_f(size[0])}" length="{_f(size[1])}"/>'
    return f'<sphere radius="{_f(size[0])}"/>'


def _link(name: str, visual: dict | None = None, rpy=None, xyz=(0.0, 0.0, 0.0),
          mass_kg: float = 0.0) -> str:
    out = [f"  <link name={quoteattr(name)}>"]
    if visual is not None:
        rpy = rpy if rpy is not None else quaternion_rpy(visual["orientation"])
        geom = _geometry(visual["shape"], visual["size"])
        origin = f'<origin xyz="{_xyz(xyz)}" rpy="{_xyz(rpy)}"/>'
        r, g, b = visual["color"][:3]
        out += [f"    <visual>{origin}<geometry>{geom}</geometry>"
                f"<material name={quoteattr(visual['name'])}><color rgba=\"{_xyz((r, g, b, 1.0))}\"/>"
                "</material></visual>",
                f"    <collision>{origin}<geometry>{geom}</geometry></collision>"]
    if mass_kg > 0:
        out.append(f'    <inertial><mass value="{_f(mass_kg)}"/>'
                   '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>')
    out.append("  </link>")
    return "\n".join(out)


def _joint(name: str, kind: str, parent: str, child: str, xyz, rpy=(0.0, 0.0, 0.0),
           axis=None) -> str:
    s = (f"  <joint name={quoteattr(name)} type=\"{kind}\">"
         f"<parent link={quoteattr(parent)}/><child link={quoteattr(child)}/>"
         f'<origin xyz="{_xyz(xyz)}" rpy="{_xyz(rpy)}"/>')
    if axis is not None:
        s += f'<axis xyz="{_xyz(axis)}"/>'
    return s + "</joint>"


def robot_urdf(info: dict, robot: str) -> str:
    """The URDF of ``robot`` in a ``sim/info`` dict (KeyError if there is no such robot)."""
    r = info["robots"][robot]
    base = frame(robot, "base_link")
    body = {v["name"]: v for v in r.get("body", [])}
    parts = [f"{robot}_{p}" for p in r.get("parts", [])]
    chassis = body.get(f"{robot}_chassis")
    lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(robot)}>",
             _link(base, chassis, xyz=chassis["position"] if chassis else (0, 0, 0),
                   mass_kg=5.0)]
    caster = body.get(f"{robot}_caster")
    if caster is not None:
        lines += [_link(frame(robot, "caster"), caster, rpy=(0, 0, 0)),
                  _joint("caster_joint", "fixed", base, frame(robot, "caster"),
                         caster["position"])]
    for joint, wheel in WHEELS.items():
        v = body.get(f"{robot}_{wheel}_visual")
        # a sim/info without the body (a thin plant): the wheels from the drive's numbers
        y = float(r.get("wheel_separation_m", 0.0)) / 2 * (1 if wheel.startswith("left") else -1)
        xyz = v["position"] if v is not None else (0.0, y, 0.0)
        shape = v if v is not None else {"name": wheel, "shape": "cylinder",
                                         "size": [float(r.get("wheel_radius_m", 0.05)), 0.04],
                                         "color": [0.1, 0.1, 0.1]}
        # the cylinder's axis is its z: turned onto the wheel's axle (+y)
        lines += [_link(frame(robot, wheel), shape, rpy=(math.pi / 2, 0, 0), mass_kg=0.5),
                  _joint(joint, "continuous", base, frame(robot, wheel), xyz, axis=(0, 1, 0))]
    for name in parts:
        v = body.get(name)
        if v is None:
            continue
        link = frame(robot, name[len(robot) + 1:])
        lines += [_link(link, v, rpy=(0, 0, 0)),
                  _joint(f"{name[len(robot) + 1:]}_joint", "fixed", base, link, v["position"],
                         quaternion_rpy(v["orientation"]))]
    sensors = r.get("sensors") or {}
    lidar, cam = sensors.get("lidar"), sensors.get("camera")
    if lidar:
        lines += [_link(frame(robot, "laser")),
                  _joint("laser_joint", "fixed", base, frame(robot, "laser"),
                         (lidar["mount_x_m"], lidar["mount_y_m"], lidar["mount_z_m"]),
                         (0.0, 0.0, lidar["mount_yaw_rad"]))]
    if cam:
        lines += [_link(frame(robot, "camera")),
                  _joint("camera_joint", "fixed", base, frame(robot, "camera"),
                         (cam["mount_x_m"], cam["mount_y_m"], cam["mount_z_m"]),
                         (cam["mount_roll_rad"], cam["mount_pitch_rad"], cam["mount_yaw_rad"])),
                  _link(frame(robot, "camera_optical")),
                  _joint("camera_optical_joint", "fixed", frame(robot, "camera"),
                         frame(robot, "camera_optical"), (0.0, 0.0, 0.0), OPTICAL_RPY)]
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def description_message(info: dict, robot: str):
    """``std_msgs/msg/String`` holding :func:`robot_urdf`."""
    from bus.codec import T
    return T[DESCRIPTION_TYPE](data=robot_urdf(info, robot))
