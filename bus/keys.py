"""The key catalog: every Zenoh key of the simulation is spelled here and nowhere else.

Keys are ``[<namespace>/]sim/...`` for the simulation's own keys and
``[<namespace>/]<robot>/<topic>`` for a robot's topics. A namespace lets several
simulations share one Zenoh network without clashing.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from urllib.parse import quote, unquote

#: a robot or node name's longest (ASCII, so as many bytes: the attachment's name_len)
NAME_MAX = 64
NAME_RE = re.compile(rf"^[A-Za-z][A-Za-z0-9_-]{{0,{NAME_MAX - 1}}}$")

# Names that would be read as the simulation's own key space.
RESERVED = {"sim"}


class BadName(ValueError):
    """A robot name, node name or namespace that cannot be part of a key."""


def check_name(name: str, what: str = "name") -> str:
    """Return ``name`` if it is a safe key segment, else raise ``ValueError``.

    Refused: empty names, ``*``, ``**``, ``$``, ``/``, whitespace and anything
    that would change the meaning of a key expression.
    """
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise BadName(
            f"invalid {what} {name!r}: use a letter then letters, digits, '_' or '-' "
            f"(no '/', '*', '$', spaces; at most {NAME_MAX} characters)")
    if name in RESERVED:
        raise BadName(f"invalid {what} {name!r}: reserved")
    return name


def check_names(names, what: str = "robot name") -> list[str]:
    """``names`` as a list if each is a safe key segment (:func:`check_name`) and none comes
    twice, else ``BadName``: a node's robots (``--robots``, a bridge's), checked here only."""
    names = list(names)
    for n in names:
        check_name(n, what)
    if len(set(names)) != len(names):
        raise BadName(f"a robot is named twice in {','.join(names)!r}")
    return names


def split_names(text: str, what: str = "robot name") -> list[str]:
    """Comma-separated names (``r0,r1``; spaces around each dropped), checked as
    :func:`check_names` does; ``BadName`` if there are none."""
    names = [v.strip() for v in text.split(",") if v.strip()]
    if not names:
        raise BadName(f"expected {what}s, e.g. r0,r1")
    return check_names(names, what)


@dataclass(frozen=True)
class Topic:
    """One robot topic: key suffix, ROS 2 message type, who publishes it."""

    suffix: str
    msgtype: str
    source: str  # "plant", "controller", "node" (a bus node other than the plant), or
    #              "external" (anyone, e.g. a user's script: never waited for)
    rate: str
    units: str
    frame: str

    @property
    def awaited(self) -> bool:
        """A lockstep reader waits for it at every tick (a plant sensor only when due)."""
        return self.source in ("controller", "node")


#: Per-robot topics. ``source == "node"`` topics are produced by bus nodes in
#: lockstep, so a consumer waits for them; the plant's topics arrive before
#: ``sim/clock`` of the same tick.
TOPICS: dict[str, Topic] = {
    "cmd_vel": Topic("cmd_vel", "geometry_msgs/msg/TwistStamped", "controller",
                     "every control tick (or any rate in realtime)",
                     "m/s, rad/s", "<robot>/base_link"),
    "wheel_cmd": Topic("wheel_cmd", "sensor_msgs/msg/JointState", "controller",
                       "every control tick (or any rate in realtime)",
                       "rad/s (velocity field)", "-"),
    "joint_states": Topic("joint_states", "sensor_msgs/msg/JointState", "plant",
                          "every control tick", "rad, rad/s", "-"),
    "gps": Topic("gps", "geometry_msgs/msg/PointStamped", "plant",
                 "every control tick", "m", "world"),
    "ground_truth": Topic("ground_truth", "nav_msgs/msg/Odometry", "plant",
                          "every control tick", "m, rad, m/s, rad/s",
                          "world -> <robot>/base_link"),
    "scan": Topic("scan", "sensor_msgs/msg/LaserScan", "plant", "10 Hz", "m, rad",
                  "<robot>/laser"),
    "camera/image_raw": Topic("camera/image_raw", "sensor_msgs/msg/Image", "plant", "30 Hz",
                              "rgb8", "<robot>/camera_optical"),
    "camera/camera_info": Topic("camera/camera_info", "sensor_msgs/msg/CameraInfo", "plant",
                                "with image", "px", "<robot>/camera_optical"),
    "odom": Topic("odom", "nav_msgs/msg/Odometry", "node", "every control tick",
                  "m, rad, m/s, rad/s", "<robot>/odom -> <robot>/base_link"),
    "follower/debug": Topic("follower/debug", "std_msgs/msg/Float64MultiArray", "controller",
                            "with each camera frame",
                            "found, u px, v px, radius px, distance m, bearing rad",
                            "<robot>/camera_optical"),
}

#: the world's fixed frame (ground truth, GPS, the scene)
WORLD_FRAME = "world"


def frame(robot: str, name: str) -> str:
    """A robot's frame: ``<robot>/<name>`` (``base_link``, ``odom``, ``laser``,
    ``camera``, ``camera_optical``), so several robots never share one (docs/PROTOCOL.md)."""
    return f"{robot}/{name}"


CLOCK_TYPE = "rosgraph_msgs/msg/Clock"
#: ``sim/poses``: a TransformStamped per robot, ``world`` -> ``<robot>/base_link``
POSES_TYPE = "tf2_msgs/msg/TFMessage"

# ---------------------------------------------------------------- FMU variables
#: FMU nodes publish their variables on ``fmu/<instance>/<variable>`` (bus-wide, not per
#: robot); a node reads a variable's key as a "topic" named ``fmu/...`` (docs/fmu.md)
FMU_ROOT = "fmu"
#: the last segment of an FMU node's queryable (its variables, types, units, keys)
FMU_INFO = "info"


def escape_variable(name: str) -> str:
    """An FMU variable name as one key segment (docs/fmu.md, "Keys"): percent-encoding
    (RFC 3986) of every byte of its UTF-8 that is not a letter, digit, ``_ . - ~``; a
    variable named ``info`` (the node's queryable) is written ``%69nfo``. So ``der(x)`` is
    ``der%28x%29``, ``a.b[1]`` is ``a.b%5B1%5D``, and :func:`unescape_variable` inverts it."""
    if not isinstance(name, str) or not name:
        raise BadName(f"invalid FMU variable name {name!r}: empty")
    seg = quote(name, safe="")
    if seg == FMU_INFO:
        seg = "%69nfo"
    if seg in (".", ".."):
        seg = seg.replace(".", "%2E")
    return seg


def unescape_variable(segment: str) -> str:
    return unquote(segment)


def is_fmu_topic(name: str) -> bool:
    """True for a bus-wide FMU variable "topic" (``fmu/<instance>/<escaped variable>``)."""
    return isinstance(name, str) and name.startswith(FMU_ROOT + "/")


def fmu_topic(instance: str, variable: str) -> str:
    """The topic name (the key without namespace) of an FMU node's variable."""
    return f"{FMU_ROOT}/{check_name(instance, 'FMU instance name')}/{escape_variable(variable)}"


def check_fmu_topic(name: str) -> str:
    """``name`` if it is ``fmu/<instance>/<segment>`` with a valid instance and an escaped
    variable segment (what :func:`fmu_topic` makes), else BadName."""
    parts = name.split("/") if isinstance(name, str) else []
    if len(parts) != 3 or parts[0] != FMU_ROOT:
        raise BadName(f"invalid FMU key {name!r}: expected {FMU_ROOT}/<instance>/<variable>")
    check_name(parts[1], "FMU instance name")
    if parts[2] == FMU_INFO or escape_variable(unescape_variable(parts[2])) != parts[2]:
        raise BadName(f"invalid FMU key {name!r}: {parts[2]!r} is not an escaped variable "
                      f"name (variable {unescape_variable(parts[2])!r} is "
                      f"{escape_variable(unescape_variable(parts[2]))!r}; docs/fmu.md)")
    return name


class Keys:
    """Key names for one simulation (one namespace)."""

    def __init__(self, namespace: str = "") -> None:
        if namespace:
            check_name(namespace, "namespace")
        self.namespace = namespace
        self._prefix = f"{namespace}/" if namespace else ""

    def _k(self, rest: str) -> str:
        return self._prefix + rest

    # -- the simulation's own keys
    @property
    def clock(self) -> str:
        return self._k("sim/clock")

    @property
    def poses(self) -> str:
        """Every robot's true pose at a tick, one message (:data:`POSES_TYPE`)."""
        return self._k("sim/poses")

    @property
    def reset(self) -> str:
        return self._k("sim/reset")

    @property
    def info(self) -> str:
        return self._k("sim/info")

    @property
    def end(self) -> str:
        """The plant's last word: the simulation ended normally (payload: reason)."""
        return self._k("sim/end")

    def alive(self, node: str = "*") -> str:
        return self._k(f"sim/alive/{node}")

    def sync(self, node: str = "*") -> str:
        return self._k(f"sim/sync/{node}")

    def ack(self, node: str = "*") -> str:
        return self._k(f"sim/ack/{node}")

    def seen(self, node: str = "*") -> str:
        """What a process that is not a member has taken in: a recorder's reports, which
        lockstep paces to, and the queryable the plant asks at a run's end (docs/PROTOCOL.md
        section 4, "Watchers that keep up", "End")."""
        return self._k(f"sim/seen/{node}")

    @property
    def all(self) -> str:
        """Every key of this simulation (for recorders and observers)."""
        return self._k("**")

    # -- FMU nodes (docs/fmu.md)
    def fmu(self, instance: str, variable: str) -> str:
        """``fmu/<instance>/<variable>``: an FMU node's variable (escaped)."""
        return self._k(fmu_topic(instance, variable))

    def fmu_info(self, instance: str = "*") -> str:
        """``fmu/<instance>/info``: the FMU node's queryable (``*``: every FMU node)."""
        return self._k(f"{FMU_ROOT}/{instance}/{FMU_INFO}")

    # -- robot topics
    def topic(self, robot: str, name: str) -> str:
        """A robot topic's key; an ``fmu/...`` name is bus-wide (the robot is not in it)."""
        if is_fmu_topic(name):
            return self._k(check_fmu_topic(name))
        if name not in TOPICS:
            raise BadName(f"unknown topic {name!r}; known: {', '.join(TOPICS)}")
        return self._k(f"{robot}/{TOPICS[name].suffix}")

    def robot_topic_of(self, key: str) -> tuple[str, str] | None:
        """Split a concrete key into (robot, topic name), or None if it is not a robot topic."""
        if self._prefix:
            if not key.startswith(self._prefix):
                return None
            key = key[len(self._prefix):]
        robot, _, suffix = key.partition("/")
        if robot in RESERVED or not suffix:
            return None
        for name, t in TOPICS.items():
            if t.suffix == suffix:
                return robot, name
        return None

    def node_of(self, key: str) -> str:
        """The last segment of a membership key (``.../sim/sync/<node>``)."""
        return str(key).rsplit("/", 1)[-1]

    def msgtype_of(self, key: str) -> str | None:
        """The ROS 2 message type carried on a concrete key, if it is one of ours."""
        if key == self.clock:
            return CLOCK_TYPE
        if key == self.poses:
            return POSES_TYPE
        rt = self.robot_topic_of(key)
        return TOPICS[rt[1]].msgtype if rt else None
