"""`diffbot ros2`: the bus <-> ROS 2 bridge, one rclpy node plus one Zenoh session.

The names and frames are the bus's (one table: docs/ros2.md). Out to ROS 2 (the bus's CDR
bytes pass through unchanged, no decode/re-encode): ``/clock`` and, per robot under
``/<robot>/``: ``scan``, ``camera/image_raw``, ``camera/camera_info``, ``joint_states``,
``odom`` (frame ``<robot>/odom``), ``ground_truth`` (nav_msgs/Odometry in ``world``),
``gps`` (geometry_msgs/PointStamped) and ``robot_description`` (std_msgs/String, the URDF,
transient local). In from ROS 2: ``/<robot>/cmd_vel`` (geometry_msgs/TwistStamped, as
ROS 2 Jazzy's diff_drive_controller takes it), ``/<robot>/cmd_vel_unstamped`` (plain
geometry_msgs/Twist, what teleop_twist_keyboard sends with ``-r cmd_vel:=...``; stamped
with the current sim time) and ``/<robot>/wheel_cmd`` (sensor_msgs/JointState, velocity
in rad/s). Commands with non-finite or absurd numbers are rejected and counted. The
service ``/reset_simulation`` (std_srvs/srv/Empty, Gazebo's name) resets the simulation
through ``sim/reset``. ``/tf`` is not published: ``tf2_msgs`` has no PyPI wheel (the
recordings and the live view carry it).

``--lockstep``: the bridge is a lockstep member of the simulation (bus.runtime.NodeRunner).
At each tick it hands the ROS 2 controller its trigger input (``odom`` by default) and
``/clock``, and waits for the controller's TwistStamped on ``cmd_vel`` stamped with the
trigger's stamp; that command goes to the plant with the tick's ACK. Until the controller has answered once, the bridge hands the
tick's other sensors (scan, GPS, ...) over again with the trigger every RESEND_S, so a node
started late that waits for its first scan does not hang the run; it logs what it waits
for. When the controller leaves the ROS graph (finished or killed) the bridge stops its
robot and leaves the simulation like any finished node.
"""
from __future__ import annotations

import argparse
import math
import os
import struct
import threading
import time

from bus import codec, urdf
from bus.cliargs import ArgumentParser
from bus.jsonio import write_stats
from bus.keys import Keys, check_name
from bus.log import RejectCounter, setup_logging
from bus.inputs import ABSURD_INPUT
from bus.runtime import EXIT_BAD_CONFIG, EXIT_PLANT_GONE, NodeRunner
from bus.session import close_session, install_stop_signals, query_info
from bus.session import BusConfigError, add_bus_args, open_node

from .ros2_types import OUT_TOPICS, ros_modules

#: how often the lockstep wait checks for stop and for the controller leaving the graph
_POLL_S = 0.05
#: (--lockstep) the trigger is handed over again after this long without an answer
RESEND_S = 0.5
#: plain geometry_msgs/Twist goes here (one type per topic: cmd_vel is TwistStamped)
UNSTAMPED = "cmd_vel_unstamped"
#: a wrong-sized TwistStamped is rejected before it is looked at
_TWIST6 = struct.Struct("<6d")


def domain_id_arg(value: str) -> int:
    n = int(value)
    if not 0 <= n <= 232:
        raise argparse.ArgumentTypeError(f"--domain-id must be 0..232 (0..101 is safe), got {n}")
    return n


def build_parser() -> ArgumentParser:
    p = ArgumentParser(prog="diffbot ros2", description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", default=None,
                   help="comma-separated robots to bridge (default: every robot of the world)")
    p.add_argument("--lockstep", action="store_true",
                   help="take part in lockstep: wait for the ROS 2 controller's command each tick")
    p.add_argument("--trigger", default="odom", choices=sorted(OUT_TOPICS),
                   help="(--lockstep) the input handed to the ROS 2 controller each tick, whose "
                        "stamp its command carries (default odom)")
    p.add_argument("--domain-id", type=domain_id_arg, default=None,
                   help="ROS_DOMAIN_ID (default: the environment's, else 0)")
    p.add_argument("--name", default="ros2_bridge", help="node name on the bus and in ROS 2")
    p.add_argument("--stats", default=None, metavar="FILE.json",
                   help="write forwarded/rejected counts here on exit")
    p.add_argument("--log-level", default="INFO")
    add_bus_args(p)
    return p


def _finite_twist(data: bytes) -> str | None:
    """Why a TwistStamped CDR is refused, or None (its six doubles are its last 48 bytes)."""
    if len(data) < 4 + 8 + 4 + 48:
        return "short TwistStamped"
    vals = _TWIST6.unpack_from(data, len(data) - 48)
    if not all(math.isfinite(v) and abs(v) < ABSURD_INPUT for v in vals):
        return "non-finite or absurd cmd_vel"
    return None


class Bridge:
    """The rclpy node and the Zenoh side; forwards in both directions."""

    def __init__(self, args, session, keys: Keys, info: dict, log) -> None:
        self.ros = ros_modules()
        rclpy = self.ros.rclpy
        self.log = log
        self.session = session
        self.keys = keys
        self.lockstep = bool(args.lockstep)
        self.trigger = args.trigger
        known = list(info.get("robots", {}))
        self.robots = args.robots.split(",") if args.robots else known
        for r in self.robots:
            check_name(r, "robot name")
            if r not in known:
                raise ValueError(f"robot {r!r} is not in the plant's world "
                                 f"(robots: {', '.join(known) or 'none'})")
        self.rejects = RejectCounter(log)
        self.forwarded: dict[str, int] = {}
        self.t_ns = 0                      # last sim/clock seen
        self._seq = 0
        self._lock = threading.Lock()
        # lockstep: robot -> {stamp_ns: TwistStamped CDR bytes}
        self.cmds: dict[str, dict[int, bytes]] = {r: {} for r in self.robots}
        self.cond = threading.Condition()
        self._had: dict[str, bool] = {}
        self.resends = 0    # lockstep: the controller was seen
        self.published: dict[str, int] = {}        # bus key -> messages put on the bus
        self.latest: dict[str, bytes] = {}          # bus key -> its last sample (re-sent)
        self.answered: set[str] = set()             # robots whose controller answered once
        self.closing = False
        self.info = info
        self.node = self._participant(args.name, args.domain_id)
        self._zsubs = []
        self._pubs: dict[str, object] = {}
        self._zpubs: dict[str, object] = {}
        self._setup_out()
        self._setup_in()
        self._spins = [threading.Thread(target=self._spin_loop, args=(self.node,), daemon=True)]
        for t in self._spins:
            t.start()

    def _participant(self, name: str, domain_id: int | None):
        rclpy = self.ros.rclpy
        context = rclpy.context.Context()
        rclpy.init(context=context, domain_id=domain_id,
                   signal_handler_options=self.ros.SignalHandlerOptions.NO)
        node = rclpy.create_node(name, context=context)
        node.executor_ = rclpy.executors.SingleThreadedExecutor(context=context)
        node.executor_.add_node(node)
        return node

    # ------------------------------------------------------------------ bus -> ROS 2
    def _setup_out(self) -> None:
        ros = self.ros
        self.clock_pub = self.node.create_publisher(ros.Clock, "/clock", ros.qos_clock)
        self._zsubs.append(self.session.declare_subscriber(self.keys.clock, self._on_clock))
        for robot in self.robots:
            for bus_topic, (ros_name, msg) in OUT_TOPICS.items():
                if self.lockstep and bus_topic == self.trigger:
                    continue                       # handed over tick by tick by the controller
                pub = self.node.create_publisher(getattr(ros, msg), f"/{robot}/{ros_name}",
                                                 ros.qos_sensor)
                self._pubs[self.keys.topic(robot, bus_topic)] = pub
                self._zsubs.append(self.session.declare_subscriber(
                    self.keys.topic(robot, bus_topic), self._on_bus))
            desc = self.node.create_publisher(ros.String, f"/{robot}/{urdf.DESCRIPTION_TOPIC}",
                                              ros.qos_latched)
            desc.publish(ros.String(data=urdf.robot_urdf(self.info, robot)))
            self._pubs[f"/{robot}/{urdf.DESCRIPTION_TOPIC}"] = desc
        self.node.create_service(ros.Empty, "/reset_simulation", self._on_reset)

    def _count(self, what: str) -> None:
        with self._lock:
            self.forwarded[what] = self.forwarded.get(what, 0) + 1

    def _on_clock(self, sample) -> None:
        data = bytes(sample.payload)
        if len(data) == 12:
            sec, nsec = struct.unpack_from("<iI", data, 4)
            self.t_ns = sec * 1_000_000_000 + nsec
        if not self.lockstep:                      # in lockstep /clock follows the trigger
            self._publish(self.clock_pub, data)

    def _on_bus(self, sample) -> None:
        key = str(sample.key_expr)
        pub = self._pubs.get(key)
        if pub is not None:
            data = bytes(sample.payload)
            if self.lockstep:
                self.latest[key] = data
            self._publish(pub, data)

    def _publish(self, pub, data: bytes) -> None:
        """Publish and count; a Zenoh callback racing the shutdown is dropped, not raised."""
        if self.closing:
            return
        try:
            pub.publish(data)
        except Exception:      # rclpy's InvalidHandle once the node is being destroyed
            if not self.closing:
                raise
            return
        self._count(pub.topic_name)

    def resend_latest(self, robot: str) -> None:
        """Hand a robot's last sensor samples over again (a node that joined late)."""
        prefix = self.keys.topic(robot, "scan").rsplit("/", 1)[0] + "/"
        for key, data in list(self.latest.items()):
            if key.startswith(prefix):
                self._publish(self._pubs[key], data)

    def _on_reset(self, request, response):
        """``/reset_simulation``: ``sim/reset`` with no arguments (start poses, same seed)."""
        said = None
        for reply in self.session.get(self.keys.reset, timeout=5.0):
            if reply.ok is not None:
                said = reply.ok.payload.to_bytes().decode("utf-8", "replace")
            else:
                said = "error: " + reply.err.payload.to_bytes().decode("utf-8", "replace")
        self.log.info("/reset_simulation: %s", said or "no plant answered sim/reset")
        self._count("/reset_simulation")
        return response

    # ------------------------------------------------------------------ ROS 2 -> bus
    def _setup_in(self) -> None:
        ros = self.ros
        for robot in self.robots:
            self.node.create_subscription(
                ros.TwistStamped, f"/{robot}/cmd_vel",
                lambda data, r=robot: self._on_cmd(r, data), ros.qos_cmd, raw=True)
            self.node.create_subscription(
                ros.Twist, f"/{robot}/{UNSTAMPED}",
                lambda data, r=robot: self._on_twist(r, data), ros.qos_cmd, raw=True)
            self.node.create_subscription(
                ros.JointState, f"/{robot}/wheel_cmd",
                lambda data, r=robot: self._on_wheels(r, data), ros.qos_cmd, raw=True)

    def _put(self, robot: str, topic: str, data: bytes, t_ns: int) -> None:
        key = self.keys.topic(robot, topic)
        pub = self._zpubs.get(key)
        if pub is None:
            pub = self._zpubs[key] = self.session.declare_publisher(key)
        with self._lock:
            self._seq += 1
            seq = self._seq
        pub.put(data, attachment=codec.attachment(seq, t_ns))
        self._count(f"/{robot}/{topic}")
        with self._lock:
            self.published[key] = self.published.get(key, 0) + 1

    def _on_cmd(self, robot: str, data: bytes) -> None:
        why = _finite_twist(data)
        if why is None:
            try:
                msg = codec.decode(data, "geometry_msgs/msg/TwistStamped")
            except codec.CodecError as exc:
                why = str(exc)
        if why is not None:
            self.rejects.reject(why, f"/{robot}/cmd_vel")
            return
        stamp = codec.stamp_ns(msg.header.stamp)
        if self.lockstep:
            with self.cond:
                self.cmds[robot][stamp] = data
                self.cond.notify_all()
            return
        self._put(robot, "cmd_vel", data, stamp or self.t_ns)

    def _on_twist(self, robot: str, data: bytes) -> None:
        try:
            t = codec.decode(data, "geometry_msgs/msg/Twist")
        except codec.CodecError as exc:
            self.rejects.reject(str(exc), f"/{robot}/{UNSTAMPED}")
            return
        t_ns = self.t_ns
        out = codec.encode(codec.twist_stamped(t_ns, t.linear.x, t.angular.z))
        if self.lockstep:
            self.rejects.reject("unstamped Twist in lockstep (send TwistStamped on cmd_vel)",
                                f"/{robot}/{UNSTAMPED}")
            return
        self._on_cmd(robot, out)

    def _on_wheels(self, robot: str, data: bytes) -> None:
        try:
            m = codec.decode(data, "sensor_msgs/msg/JointState")
            vals = [float(v) for v in m.velocity]
            if len(vals) != 2 or not all(math.isfinite(v) and abs(v) < ABSURD_INPUT for v in vals):
                raise codec.CodecError("wheel_cmd needs two finite velocities")
        except codec.CodecError as exc:
            self.rejects.reject(str(exc), f"/{robot}/wheel_cmd")
            return
        self._put(robot, "wheel_cmd", data, codec.stamp_ns(m.header.stamp) or self.t_ns)

    # ------------------------------------------------------------------ lockstep
    def controller_for(self, robot: str) -> "_RosController":
        return _RosController(self, robot)

    def command_for(self, robot: str, stamp_ns: int, stop: threading.Event,
                    resend) -> bytes | None:
        """Wait for the ROS 2 controller's command stamped ``stamp_ns``; None if it left.
        ``resend()`` hands the trigger over again every RESEND_S without an answer (a
        controller not discovered yet, a lost best-effort sample)."""
        topic = f"/{robot}/cmd_vel"
        seen = False
        sent = time.monotonic()
        said = sent - 3.0                      # the first word after 2 s, then every 5 s
        with self.cond:
            while not stop.is_set():
                cmds = self.cmds[robot]
                if stamp_ns in cmds:
                    data = cmds.pop(stamp_ns)
                    for s in [s for s in cmds if s < stamp_ns]:
                        del cmds[s]
                    self._had[robot] = True            # it answered: it was there
                    if robot not in self.answered:
                        self.answered.add(robot)
                        self.log.info("%s: the ROS 2 controller answered (t=%.3f s)", topic,
                                      stamp_ns * 1e-9)
                    return data
                n = self.node.count_publishers(topic)
                if n:
                    seen = True
                    self._had[robot] = True
                elif self._had.get(robot):
                    self.log.info("%s: the ROS 2 controller left the graph", topic)
                    return None
                now = time.monotonic()
                if now - sent > RESEND_S:
                    resend()
                    if robot not in self.answered:     # a late node: its first inputs too
                        self.resend_latest(robot)
                    sent = now
                    self.resends += 1
                if now - said > 5.0:
                    self.log.info("waiting for a TwistStamped on %s stamped t=%.3f s (%s; "
                                  "handing /%s/%s and the tick's sensors over again every "
                                  "%.1f s)", topic, stamp_ns * 1e-9,
                                  "a publisher is there" if seen else "no ROS 2 publisher yet",
                                  robot, OUT_TOPICS[self.trigger][0], RESEND_S)
                    said = time.monotonic()
                self.cond.wait(_POLL_S)
        return None

    # ------------------------------------------------------------------ life cycle
    def _spin_loop(self, node) -> None:
        context = node.context
        try:
            while context.ok():
                node.executor_.spin_once(timeout_sec=0.1)
        except Exception as exc:  # the context shut down under us at exit
            if context.ok():
                self.log.error("rclpy executor: %s", exc)

    def stats(self) -> dict:
        with self._lock:
            return {"forwarded": dict(self.forwarded), "published": dict(self.published),
                    "rejected": dict(self.rejects.counts),
                    "rejected_total": self.rejects.total, "lockstep_resends": self.resends}

    def close(self) -> None:
        for sub in self._zsubs:
            sub.undeclare()
        self._zsubs = []
        self.closing = True
        for node in (self.node,):
            context = node.context
            try:
                node.executor_.shutdown(timeout_sec=1.0)
                node.destroy_node()
            finally:
                context.try_shutdown()
        for t in self._spins:
            t.join(2.0)


class _RosController:
    """A bus.node controller whose step is answered by a ROS 2 node."""
    sync = True
    check_inputs = True

    def __init__(self, bridge: Bridge, robot: str) -> None:
        self.bridge = bridge
        self.robot = robot
        self.inputs = [bridge.trigger]
        self.done = False
        ros_name, msg = OUT_TOPICS[bridge.trigger]
        # reliable: a best-effort subscriber (qos_profile_sensor_data) matches it as well
        self.pub = bridge.node.create_publisher(getattr(bridge.ros, msg), f"/{robot}/{ros_name}",
                                                bridge.ros.qos_cmd)
        self.stop = threading.Event()

    def step(self, obs):
        b = self.bridge
        trig = obs[b.trigger]
        if trig is None:
            return None
        stamp = codec.stamp_ns(trig.header.stamp)
        clock, data = codec.encode(codec.clock(obs.t_ns)), codec.encode(trig)

        def hand_over() -> None:
            b._publish(b.clock_pub, clock)
            b._publish(self.pub, data)
        hand_over()
        data = b.command_for(self.robot, stamp, self.stop, hand_over)
        if data is None:
            self.done = True
            return None
        cmd = codec.decode(data, "geometry_msgs/msg/TwistStamped")
        # on the bus a command carries the tick it answers (the plant files it by stamp)
        cmd.header.stamp = codec.time_msg(obs.t_ns)
        return {"cmd_vel": cmd}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    log = setup_logging(args.name, args.log_level)
    try:
        ros_modules()
    except ImportError as exc:
        log.error("rclpy is not importable (%s): `pip install -e '.[ros2]'` or source a "
                  "ROS 2 setup (Humble, Jazzy)", exc)
        return EXIT_BAD_CONFIG
    try:
        keys, session = open_node(args, args.name)
    except (BusConfigError, ValueError) as exc:
        log.error("%s", exc)
        return EXIT_BAD_CONFIG
    bridge = None
    stop = threading.Event()
    try:
        try:
            info = query_info(session, keys)
            bridge = Bridge(args, session, keys, info, log)
        except TimeoutError as exc:
            log.error("%s", exc)
            return EXIT_PLANT_GONE
        except ValueError as exc:
            log.error("%s", exc)
            return EXIT_BAD_CONFIG
        log.info("bridging %s to ROS 2 (domain %s, %s)", ",".join(bridge.robots),
                 args.domain_id if args.domain_id is not None
                 else os.environ.get("ROS_DOMAIN_ID", "0"),
                 "lockstep" if args.lockstep else "free running")
        if args.lockstep and info.get("mode") == "lockstep":
            ctrls = {r: bridge.controller_for(r) for r in bridge.robots}
            runner = NodeRunner(lambda r: ctrls[r], None, args.name, session, keys, log,
                                robots=bridge.robots)
            install_stop_signals(runner.stop_event)
            threading.Thread(target=_relay_stop, args=(runner.stop_event, ctrls), daemon=True).start()
            try:
                return runner.run()
            finally:       # the commands went on the bus through the runner: count them
                for key, n in runner.published.items():
                    bridge.published[key] = bridge.published.get(key, 0) + n
        install_stop_signals(stop)
        return _free_run(session, keys, args.name, stop, log)
    except KeyboardInterrupt:
        return 0
    finally:
        stats = bridge.stats() if bridge is not None else None
        try:
            if bridge is not None:
                bridge.close()
        finally:                        # the session always closes (else the exit hangs)
            close_session(session, log)
        write_stats(args.stats, stats, log)


def _free_run(session, keys: Keys, name: str, stop: threading.Event, log) -> int:
    """Forward until stopped or the plant goes (exit 3, like a node)."""
    import zenoh
    liveliness = session.liveliness()
    token = liveliness.declare_token(keys.alive(name))
    plant_gone = threading.Event()

    def on_plant(sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE:
            plant_gone.set()
            stop.set()
    ended = threading.Event()

    def on_end(sample) -> None:
        ended.set()
        stop.set()
    # the plant's last word comes before its token goes: a normal end is not a lost plant
    watches = [session.declare_subscriber(keys.end, on_end),
               liveliness.declare_subscriber(keys.end, on_end),
               liveliness.declare_subscriber(keys.alive("plant"), on_plant, history=True)]
    try:
        while not stop.wait(0.2):
            pass
    finally:
        for w in watches:
            w.undeclare()
        token.undeclare()
    if ended.wait(0.2 if plant_gone.is_set() else 0.0):   # the two watches may race
        log.info("the simulation ended")
        return 0
    if plant_gone.is_set():
        log.info("the plant went away")
        return EXIT_PLANT_GONE
    return 0


def _relay_stop(stop: threading.Event, ctrls: dict) -> None:
    stop.wait()
    for c in ctrls.values():
        c.stop.set()
