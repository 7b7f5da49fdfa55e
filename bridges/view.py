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
* ``/scene``, ``/tf_static`` (with ``world -> <robot>/odom``), ``/tf`` (:mod:`bridges.scene`,
  the same as in recordings) and ``/<robot>/robot_description`` (the URDF, :mod:`bridges.urdf`;
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

import itertools
import queue
import threading
import time
from collections import deque

import zenoh

from bus import codec

from . import scene, urdf
from bus.keys import TOPICS, Keys
from bus.log import RejectCounter
from bus.process import EXIT_OK
from bus.session import query_info, undeclare_all

from .view_clients import ClientInput
from .view_derived import Derived, Path, tracking_pairs

PATH_PERIOD_S = 0.5
TIME_PERIOD_S = 1 / 30
#: the loop's period: samples wait at most this long (s)
LOOP_S = 0.005
#: ... while no client watches anything
IDLE_LOOP_S = 0.05
#: samples of ground truth kept per robot to pair with odometry of the same stamp
_GT_KEEP = 64
RATE_LIMITED = ("camera/image_raw", "camera/camera_info")
#: what foxglove-sdk's server speaks (clients asking only for foxglove.websocket.v1 get 400)
SUBPROTOCOL = "foxglove.sdk.v1"
#: topics nodes publish: advertised when their first sample shows the scenario has them
NODE_TOPICS = ("odom", "cmd_vel", "wheel_cmd", "follower/debug")


def ros2msg_schema(msgtype: str):
    """A foxglove Schema with the full ROS 2 message definition (dependencies included)."""
    import foxglove
    msgdef, _ = codec.TYPESTORE.generate_msgdef(msgtype, ros_version=2)
    return foxglove.Schema(name=msgtype, encoding="ros2msg", data=msgdef.encode())


class View(Derived, ClientInput):
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

    # ------------------------------------------------------------------ loop
    def run(self) -> int:
        next_path = next_time = 0.0
        get = self.queue.get_nowait
        # Wake every LOOP_S and take what came in one batch: a wake-up per sample (thousands
        # a second) costs more than the work here.
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
        undeclare_all([*self._subs, *self._key_subs.values(), *self._probes.values()])
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
