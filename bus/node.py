"""The node API: a controller is an object with ``step(observation) -> command``.

:func:`run_node` does everything else: it opens the Zenoh session, learns the
simulation's mode from the plant (``sim/info``), subscribes to the controller's
inputs and ``sim/clock``, takes part in lockstep (liveliness token
``sim/sync/<node>``, an ack per tick), stamps and publishes the outputs, and
exits cleanly on Ctrl-C, SIGTERM, the controller finishing, or the plant going away.

One node may drive several robots (``--robots r0,r1`` or ``run_node(..., robots=[...])``):
one controller object per robot (a factory makes them, or the given object is copied),
one session, one lockstep member that acks each tick once for all its robots, each
robot's inputs awaited separately; the node finishes when every controller is done.

A controller declares::

    inputs = ["joint_states", "odom"]   # topics of its robot it reads
    sync = True                         # holds the simulation in lockstep (default)
    def step(self, obs) -> Twist | WheelSpeeds | dict | None
    done = False                        # set True to stop the robot and exit 0

``step`` returns a :class:`Twist` (published as ``cmd_vel``), :class:`WheelSpeeds`
(``wheel_cmd``), a dict ``{topic: message}`` of other outputs (a Twist or WheelSpeeds
value in it, under any key, is the command), or None.

Faults (see the README's "What happens when ..."): the plant is watched through its
liveliness token, so a killed plant is noticed within milliseconds and a frozen one
(SIGSTOP) within the 1 s lease; the node then exits 3, or with ``--wait`` waits for a
plant to come back, re-reads ``sim/info`` and carries on (this node's controller object
keeps its state). A node that was itself frozen longer than the lease has been dropped by
the simulation; when it resumes it sees the plant gone and exits 3 (with ``--wait`` it
rejoins at the current tick). Inputs are filed by stamp, so stray, stale or forged
samples never displace the one a tick needs; bad values are rejected and counted, and
the tick goes on with the last good message (``check_inputs = False`` on a controller
that validates its own). A lockstep node that waits for another node's output after
that node left exits 4 instead of holding the simulation forever.
"""
from __future__ import annotations

import argparse
import copy
import inspect
import json
import logging
import math
import signal
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from . import codec
from .cliargs import ArgumentParser
from .inbox import Inbox
from .jsonio import write_json  # noqa: F401  (re-exported: controllers import it from here)
from .keys import TOPICS, Keys, check_name
from .protocol import PLANT_READS, check_version
from .log import RejectCounter, setup_logging
from .session import BusConfigError, add_bus_args, make_config, open_session

WHEEL_JOINTS = ("left_wheel_joint", "right_wheel_joint")

EXIT_PLANT_GONE = 3
#: a lockstep node whose awaited input comes from a node that left (it would wait forever)
EXIT_INPUT_GONE = 4

#: the Zenoh lease (bus.session.DEFAULT_LEASE_MS): a peer silent for longer is dropped
LEASE_S = 1.0
#: how long a lockstep node waits for another node's output once a member has left
PRODUCER_GRACE_S = 0.5
#: an input older than this (simulated s, or three of its periods) is not shown to the
#: controller: its producer is gone (realtime and fast modes, where nobody waits for it)
STALE_S = 0.5
#: samples kept per input topic (by stamp) and clock ticks waiting for their inputs
_BUF_PER_TOPIC = 8
_PENDING_MAX = 16
#: input values beyond this magnitude are absurd (m, rad, m/s, rad/s ...): rejected
ABSURD_INPUT = 1e9
_HELD = object()     # "a bad sample came for this tick": the tick goes on, the last good is held
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


@dataclass
class _Slot:
    """One robot a node drives: its controller object and what it reads."""
    robot: str
    controller: Any
    inputs: list[str]
    check_inputs: bool
    periods: dict[str, int] = field(default_factory=dict)
    awaited: list[str] = field(default_factory=list)
    done: bool = False


def make_controllers(controller, robots: list[str]) -> list:
    """One controller object per robot. ``controller`` is either an object with ``step``
    (one robot: used as it is; several: one deep copy per robot, made before any runs) or
    a factory: a class or callable, called once per robot with the robot name if it takes
    a parameter, else with none."""
    if hasattr(controller, "step") and not isinstance(controller, type):
        if len(robots) == 1:
            return [controller]
        try:
            return [copy.deepcopy(controller) for _ in robots]
        except Exception as exc:
            raise ValueError(f"{type(controller).__name__} cannot drive several robots: it "
                             f"cannot be copied ({exc}); pass a factory instead") from None
    if not callable(controller):
        raise ValueError(f"{controller!r} is neither a controller (an object with step) "
                         "nor a factory of controllers")
    try:
        takes_robot = bool(inspect.signature(controller).parameters)
    except (TypeError, ValueError):
        takes_robot = False
    return [controller(r) if takes_robot else controller() for r in robots]


class NodeRunner:
    """Runs controller objects on the bus as one node: one per robot (module docstring)."""

    def __init__(self, controller, robot: str | None, name: str, session: zenoh.Session,
                 keys: Keys, log: logging.Logger, wait_for_plant_s: float = 15.0,
                 wait: bool = False, robots: list[str] | None = None) -> None:
        robots = list(robots) if robots else [robot or "robot1"]
        for r in robots:
            check_name(r, "robot name")
        if len(set(robots)) != len(robots):
            raise ValueError(f"a robot is named twice in {','.join(robots)}")
        self.robots = robots
        self.robot = robots[0]
        self.name = check_name(name, "node name")
        self.session = session
        self.keys = keys
        self.log = log
        #: --wait: when the plant goes away, wait for it to come back instead of exiting 3
        self.wait = wait
        self.slots: list[_Slot] = []
        ctrls = make_controllers(controller, robots)
        # the topic catalog, plus the bus-wide ``fmu/...`` keys a controller declares in
        # ``topics`` ({name: bus.keys.Topic}; message types without a header are stamped by
        # the attachment)
        self.topics = dict(TOPICS)
        for ctrl in ctrls:
            self.topics.update(getattr(ctrl, "topics", {}))
        for r, ctrl in zip(robots, ctrls):
            inputs = list(getattr(ctrl, "inputs", ()))
            for topic in inputs:
                if topic not in self.topics:
                    raise ValueError(f"{type(ctrl).__name__}.inputs: unknown topic {topic!r}")
            # inputs with non-finite or absurd numbers, or wrong joint names, are rejected
            # here unless the controller validates its own (``check_inputs = False``)
            self.slots.append(_Slot(r, ctrl, inputs, bool(getattr(ctrl, "check_inputs", True))))
        self.controller = self.slots[0].controller
        self.inputs = self.slots[0].inputs
        self.rejects = RejectCounter(log)
        self.stop_event = threading.Event()
        self.exit_code = 0
        self.published: dict[str, int] = {}
        self.ticks = 0
        self.final_tick: int | None = None   # the tick at which the last controller finished
        self.plant_lost = 0           # times the plant went away while --wait kept us here
        self._seq = 0
        # the current tick's outputs, not sent yet: (key, message, read by the plant)
        self._out: list[tuple[str, Any, bool]] = []
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._keys: dict[tuple[str, str], str] = {}
        # input key -> (slot, topic); filled by run()
        self._topic_of: dict[str, tuple[_Slot, str]] = {}
        self._apply_info(query_info(session, keys, wait_for_plant_s))
        for slot in self.slots:
            if hasattr(slot.controller, "configure"):
                slot.controller.configure(self.info, slot.robot)
            if hasattr(slot.controller, "on_session"):   # e.g. to declare a queryable
                slot.controller.on_session(session, keys)

    def _apply_info(self, info: dict) -> None:
        """Take the simulation's protocol, mode, coupling, tick and sensor periods from the
        plant's ``sim/info`` (a plant of another protocol version is a ProtocolError)."""
        check_version(info)
        self.info = info
        self.mode = info.get("mode", "lockstep")
        self.coupling = info.get("coupling", "sequential")
        self.sync = self.mode == "lockstep" and all(
            bool(getattr(s.controller, "sync", True)) for s in self.slots)
        robots = info.get("robots", {})
        for slot in self.slots:
            if slot.robot not in robots:
                raise ValueError(f"robot {slot.robot!r} is not in the plant's world "
                                 f"(robots: {', '.join(robots) or 'none'})")
            # Sensors the plant publishes every `period` ticks; node outputs come every tick.
            slot.periods = dict(robots[slot.robot].get("topics", {}))
            slot.awaited = [t for t in slot.inputs
                            if self.topics[t].awaited or t in slot.periods]
        self.periods = self.slots[0].periods
        self.tick_ns = int(round(info.get("control_tick_s", 0.0) * 1e9))
        # Pipelined coupling: other nodes' outputs are taken one tick old, so producer and
        # consumer work on the same tick in parallel (docs/PROTOCOL.md).
        lag = int(info.get("node_input_delay_ticks", 0)) * self.tick_ns if self.sync else 0
        self.lag_ns = {t: lag if v.awaited else 0 for t, v in self.topics.items()}

    def _key(self, robot: str, topic: str) -> str:
        key = self._keys.get((robot, topic))
        if key is None:
            key = self._keys[robot, topic] = self.keys.topic(robot, topic)
        return key

    # ----------------------------------------------------------------- output
    def publish(self, out, t_ns: int, robot: str | None = None) -> None:
        """Queue what ``step`` returned for tick ``t_ns`` (for ``robot``, by default the
        first); :meth:`flush` sends it."""
        if out is None:
            return
        robot = robot or self.robot
        if isinstance(out, Twist):
            self._out.append((self._key(robot, "cmd_vel"),
                              codec.twist_stamped(t_ns, out.linear, out.angular), True))
        elif isinstance(out, WheelSpeeds):
            self._out.append((self._key(robot, "wheel_cmd"),
                              codec.joint_state(t_ns, WHEEL_JOINTS,
                                                velocity=(out.left, out.right)), True))
        elif isinstance(out, dict):
            for topic, msg in out.items():
                if isinstance(msg, (Twist, WheelSpeeds)):     # a command among other outputs
                    self.publish(msg, t_ns, robot)
                else:
                    self._out.append((self._key(robot, topic), msg, topic in PLANT_READS))
        else:
            raise TypeError(f"step() returned {type(out).__name__}; expected Twist, "
                            "WheelSpeeds, dict or None")

    def flush(self, t_ns: int, final: bool = False) -> None:
        """Send the tick's outputs (of every robot). A lockstep member (docs/PROTOCOL.md)
        stamps each with its trailer, sends the keys the plant reads last, and sets ACK on
        the very last of those: one message per tick for a node with one command, one per
        robot for a node with several. Only a member with no such output sends an empty
        ``sim/ack/<node>`` instead."""
        out, self._out = self._out, []
        if not self.sync:
            for key, msg, _ in out:
                self._put(key, codec.encode(msg), codec.attachment(self._next_seq(), t_ns))
            return
        out.sort(key=lambda o: o[2])                  # stable: plant-read last, robot order
        n_plant = sum(1 for o in out if o[2])
        end = codec.ACK | (codec.FINAL if final else 0)
        for i, (key, msg, _) in enumerate(out):
            last = n_plant and i == len(out) - 1
            att = codec.attachment(self._next_seq(), t_ns, end if last else 0,
                                   n_plant if last else 0, self.name)
            self._put(key, codec.encode(msg), att)
        if not n_plant:
            self._put(self.keys.ack(self.name), b"",
                      codec.attachment(self._next_seq(), t_ns, end, 0, self.name))

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq

    def _put(self, key: str, payload: bytes, att: bytes) -> None:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self.session.declare_publisher(
                key, encoding=zenoh.Encoding.APPLICATION_CDR,
                congestion_control=zenoh.CongestionControl.BLOCK)
        pub.put(payload, attachment=att)
        self.published[key] = self.published.get(key, 0) + 1

    def _needs(self, slot: _Slot, t_ns: int) -> list[tuple[str, str, int]]:
        """(input key, topic, stamp) a robot needs before the node acts on tick ``t_ns``:
        the plant's sensors due at this tick, and outputs of other lockstep nodes (stamped
        ``t_ns``, or one tick earlier in pipelined coupling: none at the first tick)."""
        k = t_ns // self.tick_ns if self.tick_ns else 0
        return [(self._key(slot.robot, t), t, t_ns - self.lag_ns[t]) for t in slot.awaited
                if k % slot.periods.get(t, 1) == 0 and t_ns - self.lag_ns[t] >= 0]

    def due_inputs(self, t_ns: int) -> list[str]:
        """The first robot's inputs that must be in before the node acts on tick ``t_ns``."""
        return [t for _, t, _ in self._needs(self.slots[0], t_ns)]

    # ----------------------------------------------------------------- input
    def _input(self, key: str, payload: bytes, att: bytes | None = None) -> None:
        """Decode and check one input sample, and file it under its stamp.

        Samples are kept by stamp (a few per key), so a late, early or forged sample
        never displaces the one a tick needs. A sample that decodes but carries bad
        values (NaN, inf, absurd magnitudes, wrong joint names) is rejected and *held*:
        its tick still happens and the controller sees the topic's last good message.
        """
        slot, topic = self._topic_of[key]
        try:
            msg = codec.decode(payload, self.topics[topic].msgtype)
        except codec.CodecError as exc:
            self.rejects.reject(topic, str(exc))
            return
        stamp, problem = _stamp_of(msg, self.tick_ns, att, self._last_clock)
        if problem:
            self.rejects.reject(topic, problem)
            return
        buf = self._buf.setdefault(key, {})
        if slot.check_inputs and (problem := check_input(topic, msg)):
            self.rejects.reject(topic, f"{problem} (t={stamp * 1e-9:.3f} s; holding the last "
                                       "good one)")
            buf.setdefault(stamp, _HELD)       # never replaces a good sample of the tick
        else:
            buf[stamp] = msg
            self._used.discard((key, stamp))    # a new sample for that tick (a reset)
        if len(buf) > _BUF_PER_TOPIC:          # drop what lies farthest from the clock
            ref = self._last_clock if self._last_clock is not None else stamp
            del buf[max(buf, key=lambda s: abs(s - ref))]

    def _clock(self, payload: bytes) -> int | None:
        try:
            msg = codec.decode(payload, "rosgraph_msgs/msg/Clock")
        except codec.CodecError as exc:
            self.rejects.reject("clock", str(exc))
            return None
        t_ns, problem = _stamp_of(msg, self.tick_ns)
        if problem:
            self.rejects.reject("clock", problem)
            return None
        self._last_clock = t_ns
        return t_ns

    def _complete(self, t_ns: int) -> bool:
        """Every robot still driven has, for every input due at ``t_ns``, a sample (good or
        held) of the stamp it needs that this node has not acted on yet."""
        return all(s in self._buf.get(key, ()) and (key, s) not in self._used
                   for slot in self.slots if not slot.done
                   for key, _, s in self._needs(slot, t_ns))

    def _observation(self, slot: _Slot, t_ns: int) -> Observation:
        """The latest good message of each of a robot's inputs stamped at or before ``t_ns``
        (a tick earlier for a lagged one), unless it is stale (older than ``STALE_S`` or
        three of its periods: its producer is gone), so a controller never steers on a dead
        input; older ones and held marks are dropped."""
        msgs = {}
        for topic in slot.inputs:
            key = self._key(slot.robot, topic)
            buf = self._buf.get(key)
            if not buf:
                continue
            upto = t_ns - self.lag_ns[topic]       # a lagged input never shows a newer sample
            good = [s for s, m in buf.items() if s <= upto and m is not _HELD]
            if good:
                best = max(good)
                stale_ns = max(STALE_S * 1e9, 3 * slot.periods.get(topic, 1) * self.tick_ns)
                if upto - best <= stale_ns:
                    msgs[topic] = buf[best]
            else:
                best = None
            for s in [s for s, m in buf.items()
                      if s <= upto and (s != best) and (best is None or s < best or m is _HELD)]:
                del buf[s]
            self._used.add((key, upto))
        if len(self._used) > 4 * _BUF_PER_TOPIC * max(1, len(self._topic_of)):
            self._used = {(k, s) for k, s in self._used if s >= t_ns - self.tick_ns}
        return Observation(t_ns, slot.robot, msgs)

    def _reset_inputs(self) -> None:
        self._buf: dict[str, dict[int, Any]] = {}
        self._used: set[tuple[str, int]] = set()
        self._pending: dict[int, float] = {}   # lockstep: clock stamp -> wall time it came
        self._last_clock: int | None = None

    # ----------------------------------------------------------------- loop
    def run(self, max_ticks: int | None = None) -> int:
        inbox = Inbox(self.session)
        self._topic_of = {self._key(s.robot, t): (s, t) for s in self.slots for t in s.inputs}
        for key in self._topic_of:
            inbox.subscribe(key, "input")
        inbox.subscribe(self.keys.clock, "clock")
        inbox.subscribe(self.keys.end, "end")
        # The plant also declares sim/end as a liveliness token before it withdraws
        # sim/alive/plant: declarations stay in order, so the end is seen before the absence.
        inbox.watch_liveliness(self.keys.end, "end")
        inbox.watch_liveliness(self.keys.alive("plant"), "plant")
        inbox.watch_liveliness(self.keys.sync(), "member")
        liveliness = self.session.liveliness()
        tokens = {"alive": liveliness.declare_token(self.keys.alive(self.name))}
        if self.sync:
            tokens["sync"] = liveliness.declare_token(self.keys.sync(self.name))
        self._reset_inputs()
        plant_seen = plant_here = False
        left: dict[str, float] = {}          # lockstep members that left -> wall time
        last_loop, stalled, stall_s = time.monotonic(), -math.inf, 0.0
        self.log.info("%s on robot%s %s: mode %s, inputs %s%s", self.name,
                      "s" if len(self.slots) > 1 else "", ", ".join(self.robots), self.mode,
                      ", ".join(self.inputs) or "none", ", lockstep member" if self.sync else "")
        try:
            while not self.stop_event.is_set():
                ev = inbox.get(timeout=0.2)
                now = time.monotonic()
                if now - last_loop > LEASE_S:      # this process was stopped (SIGSTOP) or starved
                    stall_s, stalled = now - last_loop, now
                last_loop = now
                if ev is None:
                    if self.sync and self._producer_gone(left, now):
                        break
                    continue
                if ev.tag == "end":
                    if not ev.alive or (not plant_here and not ev.payload):
                        continue             # the end token withdrawn, or a repeat of the end
                    reason = ev.payload.decode("utf-8", "replace") or "the plant ended it"
                    if self.wait:
                        self.log.warning("the simulation ended (%s); waiting for a plant "
                                         "(--wait)", reason)
                        plant_here = False
                        self._reset_inputs()
                        continue
                    self.log.info("the simulation ended (%s); stopping", reason)
                    break
                if ev.tag == "plant":
                    if ev.alive:
                        if plant_seen and not plant_here:
                            if not self._plant_back(tokens):
                                break
                        plant_seen = plant_here = True
                    elif plant_here:
                        plant_here = False
                        self._reset_inputs()
                        if self.wait:
                            self.plant_lost += 1
                            self.log.warning("the plant is gone; waiting for it to come back "
                                             "(--wait)")
                            continue
                        if now - stalled < 5.0:
                            self.log.error("the plant is gone: this process was stopped for "
                                           "%.1f s, longer than the %.0f s bus lease, so the "
                                           "simulation dropped it; stopping", stall_s, LEASE_S)
                        else:
                            self.log.error("the plant is gone; stopping")
                        self.exit_code = EXIT_PLANT_GONE
                        break
                    continue
                if ev.tag == "member":
                    node = self.keys.node_of(ev.key)
                    if not ev.alive and node != self.name:
                        left[node] = now
                    elif ev.alive:
                        left.pop(node, None)
                    continue
                if ev.tag == "clock":
                    t_ns = self._clock(ev.payload)
                    if t_ns is None:
                        continue
                    if not self.sync:
                        if self._act(t_ns):
                            break
                        if max_ticks is not None and self.ticks >= max_ticks:
                            break
                        continue
                    self._pending[t_ns] = now
                    if len(self._pending) > _PENDING_MAX:
                        old = next(iter(self._pending))
                        del self._pending[old]
                        self.rejects.reject("clock", f"tick t={old * 1e-9:.3f} s never "
                                                     "completed (a stray clock?)")
                else:
                    self._input(ev.key, ev.payload, ev.attachment)
                    if not self.sync:
                        continue
                finished = False
                for t_ns in [t for t in self._pending if self._complete(t)]:
                    del self._pending[t_ns]
                    if self._act(t_ns):
                        finished = True
                        break
                    if max_ticks is not None and self.ticks >= max_ticks:
                        finished = True
                        break
                if finished:
                    break
            if self.final_tick is not None and self.sync:
                self._linger(inbox, self.final_tick)
        finally:
            for tok in tokens.values():
                tok.undeclare()
            inbox.close()
        return self.exit_code

    def _linger(self, inbox: Inbox, t_done: int, timeout_s: float = 2.0) -> None:
        """After the final ack, stay in the lockstep set until the plant has taken it: it
        publishes a tick past ``t_done`` plus the actuation delay (pipelined: the plant
        publishes t_done + 1 tick before it looks at the acks of t_done), or ends. Leaving
        earlier would let the token's withdrawal overtake the ack, and the plant would step
        on without knowing this node finished."""
        t_done += int(self.info.get("actuation_delay_ticks", 0)) * self.tick_ns
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not self.stop_event.is_set():
            ev = inbox.get(timeout=0.05)
            if ev is None:
                continue
            if ev.tag == "end" or (ev.tag == "plant" and not ev.alive):
                return
            if ev.tag == "clock":
                t = self._clock(ev.payload)
                if t is not None and t > t_done:
                    return

    def _act(self, t_ns: int) -> bool:
        """Step every robot's controller at tick ``t_ns``, publish, ack (one ack for all);
        True once every controller is done. A robot whose controller is done is sent its
        stop command every tick until the others are."""
        for slot in self.slots:
            if slot.done:
                self.publish(self._stop_command(slot), t_ns, slot.robot)
                continue
            self.publish(slot.controller.step(self._observation(slot, t_ns)), t_ns, slot.robot)
            if getattr(slot.controller, "done", False):
                slot.done = True
                self.publish(self._stop_command(slot), t_ns, slot.robot)
                self.log.info("%s%s done at t=%.3f s", self.name,
                              f" ({slot.robot})" if len(self.slots) > 1 else "", t_ns * 1e-9)
        self.ticks += 1
        finished = all(slot.done for slot in self.slots)
        self.flush(t_ns, final=finished)
        if finished:
            self.final_tick = t_ns
        return finished

    def _plant_back(self, tokens: dict) -> bool:
        """A plant is there again (--wait): learn its mode and carry on. False to stop."""
        try:
            self._apply_info(query_info(self.session, self.keys, 15.0))
        except (TimeoutError, ValueError) as exc:
            self.log.error("a plant came back but %s; stopping", exc)
            self.exit_code = EXIT_PLANT_GONE
            return False
        if self.sync and "sync" not in tokens:
            tokens["sync"] = self.session.liveliness().declare_token(self.keys.sync(self.name))
        elif not self.sync and "sync" in tokens:
            tokens.pop("sync").undeclare()
        self._reset_inputs()
        self.log.warning("the plant is back (%s mode, t=%.3f s); carrying on", self.mode,
                         self.info.get("time_ns", 0) * 1e-9)
        return True

    def _producer_gone(self, left: dict[str, float], now: float) -> bool:
        """Lockstep: a tick has every plant sensor it needs but waits for another node's
        output, and a member left the simulation since: that output will never come."""
        if not left or not self._pending:
            return False
        for t_ns, came in self._pending.items():
            missing = [tp for slot in self.slots if not slot.done
                       for key, tp, s in self._needs(slot, t_ns)
                       if s not in self._buf.get(key, ())]
            if not missing or any(not self.topics[tp].awaited for tp in missing):
                continue
            gone = [n for n, w in left.items() if w >= came - PRODUCER_GRACE_S]
            if gone and now - max(came, max(left[n] for n in gone)) > PRODUCER_GRACE_S:
                self.log.error("no %s for t=%.3f s: lockstep member %s left the simulation, "
                               "so it will never come; stopping", ", ".join(missing),
                               t_ns * 1e-9, ", ".join(sorted(gone)))
                self.exit_code = EXIT_INPUT_GONE
                return True
        return False

    def _stop_command(self, slot: _Slot | None = None):
        stop = getattr((slot or self.slots[0]).controller, "stop_command", None)
        return stop() if callable(stop) else Twist(0.0, 0.0)

    def stats(self) -> dict:
        return {"node": self.name, "robot": self.robot, "robots": self.robots,
                "ticks": self.ticks,
                "published": self.published, "rejected": dict(self.rejects.counts),
                "plant_lost": self.plant_lost, "exit_code": self.exit_code}


def _stamp_of(msg, tick_ns: int, att: bytes | None = None,
              last_clock: int | None = None) -> tuple[int, str | None]:
    """(stamp in ns, problem or None): stamps must be valid times on the tick grid. A
    message with no header (std_msgs) has the attachment's stamp, or without one the
    last clock tick (it came "now")."""
    if hasattr(msg, "header") or hasattr(msg, "clock"):
        st = msg.header.stamp if hasattr(msg, "header") else msg.clock
        if st.sec < 0 or not 0 <= st.nanosec < 1_000_000_000:
            return 0, f"invalid stamp ({st.sec} s, {st.nanosec} ns)"
        t_ns = codec.stamp_ns(st)
    else:
        a = codec.parse_attachment(att)
        t_ns = a.t_ns if a else (last_clock or 0)
    if tick_ns and t_ns % tick_ns:
        return t_ns, (f"stamp t={t_ns * 1e-9:.9f} s is not on the {tick_ns * 1e-6:g} ms "
                      "tick grid")
    return t_ns, None


#: fields where inf / NaN are legitimate (REP 117: no return) or that are not numbers
_FREE_FIELDS = {"ranges", "intensities", "data"}


def check_input(topic: str, msg) -> str | None:
    """Why an input message is unusable (non-finite or absurd numbers, wrong joint names),
    or None. Laser ranges may be inf or NaN (no return); covariances need only be finite."""
    if topic == "joint_states":
        names = list(msg.name)
        if names != list(WHEEL_JOINTS):
            return f"joint names {names} are not {list(WHEEL_JOINTS)}"
        if len(msg.position) != 2 or len(msg.velocity) not in (0, 2):
            return (f"expected 2 positions (and 0 or 2 velocities), got {len(msg.position)} "
                    f"and {len(msg.velocity)}")
    return _numbers_problem(msg, "")


def _numbers_problem(msg, where: str) -> str | None:
    for name in msg.__dataclass_fields__:
        if name.startswith("__") or name in _FREE_FIELDS:
            continue
        v = getattr(msg, name)
        path = f"{where}{name}"
        if isinstance(v, float):
            if not math.isfinite(v) or abs(v) > ABSURD_INPUT:
                return f"{path} = {v!r}"
        elif isinstance(v, np.ndarray):
            if v.dtype.kind == "f" and v.size:
                if not np.isfinite(v).all():
                    return f"{path} is not finite"
                if "covariance" not in name and np.abs(v).max() > ABSURD_INPUT:
                    return f"{path} has absurd values (max |v| {np.abs(v).max():.3g})"
        elif hasattr(v, "__dataclass_fields__"):
            if (p := _numbers_problem(v, path + ".")) is not None:
                return p
        elif isinstance(v, list):
            for i, item in enumerate(v):
                if hasattr(item, "__dataclass_fields__") and \
                        (p := _numbers_problem(item, f"{path}[{i}].")) is not None:
                    return p
    return None


def node_arg_parser(description: str, default_name: str | None = None) -> argparse.ArgumentParser:
    p = _NodeParser(description=description)
    p.add_argument("--robot", default="robot1", type=_name_arg("robot name"),
                   help="robot to control (default robot1)")
    p.add_argument("--robots", default=None, type=_names_arg, metavar="R1,R2,...",
                   help="drive several robots from this one process: one controller object "
                        "per robot, one lockstep member (the default node name uses the "
                        "first robot)")
    p.add_argument("--name", default=default_name, type=_name_arg("node name"),
                   help="node name on the bus (default <controller>_<robot>)")
    p.add_argument("--stats", metavar="FILE", help="write the node's counters as JSON at exit")
    p.add_argument("--log-level", default="INFO")
    p.add_argument("--wait", action="store_true",
                   help="if the plant is not there yet or goes away (killed, frozen, "
                        "restarted), wait for it and carry on when it is back, instead of "
                        "exiting with code 3")
    add_bus_args(p)
    return p


def _name_arg(what: str):
    """argparse type: a name that is one safe key segment (no '*', '$', '/', not empty)."""
    def check(value: str) -> str:
        try:
            return check_name(value, what)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    check.__name__ = what
    return check


class _NodeParser(ArgumentParser):
    """With ``--robots``, ``args.robot`` is the first of them (default node names use it)."""

    def parse_known_args(self, args=None, namespace=None):
        ns, rest = super().parse_known_args(args, namespace)
        if getattr(ns, "robots", None):
            ns.robot = ns.robots[0]
        return ns, rest


def _names_arg(value: str) -> list[str]:
    """argparse type: comma-separated robot names, each one safe key segment, no repeats."""
    names = [v.strip() for v in value.split(",") if v.strip()]
    if not names:
        raise argparse.ArgumentTypeError("expected robot names, e.g. r0,r1")
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"a robot is named twice in {value!r}")
    check = _name_arg("robot name")
    return [check(n) for n in names]


def install_stop_signals(stop_event: threading.Event) -> None:
    """SIGINT/SIGTERM end the loop cleanly (the session is closed on the way out)."""
    def handler(signum, frame):
        stop_event.set()
    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


def run_node(controller, robot: str | None = None, argv: list[str] | None = None,
             name: str | None = None, robots: list[str] | None = None) -> int:
    """Run ``controller`` as a bus node; parse the standard options from ``argv``.

    ``controller`` is a controller object, or a factory of them (a class, or a callable
    taking the robot name): with several ``robots`` (or ``--robots``) the node drives one
    controller per robot (:func:`make_controllers`).
    Returns the exit code (0 when stopped or done, 2 on bad configuration,
    3 when the plant went away).
    """
    base = getattr(controller, "name", None) or (
        controller if isinstance(controller, type) else type(controller)).__name__.lower()
    parser = node_arg_parser(f"{base} controller")
    if robot is not None:
        parser.set_defaults(robot=robot)
    if robots:
        parser.set_defaults(robots=list(robots))
    args = parser.parse_args(argv)
    if args.robots:
        args.robot = args.robots[0]
    return run_node_args(controller, args, name or args.name or f"{base}_{args.robot}")


def run_node_args(controller, args: argparse.Namespace, name: str) -> int:
    log = setup_logging(name, args.log_level)
    wait = bool(getattr(args, "wait", False))
    robots = getattr(args, "robots", None) or [args.robot]
    try:
        keys = Keys(args.namespace)
        for r in robots:
            check_name(r, "robot name")
        check_name(name, "node name")
        session = _open_node_session(args, wait, log)
    except (BusConfigError, ValueError) as exc:
        log.error("%s", exc)
        return EXIT_BAD_CONFIG
    except KeyboardInterrupt:              # Ctrl-C while waiting for the plant
        return 0
    runner = None
    try:
        try:
            if wait:
                log.info("waiting for the plant (--wait)")
            runner = NodeRunner(controller, robots[0], name, session, keys, log,
                                wait_for_plant_s=math.inf if wait else 15.0, wait=wait,
                                robots=robots)
        except TimeoutError as exc:
            log.error("%s", exc)
            return EXIT_PLANT_GONE
        except ValueError as exc:
            log.error("%s", exc)
            return EXIT_BAD_CONFIG
        except KeyboardInterrupt:          # Ctrl-C while waiting for the plant
            return 0
        install_stop_signals(runner.stop_event)
        return runner.run()
    finally:
        if runner is not None and getattr(args, "stats", None):
            write_json(args.stats, runner.stats())
        close_session(session, log)


def close_session(session: zenoh.Session, log) -> None:
    """Close, even when the far end is gone (a close that times out is logged, not raised)."""
    try:
        session.close()
    except Exception as exc:       # zenoh.ZError: "close operation timed out"
        log.warning("closing the Zenoh session: %s", exc)


def _open_node_session(args: argparse.Namespace, wait: bool, log) -> zenoh.Session:
    """The node's client session; with ``--wait`` (and the default config) keep trying until
    a plant listens (a Zenoh client cannot open without its router)."""
    if not wait or args.zenoh_config:
        return open_session("node", args.endpoint, args.zenoh_config)
    conf = make_config("node", args.endpoint)
    conf.insert_json5("connect/timeout_ms", "1000")
    said = False
    while True:
        try:
            return zenoh.open(conf)
        except Exception as exc:
            if "connect" not in str(exc).lower():
                raise BusConfigError(f"bad endpoint {args.endpoint!r}: {exc}") from None
        if not said:
            log.info("no plant at %s yet; waiting for one (--wait)", args.endpoint)
            said = True
        time.sleep(0.2)
