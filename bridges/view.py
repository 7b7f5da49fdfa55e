"""``diffbot view``: the simulation live in Foxglove, and teleop from it.

A bus node that never holds lockstep (no ``sim/sync`` token): it advertises a channel
for every topic the plant's ``sim/info`` implies, listens on the bus only to the keys the
channels that clients watch need (nothing is watched: nothing but the clock flows to
it), and serves a Foxglove WebSocket (``foxglove-sdk``, subprotocol
``foxglove.sdk.v1``) on ``ws://127.0.0.1:8765`` by default (loopback only unless
``--host`` says otherwise). Channels, all ``cdr`` with full ``ros2msg`` schemas, so
Foxglove needs nothing installed:

* every bus topic as ``/<key>`` (``/robot1/odom``, ``/robot1/camera/image_raw``,
  ``/sim/clock`` ...), bytes unchanged: the same names and frames as on the bus, over ROS 2
  and in recordings (docs/ros2.md). The plant's topics are advertised from ``sim/info``;
  the nodes' topics (``odom``, ``cmd_vel``, ``wheel_cmd``, ``follower/debug``) once a first
  sample shows the scenario has them;
* ``/scene``, ``/tf_static`` (with ``world -> <robot>/odom``), ``/tf`` (:mod:`bus.scene`,
  the same as in recordings) and ``/<robot>/robot_description`` (the URDF, :mod:`bus.urdf`;
  Foxglove's 3D panel: add a URDF layer with this topic);
* ``/<robot>/path/{ground_truth,odom,gps}`` (``nav_msgs/Path``, 2 Hz wall);
* ``/<robot>/metrics/odometry_error_m`` (odometry vs ground truth, m) and
  ``/<robot>/metrics/tracking_distance_m`` (this robot's camera to another robot's ball);
* ``/<robot>/camera/image_annotated`` (when the robot's ``follower/debug`` exists): the
  camera image with the follower's detection drawn on it.

Costs: every key goes through a latest-only slot and leaves at most ``--rate`` times per
wall second (30; images and camera info ``--image-rate``, 15): what came in between is
dropped, never queued (a recording keeps every message; ``--rate 0`` forwards every
one but the images). Each client's queue is bounded (``--backlog`` messages, the oldest
dropped). Derived channels are computed only while a client subscribes to them, and
only for the samples that are sent. Measured: ``diffbot bench --suite view``.

Teleop: a client may publish ``geometry_msgs/msg/Twist`` on ``/<robot>/cmd_vel_unstamped``
(Foxglove's Teleop panel; the shipped layout's) or ``TwistStamped`` on ``/<robot>/cmd_vel``
(as over ROS 2), ``cdr`` or ``json`` encoded; it goes on the bus as the robot's
``cmd_vel`` (TwistStamped) stamped with the latest simulated time.
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import queue
import sys
import threading
import time
from collections import deque

import numpy as np
import zenoh

from bus import codec, scene, urdf
from bus.cliargs import ArgumentParser, nonneg_float, port, positive_float, positive_int
from bus.keys import TOPICS, Keys
from bus.log import RejectCounter, setup_logging
from bus.jsonio import write_json
from bus.runtime import EXIT_PLANT_GONE
from bus.session import close_session, install_stop_signals, query_info
from bus.session import BusConfigError, add_process_args, open_node

EXIT_OK = 0
EXIT_BAD_CONFIG = 2
#: paths: a point is added once the robot moved this far from the last one; at most this many
PATH_STEP_M = 0.02
PATH_MAX_POINTS = 5000
PATH_PERIOD_S = 0.5
TIME_PERIOD_S = 1 / 30
#: the loop's period: samples wait at most this long (s)
LOOP_S = 0.005
#: ... while no client watches anything
IDLE_LOOP_S = 0.05
#: samples of ground truth kept per robot to pair with odometry of the same stamp
_GT_KEEP = 64
TWIST_TYPES = ("geometry_msgs/msg/Twist", "geometry_msgs/Twist",
               "geometry_msgs/msg/TwistStamped", "geometry_msgs/TwistStamped")
RATE_LIMITED = ("camera/image_raw", "camera/camera_info")
RESET_SERVICE = "/reset_simulation"
#: an empty ROS 2 message in CDR: the encapsulation header and the one placeholder byte
EMPTY_CDR = b"\x00\x01\x00\x00\x00"
#: what foxglove-sdk's server speaks (clients asking only for foxglove.websocket.v1 get 400)
SUBPROTOCOL = "foxglove.sdk.v1"
#: topics nodes publish: advertised when their first sample shows the scenario has them
NODE_TOPICS = ("odom", "cmd_vel", "wheel_cmd", "follower/debug")


def ros2msg_schema(msgtype: str):
    """A foxglove Schema with the full ROS 2 message definition (dependencies included)."""
    import foxglove
    msgdef, _ = codec.TYPESTORE.generate_msgdef(msgtype, ros_version=2)
    return foxglove.Schema(name=msgtype, encoding="ros2msg", data=msgdef.encode())


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


class View:
    """The bus side and the Foxglove side of ``diffbot view`` (see the module docstring)."""

    def __init__(self, session: zenoh.Session, keys: Keys, log, name: str = "view",
                 image_rate_hz: float = 15.0, rate_hz: float = 30.0) -> None:
        self.session = session
        self.keys = keys
        self.log = log
        self.name = name
        self.image_period_s = 1.0 / image_rate_hz
        #: per-key send period (s) of everything but cameras; 0: every message
        self.period_s = 1.0 / rate_hz if rate_hz > 0 else 0.0
        self.rejects = RejectCounter(log)
        self.stop_event = threading.Event()
        self.queue: queue.SimpleQueue = queue.SimpleQueue()
        self.info: dict = {}
        self.channels: dict[str, object] = {}
        self.sent: dict[str, int] = {}
        self.teleop_in = 0
        self.resets = 0
        self.published: dict[str, int] = {}
        self.sim_ns = 0
        self._seq = itertools.count(1)
        self._slots: dict[str, tuple] = {}     # latest-only: key -> (payload, attachment)
        self._next: dict[str, float] = {}
        self._route: dict[str, object] = {}
        self._lock = threading.Lock()
        self._watched: dict[str, int] = {}      # channel topic -> clients subscribed
        self._deps: dict[str, set[str]] = {}    # channel topic -> bus keys it needs
        self._key_subs: dict[str, object] = {}  # bus key -> Zenoh subscriber
        self._resub = threading.Event()
        self._paths: dict[str, Path] = {}
        # (payload, attachment) as Zenoh handed them (ZBytes, copied only when used)
        self._gt: dict[str, deque] = {}                      # robot -> the last ground truths
        self._debug: dict[str, tuple] = {}                   # robot -> the last follower/debug
        self._found: set[str] = set()                        # node topics' keys seen
        self._probes: dict[str, object] = {}                 # key -> subscriber until seen
        self._resend = threading.Event()
        self._client_channels: dict[tuple[int, int], tuple[str, str, str]] = {}
        self._subs: list = []
        self._token = None
        self._pairs: list = []
        self.server = None

    # ------------------------------------------------------------------ foxglove side
    def start_server(self, host: str, port: int, backlog: int):
        import foxglove
        from foxglove.websocket import Capability
        self.server = foxglove.start_server(
            name="diffbot-cosim", host=host, port=port, server_listener=self,
            capabilities=[Capability.ClientPublish, Capability.Time, Capability.Services],
            supported_encodings=["cdr", "json"], message_backlog_size=backlog,
            services=[self.reset_service()])
        return self.server

    def reset_service(self):
        """``/reset_simulation`` (``std_srvs/srv/Empty``, as over ROS 2) for Foxglove's
        Service Call panel: a ``sim/reset`` query with no arguments."""
        import foxglove
        from foxglove.websocket import MessageSchema, Service, ServiceSchema

        def schema(part: str):
            return MessageSchema(encoding="cdr", schema=foxglove.Schema(
                name=f"std_srvs/srv/Empty_{part}", encoding="ros2msg", data=b""))

        def handler(request) -> bytes:
            said = None
            for reply in self.session.get(self.keys.reset, timeout=5.0):
                if reply.ok is not None:
                    said = reply.ok.payload.to_bytes().decode("utf-8", "replace")
                else:
                    raise RuntimeError(reply.err.payload.to_bytes().decode("utf-8", "replace"))
            if said is None:
                raise RuntimeError(f"no plant answered {self.keys.reset}")
            self.log.info("%s: %s", RESET_SERVICE, said)
            self.resets += 1
            return b"{}" if request.encoding == "json" else EMPTY_CDR
        return Service(name=RESET_SERVICE, schema=ServiceSchema(
            name="std_srvs/srv/Empty", request=schema("Request"), response=schema("Response")),
            handler=handler)

    def topic_name(self, rest: str) -> str:
        return "/" + (f"{self.keys.namespace}/" if self.keys.namespace else "") + rest

    def channel(self, topic: str, msgtype: str):
        ch = self.channels.get(topic)
        if ch is None:
            import foxglove
            ch = self.channels[topic] = foxglove.Channel(
                topic, message_encoding="cdr", schema=ros2msg_schema(msgtype))
        return ch

    def send(self, topic: str, msgtype: str, data: bytes, t_ns: int) -> None:
        self.channel(topic, msgtype).log(data, log_time=t_ns)
        self.sent[topic] = self.sent.get(topic, 0) + 1

    def wanted(self, topic: str, msgtype: str) -> bool:
        """Declare the channel and say whether any client subscribes to it."""
        return self.channel(topic, msgtype).has_sinks()

    # ServerListener: called from the server's threads
    def on_subscribe(self, client, channel) -> None:
        with self._lock:
            self._watched[channel.topic] = self._watched.get(channel.topic, 0) + 1
        self._resub.set()
        if channel.topic in (self.topic_name(scene.SCENE_TOPIC),
                             self.topic_name(scene.TF_STATIC_TOPIC)):
            self._resend.set()

    def on_unsubscribe(self, client, channel) -> None:
        with self._lock:
            n = self._watched.get(channel.topic, 0) - 1
            if n > 0:
                self._watched[channel.topic] = n
            else:
                self._watched.pop(channel.topic, None)
        self._resub.set()

    def on_client_advertise(self, client, channel) -> None:
        self._client_channels[(client.id, channel.id)] = (
            channel.topic, channel.encoding, channel.schema_name)

    def on_client_unadvertise(self, client, client_channel_id: int) -> None:
        self._client_channels.pop((client.id, client_channel_id), None)

    def on_message_data(self, client, client_channel_id: int, data: bytes) -> None:
        ch = self._client_channels.get((client.id, client_channel_id))
        if ch is None:
            self.rejects.reject("teleop", "data on a channel the client never advertised")
            return
        topic, encoding, schema = ch
        try:
            robot = self.teleop_robot(topic)
            v, w = parse_twist(bytes(data), encoding, schema)
        except ValueError as exc:
            self.rejects.reject("teleop", f"{topic}: {exc}")
            return
        t = self.sim_ns
        key = self.keys.topic(robot, "cmd_vel")
        self.session.put(key, codec.encode(codec.twist_stamped(t, v, w)),
                         encoding=zenoh.Encoding.APPLICATION_CDR,
                         attachment=codec.attachment(next(self._seq), t))
        self.teleop_in += 1
        self.published[key] = self.published.get(key, 0) + 1

    def teleop_robot(self, topic: str) -> str:
        """The robot a client's ``/<robot>/cmd_vel`` topic drives (ValueError if none)."""
        prefix = self.topic_name("")
        rest = topic[len(prefix):] if topic.startswith(prefix) else topic.lstrip("/")
        robot, _, suffix = rest.partition("/")
        if suffix not in ("cmd_vel", "cmd_vel_unstamped"):
            raise ValueError("teleop takes /<robot>/cmd_vel_unstamped (Twist) or "
                             "/<robot>/cmd_vel (TwistStamped)")
        if robot not in self.info.get("robots", {}):
            raise ValueError(f"no robot {robot!r} in the simulation "
                             f"(robots: {', '.join(self.info.get('robots', {})) or 'none'})")
        return robot

    # ------------------------------------------------------------------ bus side
    def subscribe(self) -> None:
        """Liveliness (the plant, our token) and the clock; the topics follow the clients
        (:meth:`resubscribe`)."""
        q = self.queue
        self._key_subs[self.keys.clock] = self._declare(self.keys.clock)

        def on_plant(sample: zenoh.Sample) -> None:
            if sample.kind == zenoh.SampleKind.PUT:
                q.put(("plant", b"", None))
        self._subs.append(self.session.liveliness().declare_subscriber(
            self.keys.alive("plant"), zenoh.handlers.Callback(on_plant, indirect=False),
            history=True))
        self._token = self.session.liveliness().declare_token(self.keys.alive(self.name))

    def _declare(self, key: str):
        """A subscriber whose callback (in Zenoh's receive thread, no copy, no queue, no
        wake-up) keeps the latest sample in the key's slot; :meth:`flush` sends it."""
        slots = self._slots
        rt = self.route(key)
        if self.period_s == 0 and not (rt and rt[1] in RATE_LIMITED):
            q = self.queue

            def cb(sample: zenoh.Sample) -> None:      # --rate 0: every message, in order
                att = sample.attachment
                q.put((key, sample.payload.to_bytes(), att.to_bytes() if att is not None else None))
        elif rt is None:                                 # the clock: sim time for teleop
            def cb(sample: zenoh.Sample) -> None:
                item = (sample.payload, sample.attachment)
                a = codec.parse_attachment(item[1].to_bytes()) if item[1] is not None else None
                if a is not None:
                    self.sim_ns = a.t_ns
                slots[key] = item
        elif rt[1] == "ground_truth":                    # kept a while to pair with others
            hist = self._gt.setdefault(rt[0], deque(maxlen=_GT_KEEP))

            def cb(sample: zenoh.Sample) -> None:
                item = (sample.payload, sample.attachment)
                hist.append(item)
                slots[key] = item
        elif rt[1] == "follower/debug":
            debug, robot = self._debug, rt[0]

            def cb(sample: zenoh.Sample) -> None:
                item = (sample.payload, sample.attachment)
                debug[robot] = item
                slots[key] = item
        else:
            def cb(sample: zenoh.Sample) -> None:
                slots[key] = (sample.payload, sample.attachment)
        return self.session.declare_subscriber(key, zenoh.handlers.Callback(cb, indirect=False))

    def resubscribe(self) -> None:
        """Listen on the bus keys the watched channels need, and only those: a channel
        nobody watches costs nothing, not even its bytes over Zenoh."""
        with self._lock:
            watched = list(self._watched)
        need = {self.keys.clock}
        for topic in watched:
            need.update(self._deps.get(topic, ()))
        for key in [k for k in self._key_subs if k not in need]:
            try:
                self._key_subs.pop(key).undeclare()
            except Exception:
                pass
        for key in sorted(need - set(self._key_subs)):
            self._key_subs[key] = self._declare(key)

    def load_info(self, info: dict) -> None:
        """Take a plant's ``sim/info``: advertise every channel it implies (so a client can
        pick them before data flows) and what bus keys each one needs."""
        self.info = info
        self._pairs = tracking_pairs(info)
        k = self.keys
        deps: dict[str, set[str]] = {
            self.topic_name(scene.SCENE_TOPIC): set(),
            self.topic_name(scene.TF_STATIC_TOPIC): set(),
            self.topic_name(scene.TF_TOPIC): {k.topic(r, "ground_truth") for r in info["robots"]},
            "/" + k.clock: {k.clock},
        }
        types = {self.topic_name(scene.SCENE_TOPIC): scene.SCENE_TYPE,
                 self.topic_name(scene.TF_STATIC_TOPIC): scene.TF_TYPE,
                 self.topic_name(scene.TF_TOPIC): scene.TF_TYPE,
                 "/" + k.clock: "rosgraph_msgs/msg/Clock"}
        for r, ri in info.get("robots", {}).items():
            plant_topics = set(ri.get("topics") or {}) | {"joint_states", "gps", "ground_truth"}
            sensors = ri.get("sensors") or {}
            if sensors.get("lidar"):
                plant_topics.add("scan")
            if sensors.get("camera"):
                plant_topics |= {"camera/image_raw", "camera/camera_info"}
            found = {t for t in NODE_TOPICS if k.topic(r, t) in self._found}
            for topic in sorted(plant_topics | found):
                if topic in TOPICS:
                    key = k.topic(r, topic)
                    deps["/" + key], types["/" + key] = {key}, TOPICS[topic].msgtype
            gt, odom = k.topic(r, "ground_truth"), k.topic(r, "odom")
            derived = {f"{r}/path/ground_truth": ({gt}, "nav_msgs/msg/Path"),
                       f"{r}/path/gps": ({k.topic(r, "gps")}, "nav_msgs/msg/Path"),
                       f"{r}/{urdf.DESCRIPTION_TOPIC}": (set(), urdf.DESCRIPTION_TYPE)}
            if "odom" in found:
                derived[f"{r}/path/odom"] = ({odom}, "nav_msgs/msg/Path")
                derived[f"{r}/metrics/odometry_error_m"] = ({odom, gt}, "std_msgs/msg/Float64")
            if "camera/image_raw" in plant_topics and "follower/debug" in found:
                derived[f"{r}/camera/image_annotated"] = (
                    {k.topic(r, "camera/image_raw"), k.topic(r, "follower/debug")},
                    TOPICS["camera/image_raw"].msgtype)
            targets = [b for a, _, b, _ in self._pairs if a == r]
            if targets:
                derived[f"{r}/metrics/tracking_distance_m"] = (
                    {gt} | {k.topic(b, "ground_truth") for b in targets}, "std_msgs/msg/Float64")
            for rest, (keys_, msgtype) in derived.items():
                deps[self.topic_name(rest)], types[self.topic_name(rest)] = keys_, msgtype
        self._deps = deps
        for topic, msgtype in types.items():
            self.channel(topic, msgtype)
        self._probe(info)
        self._resub.set()
        self._resend.set()

    def _probe(self, info: dict) -> None:
        """Listen for the first sample of each node topic not seen yet (then stop: the
        channel, once advertised, is fed like any other)."""
        q = self.queue
        for r in info.get("robots", {}):
            for t in NODE_TOPICS:
                key = self.keys.topic(r, t)
                if key in self._found or key in self._probes:
                    continue

                def cb(sample: zenoh.Sample, key=key) -> None:
                    q.put(("found", key.encode(), None))
                self._probes[key] = self.session.declare_subscriber(
                    key, zenoh.handlers.Callback(cb, indirect=False))

    def found(self, key: str) -> None:
        """A node topic's first sample: advertise its channel and what derives from it."""
        probe = self._probes.pop(key, None)
        if probe is not None:
            probe.undeclare()
        if key in self._found:
            return
        self._found.add(key)
        self.log.info("%s appeared: advertising it", key)
        if self.info:
            self.load_info(self.info)

    def send_static(self) -> None:
        t = self.sim_ns
        self.send(self.topic_name(scene.SCENE_TOPIC), scene.SCENE_TYPE,
                  codec.encode(scene.scene(self.info, t)), t)
        self.send(self.topic_name(scene.TF_STATIC_TOPIC), scene.TF_TYPE,
                  codec.encode(scene.static_tf(self.info, t)), t)
        for r in self.info.get("robots", {}):
            self.send(self.topic_name(f"{r}/{urdf.DESCRIPTION_TOPIC}"), urdf.DESCRIPTION_TYPE,
                      codec.encode(urdf.description_message(self.info, r)), t)

    def route(self, key: str) -> tuple[str, str] | None:
        """(robot, topic) of a bus key, or None (the clock, keys that are no topic); cached."""
        r = self._route.get(key, False)
        if r is False:
            r = self._route[key] = (self.keys.robot_topic_of(key)
                                    if self.keys.msgtype_of(key) is not None else None)
        return r

    def handle(self, key: str, payload: bytes, att: bytes | None) -> None:
        """File one bus sample: into its key's latest-only slot (sent by :meth:`flush`), or
        straight through with ``--rate 0``. Costs nothing more than a dict store."""
        if key == "found":
            self.found(payload.decode())
            return
        if key == "plant":
            try:
                self.load_info(query_info(self.session, self.keys, 5.0))
                self.log.info("plant found: world %s, robots %s", self.info.get("world"),
                              ", ".join(self.info.get("robots", {})))
            except (TimeoutError, ValueError) as exc:
                self.log.warning("a plant appeared but %s", exc)
            return
        rt = self.route(key)
        if rt is None and key != self.keys.clock:
            return
        a = codec.parse_attachment(att)
        t = a.t_ns if a is not None else self.sim_ns
        if rt is None:
            self.sim_ns = t
        else:
            robot, topic = rt
            if topic == "ground_truth":
                self._gt.setdefault(robot, deque(maxlen=_GT_KEEP)).append((payload, att))
            elif topic == "follower/debug":
                self._debug[robot] = (payload, att)
        self.process(key, payload, t)

    def flush(self, now: float) -> None:
        """Send each key's latest sample once its period has passed (``--rate``, or
        ``--image-rate`` for cameras); what came in between was dropped, never queued."""
        for key in list(self._slots):
            if now < self._next.get(key, 0.0):
                continue
            item = self._slots.pop(key, None)         # the freshest (callbacks keep writing)
            if item is None:
                continue
            rt = self.route(key)
            image = rt is not None and rt[1] in RATE_LIMITED
            self._next[key] = now + (self.image_period_s if image else self.period_s)
            try:
                payload, t = self.unpack(item)
                self.process(key, payload, t)
            except Exception as exc:       # a bad sample never ends the view
                self.rejects.reject(key, f"{type(exc).__name__}: {exc}")

    def unpack(self, item) -> tuple[bytes, int]:
        """(payload bytes, sim-time stamp) of a kept (payload, attachment) pair."""
        payload, att = item
        if not isinstance(payload, bytes):
            payload = payload.to_bytes()
        if att is not None and not isinstance(att, bytes):
            att = att.to_bytes()
        a = codec.parse_attachment(att)
        return payload, (a.t_ns if a is not None else self.sim_ns)

    def process(self, key: str, payload: bytes, t: int) -> None:
        """Forward one sample (reframed if it is a scan or an image) and derive what hangs
        on it: /tf, paths, metrics, the annotated image."""
        msgtype = self.keys.msgtype_of(key)
        channel = "/" + key
        if key == self.keys.clock:
            self.send(channel, msgtype, payload, t)
            return
        robot, topic = self.keys.robot_topic_of(key)
        if topic == "camera/image_raw":
            self.annotated(robot, payload, t)
        if topic == "ground_truth":
            self.on_ground_truth(robot, payload, t)
        elif topic == "odom":
            self.on_odom(robot, payload, t)
        elif topic == "gps":
            if self.wanted(self.topic_name(f"{robot}/path/gps"), "nav_msgs/msg/Path"):
                m = self.decode(payload, msgtype, key)
                if m is not None:
                    self.path(robot, "gps").add(t, m.point.x, m.point.y, m.point.z)
        self.send(channel, msgtype, payload, t)

    def decode(self, payload: bytes, msgtype: str, key: str):
        try:
            return codec.decode(payload, msgtype)
        except codec.CodecError as exc:
            self.rejects.reject(key, str(exc))
            return None

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

    # ------------------------------------------------------------------ loop
    def run(self) -> int:
        next_path = next_time = 0.0
        get = self.queue.get_nowait
        # Wake every LOOP_S and take what came in one batch: a wake-up per sample (thousands
        # a second) costs more than the work here (FIELD_NOTES: halting vCPUs).
        while not self.stop_event.wait(LOOP_S if self._watched else IDLE_LOOP_S):
            for _ in range(20000):
                try:
                    item = get()
                except queue.Empty:
                    break
                try:
                    self.handle(*item)
                except Exception as exc:      # a bad sample never ends the view
                    self.rejects.reject("sample", f"{item[0]}: {type(exc).__name__}: {exc}")
            now = time.monotonic()
            if self._resub.is_set():
                self._resub.clear()
                self.resubscribe()
            if self._resend.is_set() and self.info:
                self._resend.clear()
                self.send_static()
            if self._slots:
                self.flush(now)
            if now >= next_path:
                next_path = now + PATH_PERIOD_S
                self.flush_paths()
            if now >= next_time and self.server is not None:
                next_time = now + TIME_PERIOD_S
                self.server.broadcast_time(self.sim_ns)
        return EXIT_OK

    def close(self) -> None:
        for s in [*self._subs, *self._key_subs.values(), *self._probes.values()]:
            try:
                s.undeclare()
            except Exception:
                pass
        self._subs.clear()
        self._key_subs.clear()
        self._probes.clear()
        if self._token is not None:
            self._token.undeclare()
            self._token = None
        if self.server is not None:
            self.server.stop()

    def stats(self) -> dict:
        return {"node": self.name, "sent": dict(sorted(self.sent.items())),
                "published": dict(self.published), "teleop_messages": self.teleop_in,
                "resets": self.resets,
                "cpu_s": time.process_time(),
                "rejected": dict(self.rejects.counts)}


def parse_twist(data: bytes, encoding: str, schema_name: str) -> tuple[float, float]:
    """(linear x m/s, angular z rad/s) of a client's Twist or TwistStamped; ValueError if bad."""
    if schema_name and schema_name not in TWIST_TYPES:
        raise ValueError(f"expected geometry_msgs/msg/Twist, got {schema_name!r}")
    stamped = "Stamped" in (schema_name or "")
    if encoding == "json":
        try:
            msg = json.loads(data)
            tw = msg["twist"] if stamped else msg
            v, w = float(tw["linear"]["x"]), float(tw["angular"]["z"])
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"not a JSON Twist: {exc}") from None
    elif encoding == "cdr":
        msgtype = "geometry_msgs/msg/TwistStamped" if stamped else "geometry_msgs/msg/Twist"
        try:
            m = codec.decode(data, msgtype)
        except codec.CodecError as exc:
            raise ValueError(str(exc)) from None
        tw = m.twist if stamped else m
        v, w = float(tw.linear.x), float(tw.angular.z)
    else:
        raise ValueError(f"unsupported encoding {encoding!r} (cdr, json)")
    if not (math.isfinite(v) and math.isfinite(w)):
        raise ValueError(f"non-finite twist ({v}, {w})")
    return v, w


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="diffbot view",
        description="Serve the simulation live to Foxglove (ws://HOST:PORT, subprotocol "
                    "foxglove.sdk.v1) and take teleop from it. Runs until Ctrl-C.")
    p.add_argument("--port", type=port, default=8765, help="WebSocket port (default 8765; "
                   "0 picks a free one, logged at start)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default 127.0.0.1: this machine only)")
    p.add_argument("--rate", type=nonneg_float, default=30.0, metavar="HZ",
                   help="send each topic's latest message at most this many times per wall "
                        "second (default 30; 0: every message). Recordings keep every one")
    p.add_argument("--image-rate", type=positive_float, default=15.0, metavar="HZ",
                   help="at most this many frames per second per camera (wall clock); "
                        "older frames are dropped (default 15)")
    p.add_argument("--backlog", type=positive_int, default=256, metavar="N",
                   help="messages queued per client before the oldest are dropped (default 256)")
    p.add_argument("--name", default="view", help="node name on the bus (default view)")
    p.add_argument("--info-timeout", type=positive_float, default=15.0, metavar="S",
                   help="wait this long for the plant at the start (default 15)")
    add_process_args(p)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    log = setup_logging(args.name, args.log_level)
    try:
        import foxglove  # noqa: F401
    except ImportError:
        log.error("diffbot view needs foxglove-sdk: pip install 'diffbot-cosim[view]'")
        return EXIT_BAD_CONFIG
    try:
        keys, session = open_node(args, args.name)
    except (BusConfigError, ValueError) as exc:
        log.error("%s", exc)
        return EXIT_BAD_CONFIG
    view = View(session, keys, log, args.name, args.image_rate, args.rate)
    install_stop_signals(view.stop_event)
    code = EXIT_OK
    try:
        try:
            view.load_info(query_info(session, keys, args.info_timeout))
        except (TimeoutError, ValueError) as exc:
            log.error("%s", exc)
            return EXIT_PLANT_GONE
        try:
            server = view.start_server(args.host, args.port, args.backlog)
        except Exception as exc:             # port in use, bad address
            log.error("cannot serve on %s:%d: %s", args.host, args.port, exc)
            return EXIT_BAD_CONFIG
        view.subscribe()
        log.info("serving ws://%s:%d, WebSocket subprotocol %s (Foxglove: Open connection -> "
                 "Foxglove WebSocket; layout bridges/foxglove_layout.json; docs/live-view.md); "
                 "world %s, robots %s", args.host, server.port, SUBPROTOCOL,
                 view.info.get("world"), ", ".join(view.info.get("robots", {})))
        code = view.run()
    finally:
        view.close()
        close_session(session, log)
        if args.stats:
            write_json(args.stats, view.stats())
    return code


if __name__ == "__main__":
    sys.exit(main())
