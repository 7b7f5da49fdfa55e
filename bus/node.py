"""The node API: a controller is an object with ``step(observation) -> command``.

:func:`run_node` does everything else: it opens the Zenoh session, learns the
simulation's mode from the plant (``sim/info``), subscribes to the controller's
inputs and ``sim/clock``, takes part in lockstep (liveliness token
``sim/sync/<node>``, an ack per tick), stamps and publishes the outputs, and
exits cleanly on Ctrl-C, SIGTERM, the controller finishing, or the plant going away.

A controller declares::

    inputs = ["joint_states", "odom"]   # topics of its robot it reads
    sync = True                         # holds the simulation in lockstep (default)
    def step(self, obs) -> Twist | WheelSpeeds | dict | None
    done = False                        # set True to stop the robot and exit 0

``step`` returns a :class:`Twist` (published as ``cmd_vel``), :class:`WheelSpeeds`
(``wheel_cmd``), a dict ``{topic: message}`` of other outputs, or None.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import zenoh

from . import codec
from .inbox import Inbox
from .keys import TOPICS, Keys, check_name
from .log import RejectCounter, setup_logging
from .session import BusConfigError, add_bus_args, open_session

WHEEL_JOINTS = ("left_wheel_joint", "right_wheel_joint")

EXIT_PLANT_GONE = 3
#: How long after the plant's liveliness vanished a node waits for its ``sim/end``.
END_GRACE_S = 0.3
EXIT_BAD_CONFIG = 2


@dataclass
class Twist:
    """Body velocity command: forward speed (m/s), yaw rate (rad/s, counter-clockwise)."""
    linear: float = 0.0
    angular: float = 0.0


@dataclass
class WheelSpeeds:
    """Wheel angular velocity command (rad/s, positive drives the robot forward)."""
    left: float = 0.0
    right: float = 0.0


@dataclass
class Observation:
    """What a controller sees at one tick: sim time and the latest message per input."""
    t_ns: int
    robot: str
    msgs: dict[str, Any] = field(default_factory=dict)

    @property
    def t(self) -> float:
        """Simulated time, s."""
        return self.t_ns * 1e-9

    def __getitem__(self, topic: str):
        return self.msgs.get(topic)

    def get(self, topic: str, default=None):
        return self.msgs.get(topic, default)


def query_info(session: zenoh.Session, keys: Keys, timeout_s: float = 15.0) -> dict:
    """Ask the plant for ``sim/info``; retry until it answers or ``timeout_s`` passes."""
    deadline = time.monotonic() + timeout_s
    while True:
        for reply in session.get(keys.info, timeout=1.0):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        if time.monotonic() > deadline:
            raise TimeoutError(f"no plant answered {keys.info} within {timeout_s:.0f} s")
        time.sleep(0.1)


class NodeRunner:
    """Runs one controller object on the bus (see module docstring)."""

    def __init__(self, controller, robot: str, name: str, session: zenoh.Session, keys: Keys,
                 log: logging.Logger, wait_for_plant_s: float = 15.0) -> None:
        self.controller = controller
        self.robot = check_name(robot, "robot name")
        self.name = check_name(name, "node name")
        self.session = session
        self.keys = keys
        self.log = log
        self.inputs = list(getattr(controller, "inputs", ()))
        for topic in self.inputs:
            if topic not in TOPICS:
                raise ValueError(f"{type(controller).__name__}.inputs: unknown topic {topic!r}")
        self.rejects = RejectCounter(log)
        self.stop_event = threading.Event()
        self.exit_code = 0
        self.published: dict[str, int] = {}
        self.ticks = 0
        self._seq = 0
        self.info = query_info(session, keys, wait_for_plant_s)
        self.mode = self.info.get("mode", "lockstep")
        self.sync = bool(getattr(controller, "sync", True)) and self.mode == "lockstep"
        if robot not in self.info.get("robots", {}):
            raise ValueError(f"robot {robot!r} is not in the plant's world "
                             f"(robots: {', '.join(self.info.get('robots', {})) or 'none'})")
        self.tick_ns = int(round(self.info.get("control_tick_s", 0.0) * 1e9))
        # Sensors the plant publishes every `period` ticks; node outputs come every tick.
        self.periods = dict(self.info["robots"][robot].get("topics", {}))
        self.awaited = [t for t in self.inputs
                        if TOPICS[t].source != "plant" or t in self.periods]
        self._tick_keys: list[str] = []
        if hasattr(controller, "configure"):
            controller.configure(self.info, robot)

    # ----------------------------------------------------------------- output
    def _put(self, key: str, msg, t_ns: int) -> None:
        self._seq += 1
        self._tick_keys.append(key)
        self.session.put(key, codec.encode(msg), encoding=zenoh.Encoding.APPLICATION_CDR,
                         congestion_control=zenoh.CongestionControl.BLOCK,
                         attachment=codec.attachment(self._seq, t_ns))
        self.published[key] = self.published.get(key, 0) + 1

    def publish(self, out, t_ns: int) -> None:
        if out is None:
            return
        if isinstance(out, Twist):
            self._put(self.keys.topic(self.robot, "cmd_vel"),
                      codec.twist_stamped(t_ns, out.linear, out.angular), t_ns)
        elif isinstance(out, WheelSpeeds):
            self._put(self.keys.topic(self.robot, "wheel_cmd"),
                      codec.joint_state(t_ns, WHEEL_JOINTS, velocity=(out.left, out.right)), t_ns)
        elif isinstance(out, dict):
            for topic, msg in out.items():
                self._put(self.keys.topic(self.robot, topic), msg, t_ns)
        else:
            raise TypeError(f"step() returned {type(out).__name__}; expected Twist, "
                            "WheelSpeeds, dict or None")

    def ack(self, t_ns: int, final: bool = False) -> None:
        """Tell the plant this node is done with tick ``t_ns``: the stamp, whether it is the
        node's last, and the keys it published for the tick (the plant waits for those too)."""
        if self.sync:
            self.session.put(self.keys.ack(self.name),
                             encode_ack(t_ns, self._tick_keys, final))
        self._tick_keys = []

    def due_inputs(self, t_ns: int) -> list[str]:
        """The inputs that must carry stamp ``t_ns`` before the node acts on that tick:
        outputs of other lockstep nodes, and the plant's sensors due at this tick."""
        k = t_ns // self.tick_ns if self.tick_ns else 0
        return [t for t in self.awaited if k % self.periods.get(t, 1) == 0]

    # ----------------------------------------------------------------- loop
    def run(self, max_ticks: int | None = None) -> int:
        inbox = Inbox(self.session)
        topic_of = {self.keys.topic(self.robot, t): t for t in self.inputs}
        for key in topic_of:
            inbox.subscribe(key, "input")
        inbox.subscribe(self.keys.clock, "clock")
        inbox.subscribe(self.keys.end, "end")
        inbox.watch_liveliness(self.keys.alive("plant"), "plant")
        tokens = [self.session.liveliness().declare_token(self.keys.alive(self.name))]
        if self.sync:
            tokens.append(self.session.liveliness().declare_token(self.keys.sync(self.name)))
        latest: dict[str, Any] = {}
        stamps: dict[str, int] = {}
        pending: int | None = None
        plant_seen = False
        gone_at = 0.0
        self.log.info("%s on robot %s: mode %s, inputs %s%s", self.name, self.robot, self.mode,
                      ", ".join(self.inputs) or "none", ", lockstep member" if self.sync else "")
        try:
            while not self.stop_event.is_set():
                ev = inbox.get(timeout=0.05 if gone_at else 0.2)
                if gone_at and time.monotonic() - gone_at > END_GRACE_S:
                    self.log.error("the plant is gone; stopping")
                    self.exit_code = EXIT_PLANT_GONE
                    break
                if ev is None:
                    continue
                if ev.tag == "end":
                    self.log.info("the simulation ended (%s); stopping",
                                  ev.payload.decode("utf-8", "replace"))
                    break
                if ev.tag == "plant":
                    if ev.alive:
                        plant_seen, gone_at = True, 0.0
                    elif plant_seen:
                        # Its liveliness may overtake its last word (sim/end): wait a moment.
                        gone_at = time.monotonic()
                    continue
                if ev.tag == "clock":
                    try:
                        t_ns = codec.msg_stamp_ns(codec.decode(ev.payload, "rosgraph_msgs/msg/Clock"))
                    except codec.CodecError as exc:
                        self.rejects.reject("clock", str(exc))
                        continue
                    pending = t_ns
                else:
                    topic = topic_of.get(ev.key)
                    try:
                        msg = codec.decode(ev.payload, TOPICS[topic].msgtype)
                    except codec.CodecError as exc:
                        self.rejects.reject(topic, str(exc))
                        continue
                    latest[topic] = msg
                    stamps[topic] = codec.msg_stamp_ns(msg)
                if pending is None:
                    continue
                if self.sync and any(stamps.get(t) != pending for t in self.due_inputs(pending)):
                    continue
                t_ns, pending = pending, None
                obs = Observation(t_ns, self.robot, dict(latest))
                out = self.controller.step(obs)
                self.publish(out, t_ns)
                self.ticks += 1
                if getattr(self.controller, "done", False):
                    self.publish(self._stop_command(), t_ns)
                    self.ack(t_ns, final=True)
                    self.log.info("%s done at t=%.3f s", self.name, t_ns * 1e-9)
                    break
                self.ack(t_ns)
                if max_ticks is not None and self.ticks >= max_ticks:
                    break
        finally:
            for tok in tokens:
                tok.undeclare()
            inbox.close()
        return self.exit_code

    def _stop_command(self):
        stop = getattr(self.controller, "stop_command", None)
        return stop() if callable(stop) else Twist(0.0, 0.0)

    def stats(self) -> dict:
        return {"node": self.name, "robot": self.robot, "ticks": self.ticks,
                "published": self.published, "rejected": dict(self.rejects.counts),
                "exit_code": self.exit_code}


def encode_ack(t_ns: int, keys: list[str], final: bool = False) -> bytes:
    """Ack payload: tick stamp (uint64 LE), b"F" if it is the node's last tick else b"-",
    then the keys the node published for the tick, comma-separated."""
    return t_ns.to_bytes(8, "little") + (b"F" if final else b"-") + ",".join(keys).encode()


def decode_ack(payload: bytes) -> tuple[int, list[str], bool]:
    """(tick stamp, keys published for it, final); raises ValueError if malformed."""
    if len(payload) < 9 or payload[8:9] not in (b"F", b"-"):
        raise ValueError(f"malformed ack of {len(payload)} bytes")
    rest = payload[9:].decode("utf-8")
    return (int.from_bytes(payload[:8], "little"), [k for k in rest.split(",") if k],
            payload[8:9] == b"F")


def node_arg_parser(description: str, default_name: str | None = None) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--robot", default="robot1", help="robot to control (default robot1)")
    p.add_argument("--name", default=default_name,
                   help="node name on the bus (default <controller>_<robot>)")
    p.add_argument("--stats", metavar="FILE", help="write the node's counters as JSON at exit")
    p.add_argument("--log-level", default="INFO")
    add_bus_args(p)
    return p


def install_stop_signals(stop_event: threading.Event) -> None:
    """SIGINT/SIGTERM end the loop cleanly (the session is closed on the way out)."""
    def handler(signum, frame):
        stop_event.set()
    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


def run_node(controller, robot: str | None = None, argv: list[str] | None = None,
             name: str | None = None) -> int:
    """Run ``controller`` as a bus node; parse the standard options from ``argv``.

    Returns the exit code (0 when stopped or done, 2 on bad configuration,
    3 when the plant went away).
    """
    base = getattr(controller, "name", type(controller).__name__.lower())
    parser = node_arg_parser(f"{base} controller")
    if robot is not None:
        parser.set_defaults(robot=robot)
    args = parser.parse_args(argv)
    return run_node_args(controller, args, name or args.name or f"{base}_{args.robot}")


def run_node_args(controller, args: argparse.Namespace, name: str) -> int:
    log = setup_logging(name, args.log_level)
    try:
        keys = Keys(args.namespace)
        session = open_session("node", args.endpoint, args.zenoh_config)
    except (BusConfigError, ValueError) as exc:
        log.error("%s", exc)
        return EXIT_BAD_CONFIG
    runner = None
    try:
        try:
            runner = NodeRunner(controller, args.robot, name, session, keys, log)
        except TimeoutError as exc:
            log.error("%s", exc)
            return EXIT_PLANT_GONE
        except ValueError as exc:
            log.error("%s", exc)
            return EXIT_BAD_CONFIG
        install_stop_signals(runner.stop_event)
        return runner.run()
    finally:
        if runner is not None and getattr(args, "stats", None):
            write_json(args.stats, runner.stats())
        session.close()


def write_json(path: str, data: dict) -> None:
    """Write JSON atomically (a reader never sees half a file)."""
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as f:
        json.dump(data, f, indent=2, default=_json_default)
        f.write("\n")
    os.replace(tmp, path)


def _json_default(o):
    if isinstance(o, float) and not math.isfinite(o):
        return None
    try:
        import numpy as np
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
    except ImportError:
        pass
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
