"""The node runtime: runs controller objects on the bus as one node (:class:`NodeRunner`).

It opens nothing itself: given a session, it learns the simulation's mode from the plant
(``sim/info``), subscribes to the controllers' inputs and ``sim/clock``, takes part in
lockstep (liveliness token ``sim/sync/<node>``; the member's half of the handshake is
:class:`bus.lockstep.MemberTick`), stamps and sends the outputs, and stops on a stop
event, the controllers finishing, or the plant going away. :mod:`bus.node` is its
command line. Threads: Zenoh callbacks only fill the :class:`bus.inbox.Inbox`; everything
else runs on the thread that calls :meth:`NodeRunner.run`.

One node may drive several robots: one controller object per robot (a factory makes
them, or the given object is copied), one lockstep member that acks each tick once for
all its robots, each robot's inputs awaited separately; the node finishes when every
controller is done.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import zenoh

from . import codec
from . import controller as hooks
from .controller import WHEEL_JOINTS, Observation, Twist, WheelSpeeds, make_controllers
from .inbox import Inbox
from .inputs import check_input, stamp_of
from .keys import TOPICS, Keys, check_name
from .lockstep import MemberTick, Output
from .log import RejectCounter
from .plantwatch import EXIT_PLANT_GONE, PlantWatch
from .protocol import PLANT_READS, ProtocolError, check_version
from .session import query_info

EXIT_BAD_CONFIG = 2
#: a lockstep node whose awaited input comes from a node that left (it would wait forever)
EXIT_INPUT_GONE = 4

#: the Zenoh lease (bus.session.DEFAULT_LEASE_MS): a peer silent for longer is dropped
LEASE_S = 1.0
#: how long a lockstep node waits for another node's output once a member has left
PRODUCER_GRACE_S = 0.5
#: an input older than this (simulated s, or three of its periods) is not shown to the
#: controller: its producer is gone (realtime and fast modes, where nobody waits for it)
STALE_S = 0.5
#: lockstep: ticks of this member's outputs kept to re-send when the plant re-publishes
#: them after a rejoin (more than the plant re-publishes: plant.node.REPUBLISH_TICKS, 25)
RESEND_TICKS = 30
#: samples kept per input topic (by stamp) and clock ticks waiting for their inputs
_BUF_PER_TOPIC = 8
_PENDING_MAX = 16
_HELD = object()     # "a bad sample came for this tick": the tick goes on, the last good is held


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
            self.topics.update(hooks.extra_topics(ctrl))
        for r, ctrl in zip(robots, ctrls):
            inputs = hooks.inputs_of(ctrl)
            for topic in inputs:
                if topic not in self.topics:
                    raise ValueError(f"{type(ctrl).__name__}.inputs: unknown topic {topic!r}")
            # inputs with non-finite or absurd numbers, or wrong joint names, are rejected
            # here unless the controller validates its own (``check_inputs = False``)
            self.slots.append(_Slot(r, ctrl, inputs, hooks.checks_inputs(ctrl)))
        self.controller = self.slots[0].controller
        self.inputs = self.slots[0].inputs
        self.rejects = RejectCounter(log)
        self.stop_event = threading.Event()
        self.exit_code = 0
        self.published: dict[str, int] = {}
        self.ticks = 0
        self.final_tick: int | None = None   # the tick at which the last controller finished
        self.plant_lost = 0           # times the plant went away while --wait kept us here
        #: how long a lost plant is waited for (--wait): the run's rejoin timeout
        self.watch = PlantWatch()
        self._seq = 0
        # the current tick's outputs, not sent yet
        self._out: list[Output] = []
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._keys: dict[tuple[str, str], str] = {}
        # input key -> (slot, topic); filled by run()
        self._topic_of: dict[str, tuple[_Slot, str]] = {}
        self._apply_info(query_info(session, keys, wait_for_plant_s, log))
        for slot in self.slots:
            hooks.configure(slot.controller, self.info, slot.robot)
            hooks.on_session(slot.controller, session, keys)   # e.g. to declare a queryable

    def _apply_info(self, info: dict) -> None:
        """Take the simulation's protocol, mode, coupling, tick and sensor periods from the
        plant's ``sim/info`` (a plant of another protocol version is a ProtocolError)."""
        check_version(info)
        self.info = info
        self.watch.learn(info)
        self.mode = info.get("mode", "lockstep")
        self.coupling = info.get("coupling", "sequential")
        self.sync = self.mode == "lockstep" and all(hooks.syncs(s.controller)
                                                    for s in self.slots)
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
        self.member = MemberTick(self.name, self.tick_ns,
                                 int(info.get("actuation_delay_ticks", 0)))

    def _key(self, robot: str, topic: str) -> str:
        key = self._keys.get((robot, topic))
        if key is None:
            key = self._keys[robot, topic] = self.keys.topic(robot, topic)
        return key

    # ----------------------------------------------------------------- output
    def queue_output(self, out, t_ns: int, robot: str | None = None) -> None:
        """Queue what ``step`` returned for tick ``t_ns`` (for ``robot``, by default the
        first); :meth:`send_tick` sends it."""
        if out is None:
            return
        robot = robot or self.robot
        if isinstance(out, Twist):
            self._out.append(Output(self._key(robot, "cmd_vel"),
                                    codec.twist_stamped(t_ns, out.linear, out.angular), True))
        elif isinstance(out, WheelSpeeds):
            self._out.append(Output(self._key(robot, "wheel_cmd"),
                                    codec.joint_state(t_ns, WHEEL_JOINTS,
                                                      velocity=(out.left, out.right)), True))
        elif isinstance(out, dict):
            for topic, msg in out.items():
                if isinstance(msg, (Twist, WheelSpeeds)):     # a command among other outputs
                    self.queue_output(msg, t_ns, robot)
                else:
                    self._out.append(Output(self._key(robot, topic), msg, topic in PLANT_READS))
        else:
            raise TypeError(f"step() returned {type(out).__name__}; expected Twist, "
                            "WheelSpeeds, dict or None")

    def send_tick(self, t_ns: int, final: bool = False) -> None:
        """Send the tick's queued outputs (of every robot). A lockstep member sends them as
        :meth:`bus.lockstep.MemberTick.owed` orders and flags them: one message per tick
        for a node with one command, one per robot for a node with several."""
        out, self._out = self._out, []
        if not self.sync:
            for o in out:
                self._put(o.key, codec.encode(o.msg), codec.attachment(self._next_seq(), t_ns))
            return
        sent = [(key, b"" if msg is None else codec.encode(msg), flags, n_plant)
                for key, msg, flags, n_plant in self.member.owed(out, self.keys.ack(self.name),
                                                                 final)]
        if self._keep_sent:           # (not the old world's last tick, after a reset)
            self._sent[t_ns] = sent
            while len(self._sent) > RESEND_TICKS:
                del self._sent[min(self._sent)]
        self._keep_sent = True
        self._send(sent, t_ns)

    def _resend(self, t_ns: int) -> None:
        self._send(self._sent[t_ns], t_ns)

    def _send(self, sent: list[tuple[str, bytes, int, int]], t_ns: int) -> None:
        """Send (again) what this member sent for tick ``t_ns``, byte for byte but for the
        seq: after a rejoin the plant re-publishes its last ticks, and a member answers a
        tick it already answered this way, never by stepping again (docs/PROTOCOL.md
        section 4, "Lost members")."""
        for key, payload, flags, n_plant in sent:
            self._put(key, payload, codec.attachment(self._next_seq(), t_ns, flags, n_plant,
                                                     self.name))

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
        needs = []
        for t in slot.awaited:
            stamp = self.member.input_stamp(t_ns, slot.periods.get(t, 1), self.lag_ns[t])
            if stamp is not None:
                needs.append((self._key(slot.robot, t), t, stamp))
        return needs

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
        stamp, problem = stamp_of(msg, self.tick_ns, att, self._last_clock)
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
        t_ns, problem = stamp_of(msg, self.tick_ns)
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

    def take_observation(self, slot: _Slot, t_ns: int) -> Observation:
        """The latest good message of each of a robot's inputs stamped at or before ``t_ns``
        (a tick earlier for a lagged one), unless it is stale (older than ``STALE_S`` or
        three of its periods: its producer is gone), so a controller never steers on a dead
        input. Takes: the samples older than the one shown, and held marks, are dropped,
        and the tick's stamps are marked used."""
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

    def reset_inputs(self) -> None:
        """Forget every input sample and pending tick (the plant went, or its world was reset
        from inside ``step``: the new world's clock starts again at 0)."""
        self._buf: dict[str, dict[int, Any]] = {}
        self._used: set[tuple[str, int]] = set()
        self._pending: dict[int, float] = {}   # lockstep: clock stamp -> wall time it came
        self._last_clock: int | None = None
        # lockstep: what this member sent for its last ticks, to re-send (stamp -> messages);
        # reset from inside step: the tick being answered is the old world's, not kept
        self._sent: dict[int, list[tuple[str, bytes, int, int]]] = {}
        self._keep_sent = False
        self._last_acted: int | None = None    # lockstep: the last tick acted on
        self._epoch: int | None = None         # lockstep: the epoch of the last clock

    def _new_world(self, att: bytes | None) -> bool:
        """Lockstep: the clock's epoch (docs/PROTOCOL.md section 3) differs from the last
        one's: the plant's world was reset or rebuilt, so a clock stamped like a tick this
        member answered is the new world's, to step, never one to re-send."""
        a = codec.parse_attachment(att)
        epoch = a.epoch if a is not None and a.epoch is not None else self._epoch
        new = self._epoch is not None and epoch != self._epoch
        self._epoch = epoch
        return new

    def _is_next(self, t_ns: int) -> bool:
        """Lockstep: ``t_ns`` is the tick after the last one this member acted on. A member
        answers every tick in order (docs/PROTOCOL.md section 4), so while the next tick's
        inputs are not all in, no later tick is acted on: after a blip the plant re-publishes
        what was lost, and a later tick answered first would make the next one look like a
        world gone back (stepped again, an FMU re-initialised)."""
        return (self._last_acted is not None
                and self._last_acted < t_ns <= self._last_acted + self.tick_ns)

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
        self.reset_inputs()
        self._keep_sent = True
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
                if self.wait and self.watch.expired(now):      # --wait, not past a run's end
                    self.log.error("%s; stopping", self.watch.why(now))
                    self.exit_code = EXIT_PLANT_GONE
                    break
                if ev is None:
                    if self.sync and plant_here and self._producer_gone(left, now):
                        break
                    continue
                if ev.tag == "end":
                    if not ev.alive or (not plant_here and not ev.payload):
                        continue             # the end token withdrawn, or a repeat of the end
                    reason = ev.payload.decode("utf-8", "replace") or "the plant ended it"
                    if self.wait and not plant_seen:     # --wait: for a plant to start
                        self.log.warning("the simulation ended (%s); waiting for a plant "
                                         "(--wait)", reason)
                        plant_here = False
                        self.reset_inputs()
                        continue
                    self.log.info("the simulation ended (%s); stopping", reason)
                    break
                if ev.tag == "plant":
                    if ev.alive:
                        if plant_seen and not plant_here:
                            if not self._plant_back(tokens):
                                break
                        plant_seen = plant_here = True
                        self.watch.here()
                    elif plant_here:
                        plant_here = False
                        if self.wait:       # inputs kept: the plant may be the same, back
                            self.plant_lost += 1
                            self.watch.gone(now)
                            self.log.warning("the plant is gone; waiting for it to come back "
                                             "(--wait), up to %g s (the run's rejoin timeout "
                                             "+ %g s)", self.watch.limit_s,
                                             self.watch.limit_s - self.watch.rejoin_timeout_s)
                            continue
                        if now - stalled < 5.0:
                            self.log.error("the plant is gone: this process was stopped for "
                                           "%.1f s, longer than the %.0f s bus lease, so the "
                                           "simulation dropped it; stopping", stall_s, LEASE_S)
                        else:
                            self.log.error("the plant is gone; stopping")
                        self.reset_inputs()
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
                    if self._new_world(ev.attachment):   # a reset, not a re-publish
                        self._sent.clear()
                        self._last_acted = None
                    if t_ns in self._sent:       # re-published after a rejoin
                        self._resend(t_ns)
                        continue
                    if self._sent and t_ns < max(self._sent):    # the world went back
                        self._sent.clear()
                        self._last_acted = None
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
                for t_ns in sorted(self._pending):
                    if not self._complete(t_ns):
                        if self._is_next(t_ns):
                            break      # ticks are answered in order: a later one waits
                        continue       # (a stray or the old world's: never holds a tick)
                    del self._pending[t_ns]
                    self._last_acted = t_ns
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
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not self.stop_event.is_set():
            ev = inbox.get(timeout=0.05)
            if ev is None:
                continue
            if ev.tag == "end" or (ev.tag == "plant" and not ev.alive):
                return
            if ev.tag == "clock":
                t = self._clock(ev.payload)
                if t is not None and self.member.may_leave(t_done, t):
                    return

    def _act(self, t_ns: int) -> bool:
        """Step every robot's controller at tick ``t_ns``, publish, ack (one ack for all);
        True once every controller is done. A robot whose controller is done is sent its
        stop command every tick until the others are."""
        for slot in self.slots:
            if slot.done:
                self.queue_output(hooks.stop_command(slot.controller), t_ns, slot.robot)
                continue
            self.queue_output(slot.controller.step(self.take_observation(slot, t_ns)), t_ns,
                              slot.robot)
            if hooks.is_done(slot.controller):
                slot.done = True
                self.queue_output(hooks.stop_command(slot.controller), t_ns, slot.robot)
                self.log.info("%s%s done at t=%.3f s", self.name,
                              f" ({slot.robot})" if len(self.slots) > 1 else "", t_ns * 1e-9)
        self.ticks += 1
        finished = all(slot.done for slot in self.slots)
        self.send_tick(t_ns, final=finished)
        if finished:
            self.final_tick = t_ns
        return finished

    def _plant_back(self, tokens: dict) -> bool:
        """A plant is there again (--wait): learn its mode and carry on. False to stop."""
        try:
            self._apply_info(query_info(self.session, self.keys, 15.0))
        except ProtocolError as exc:       # must not join (docs/PROTOCOL.md): as at the start
            self.log.error("a plant came back but %s; stopping", exc)
            self.exit_code = EXIT_BAD_CONFIG
            return False
        except (TimeoutError, ValueError) as exc:
            self.log.error("a plant came back but %s; stopping", exc)
            self.exit_code = EXIT_PLANT_GONE
            return False
        if self.sync and "sync" not in tokens:
            tokens["sync"] = self.session.liveliness().declare_token(self.keys.sync(self.name))
        elif not self.sync and "sync" in tokens:
            tokens.pop("sync").undeclare()
        t_plant = self.info.get("time_ns", 0)
        if self._last_clock is None or t_plant < self._last_clock:
            self.reset_inputs()                # another run (or world): start afresh
        # else the same run, back after a blip (its router or link): carry on where we were
        self.log.warning("the plant is back (%s mode, t=%.3f s); carrying on", self.mode,
                         t_plant * 1e-9)
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

    def stats(self) -> dict:
        return {"node": self.name, "robot": self.robot, "robots": self.robots,
                "ticks": self.ticks,
                "published": self.published, "rejected": dict(self.rejects.counts),
                "plant_lost": self.plant_lost, "exit_code": self.exit_code}
