"""A lockstep member's half of docs/PROTOCOL.md, with no Zenoh in it: :class:`MemberTick`.

It holds everything a member keeps between messages: the input samples filed by stamp,
the ticks the clock announced and not yet answered, what it sent for its last ticks (to
re-send after a rejoin), and its controller objects (one per robot). Its adapters only move
bytes: :class:`bus.runtime.NodeRunner` between Zenoh and it (a member as a process), and
:class:`bus.composed.Composed` between the plant's tick and it (a member composed into the
plant's process). Both hand it the same decoded messages and send what it returns, so a
member behaves the same wherever it runs. Each public method names its section.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from . import codec
from . import controller as hooks
from .controller import WHEEL_JOINTS, Observation, Twist, WheelSpeeds
from .encoded import Encoded
from .inputs import check_input, stamp_of
from .observe import _HELD, BUF_PER_TOPIC, STALE_S, observations  # noqa: F401
from .protocol import PLANT_READS, REPUBLISH_TICKS
from .rows import commands_of

#: lockstep: ticks of this member's outputs kept to re-send when the plant re-publishes
#: them after a rejoin (more than the plant re-publishes: bus.protocol.REPUBLISH_TICKS, 25)
RESEND_TICKS = 30
#: clock ticks waiting for their inputs (and samples kept per input topic: BUF_PER_TOPIC)
PENDING_MAX = 16

#: what a member sends for a tick: (key, CDR payload, flags, n_plant)
Sent = list[tuple[str, bytes, int, int]]


@dataclass
class Output:
    """One message a member queued for the current tick."""
    key: str
    msg: Any               # a message, or its CDR bytes already (:class:`Encoded`)
    plant_read: bool       # on a key the plant reads (PLANT_READS): counted in n_plant


def _holds(att: bytes) -> bool:
    """Whether attachment ``att`` may carry a hold (a trailer with hold bits): only those
    are parsed (the usual sample's, never holding, is not)."""
    return len(att) > _NO_TRAILER and codec.hold_of(att[codec.ATTACHMENT.size]) > 0


_NO_TRAILER = codec.ATTACHMENT.size + codec.EPOCH.size    # (the longest without a trailer)


def _wire(msg) -> bytes:
    return msg.data if type(msg) is Encoded else codec.encode(msg)


@dataclass
class Slot:
    """One robot a member drives: its controller object and what it reads."""
    robot: str
    controller: Any
    inputs: list[str]
    check_inputs: bool
    periods: dict[str, int] = field(default_factory=dict)
    awaited: list[str] = field(default_factory=list)
    done: bool = False
    plan: tuple | None = None     # take_observation's (input, key, lag, max age) per config
    due: tuple | None = None      # needs' (input key, topic, period, lag) per config
    cmd_key: str = ""             # its cmd_vel key (MemberTick asks it once)


def make_slots(controller, robots: list[str], topics: dict) -> list[Slot]:
    """One :class:`Slot` per robot: a controller object each (``controller`` is an object or
    a factory, :func:`bus.controller.make_controllers`), its inputs checked against the
    topic catalog ``topics`` (extended in place by the bus-wide topics a controller declares)."""
    ctrls = hooks.make_controllers(controller, robots)
    for ctrl in ctrls:
        topics.update(hooks.extra_topics(ctrl))
    slots = []
    for r, ctrl in zip(robots, ctrls):
        inputs = hooks.inputs_of(ctrl)
        for topic in inputs:
            if topic not in topics:
                raise ValueError(f"{type(ctrl).__name__}.inputs: unknown topic {topic!r}")
        # inputs with non-finite or absurd numbers, or wrong joint names, are rejected
        # unless the controller validates its own (``check_inputs = False``)
        slots.append(Slot(r, ctrl, inputs, hooks.checks_inputs(ctrl)))
    return slots


def with_own_stats(stats: dict, controllers) -> dict:
    """A node's ``--stats`` with its controllers' own (:func:`bus.controller.own_stats`)."""
    for ctrl in hooks.distinct(controllers):
        own = hooks.own_stats(ctrl)
        for reason, n in own.pop("rejected", {}).items():
            stats.setdefault("rejected", {})[reason] = stats["rejected"].get(reason, 0) + n
        stats.update(own)
    return stats


class MemberTick:
    """A lockstep member's state and rules (docs/PROTOCOL.md section 4).

    ``slots``: the robots it drives; ``topics``: the topic catalog (name -> bus.keys.Topic);
    ``key(robot, topic)``: a topic's key; ``ack_key``: its ``sim/ack/<node>``; ``sync``: a
    lockstep member (else it acts on every clock with what it has); ``input_delay_ns``: the
    coupling's node-to-node input delay."""

    def __init__(self, name: str, tick_ns: int, actuation_delay_ticks: int = 0,
                 slots: list[Slot] | None = None, topics: dict | None = None,
                 key: Callable[[str, str], str] | None = None, ack_key: str = "",
                 sync: bool = True, input_delay_ns: int = 0,
                 log: logging.Logger | None = None) -> None:
        self.name = name
        self.log = log or logging.getLogger(name)
        self.tick_ns = tick_ns
        self.actuation_delay_ticks = actuation_delay_ticks
        self.slots = list(slots or [])
        self.topics = dict(topics or {})
        self.key = key or (lambda robot, topic: f"{robot}/{topic}")
        self.ack_key = ack_key
        self.sync = sync
        self.lag_ns = {t: input_delay_ns if v.awaited else 0 for t, v in self.topics.items()}
        self.slot_of = {self.key(s.robot, t): (s, t) for s in self.slots for t in s.inputs}
        for s in self.slots:
            s.cmd_key = self.key(s.robot, "cmd_vel")
        self.ticks = 0
        self.final_tick: int | None = None   # the tick at which the last controller finished
        # the newest world epoch seen (kept across reset(): a clock of an older one is late)
        self.newest_epoch = 0
        self.mode = "lockstep"
        self.coupling = "sequential"
        self._out: list[Output] = []
        #: cmd_vel key -> (the bytes last queued on it, the stamp, linear, angular they were
        #: packed from): a composed member's plant takes the values, not the bytes
        self.twists: dict[str, tuple[bytes, int, float, float]] = {}
        #: key -> the :class:`Encoded` last queued on it: a composed member's host hands a
        #: reader beside it the message built from its values (Encoded.made), not the bytes
        self.encoded: dict[str, Encoded] = {}
        self.reset()
        self._keep_sent = True

    def configure(self, info: dict) -> None:
        """Section 5: take the simulation's mode, coupling, tick, delays and sensor periods
        from the plant's ``sim/info`` (its state kept: the plant may be the same, back).
        ValueError if a robot of this member is not in the plant's world."""
        self.mode = info.get("mode", "lockstep")
        self.coupling = info.get("coupling", "sequential")
        # the plant's world now (a plant of another run starts again at 0)
        self.newest_epoch = int(info.get("epoch", 0))
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
        self.tick_ns = int(round(info.get("control_tick_s", 0.0) * 1e9))
        self.actuation_delay_ticks = int(info.get("actuation_delay_ticks", 0))
        # Pipelined coupling: other nodes' outputs are taken one tick old, so producer and
        # consumer work on the same tick in parallel (docs/PROTOCOL.md).
        lag = int(info.get("node_input_delay_ticks", 0)) * self.tick_ns if self.sync else 0
        self.lag_ns = {t: lag if v.awaited else 0 for t, v in self.topics.items()}

    def reset(self, epoch: int | None = None) -> None:
        """Section 4, "Reset": forget every input sample and pending tick (the plant went, or
        its world was reset from inside ``step``: the new world's clock starts again at 0;
        ``epoch``: the new world's, from the ``sim/reset`` reply: older clocks are late)."""
        if epoch is not None:
            self.newest_epoch = epoch
        self.buf: dict[str, dict[int, Any]] = {}
        self.used: set[tuple[str, int]] = set()
        # input key -> (stamp of a sample whose producer holds, the last tick it holds)
        self.covered: dict[str, tuple[int, int]] = {}
        self.pending: dict[int, float] = {}    # lockstep: clock stamp -> wall time it came
        self.last_clock: int | None = None
        # what this member sent for its last ticks, to re-send (stamp -> messages); reset
        # from inside step: the tick being answered is the old world's, not kept
        self.sent: dict[int, Sent] = {}
        self._keep_sent = False
        self._last_acted: int | None = None    # lockstep: the last tick acted on
        self.hold_until: int | None = None     # lockstep: the last tick its last answer holds
        self.epoch: int | None = None          # lockstep: the plant's epoch of the last clock

    # ------------------------------------------------------------ input (section 4, step 2)
    def input_stamp(self, t_ns: int, period_ticks: int, lag_ns: int) -> int | None:
        """Section 4, step 2: the stamp the sample of one input must carry before the member
        acts on tick ``t_ns`` (a plant sensor: ``t_ns`` if due at this tick; another node's
        output: ``t_ns`` less the coupling's input delay), or None if none is due."""
        k = t_ns // self.tick_ns if self.tick_ns else 0
        if k % period_ticks or t_ns - lag_ns < 0:
            return None
        return t_ns - lag_ns

    def needs(self, slot: Slot, t_ns: int) -> list[tuple[str, str, int]]:
        """Section 4, step 2: (input key, topic, stamp) a robot needs before the member acts
        on tick ``t_ns``: the plant's sensors due at this tick, and outputs of other lockstep
        members (stamped ``t_ns``, or a tick earlier in pipelined coupling)."""
        k = t_ns // self.tick_ns if self.tick_ns else 0
        return [(key, t, t_ns - lag) for key, t, period, lag in self._plan(slot)
                if not k % period and t_ns >= lag]

    def _plan(self, slot: Slot) -> list[tuple[str, str, int, int]]:
        """``slot``'s inputs as (key, topic, period in ticks, lag ns), made once per
        configuration (input_stamp's rule) and kept while its inputs, periods and lags stay."""
        due = slot.due
        if due is None or due[0] is not slot.awaited or due[1] is not slot.periods \
                or due[2] is not self.lag_ns:
            due = slot.due = (slot.awaited, slot.periods, self.lag_ns, [
                (self.key(slot.robot, t), t, slot.periods.get(t, 1), self.lag_ns[t])
                for t in slot.awaited])
        return due[3]

    def receive(self, key: str, payload: bytes, att: bytes | None,
                msg=None) -> tuple[str, str | None, object]:
        """Section 4, step 2: one sample on input ``key``, decoded (unless ``msg``, its
        decoded form, is given) and filed (:meth:`file_input`): (topic, what is wrong with
        it or None, the message or None if it did not decode)."""
        _, topic = self.slot_of[key]
        if msg is None:
            try:
                msg = codec.decode(payload, self.topics[topic].msgtype)
            except codec.CodecError as exc:
                return topic, str(exc), None
        return topic, self.file_input(key, msg, att), msg

    def file_input(self, key: str, msg, att: bytes | None) -> str | None:
        """Section 4, step 2: file one decoded sample under its stamp; what is wrong with it,
        or None. Samples are kept by stamp (a few per key), so a late, early or forged one
        never displaces the one a tick needs. One that decodes but carries bad values (NaN,
        inf, absurd magnitudes, wrong joint names) is *held*: its tick still happens and
        the controller sees the topic's last good message."""
        slot, topic = self.slot_of[key]
        stamp, problem = stamp_of(msg, self.tick_ns, att, self.last_clock)
        if problem:
            return problem
        buf = self.buf.get(key) or self.buf.setdefault(key, {})    # (no new dict each call)
        if slot.check_inputs and (problem := check_input(topic, msg)):
            buf.setdefault(stamp, _HELD)       # never replaces a good sample of the tick
            problem = f"{problem} (t={stamp * 1e-9:.3f} s; holding the last good one)"
        else:
            buf[stamp] = msg
            self.used.discard((key, stamp))    # a new sample for that tick (a reset)
            if att is not None and self.topics[topic].awaited and _holds(att):
                a = codec.parse_attachment(att)
                if a is not None and a.node is not None and codec.hold_of(a.flags):
                    # "Holding": its producer answers nothing for the ticks it holds, so
                    # this sample stands for them (take_observation shows the latest)
                    self.covered[key] = (stamp, stamp + codec.hold_of(a.flags) * self.tick_ns)
        if len(buf) > BUF_PER_TOPIC:           # drop what lies farthest from the clock
            ref = self.last_clock if self.last_clock is not None else stamp
            del buf[max(buf, key=lambda s: abs(s - ref))]
        return problem

    def clock(self, t_ns: int, now: float = 0.0,
              epoch: int | None = None) -> tuple[Sent | None, str | None]:
        """Section 4, steps 1 and "Lost members": a ``sim/clock`` for tick ``t_ns`` of the
        plant's world ``epoch`` (section 3; None: not said). Returns (what to re-send: a
        tick this member answered, re-published after a rejoin; a problem to count, or
        None). Otherwise the tick waits for its inputs (:meth:`next_due`); ``now``: the
        wall time it came. A clock of a newer epoch is a new world's (a reset), never a
        re-publish, whatever its stamp; one of an older epoch than the newest seen is the
        old world's, late, and ignored (section 4, "Reset")."""
        if epoch is not None and epoch < self.newest_epoch:
            return None, None                  # the old world's, late: never answered
        self.last_clock = t_ns
        if not self.sync:
            return None, None
        if epoch is not None:
            self.newest_epoch = epoch
            if self.epoch is not None and epoch != self.epoch:
                self.sent.clear()
                self._last_acted = self.hold_until = None
            self.epoch = epoch
        if t_ns in self.sent:                  # re-published after a rejoin
            return self.sent[t_ns], None
        if self.sent and t_ns < max(self.sent):      # the world went back
            self.sent.clear()
            self._last_acted = self.hold_until = None
        self.pending[t_ns] = now or time.monotonic()
        if len(self.pending) > PENDING_MAX:
            old = next(iter(self.pending))
            del self.pending[old]
            return None, f"tick t={old * 1e-9:.3f} s never completed (a stray clock?)"
        return None, None

    def _complete(self, t_ns: int) -> bool:
        """Every robot still driven has, for every input due at ``t_ns``, a sample (good or
        held) of the stamp it needs that this member has not acted on yet."""
        # (needs' rule on its kept plan, read in place: asked for every robot every tick)
        k = t_ns // self.tick_ns if self.tick_ns else 0
        bufs, used = self.buf, self.used
        for slot in self.slots:
            if slot.done:
                continue
            for key, _, period, lag in self._plan(slot):
                if k % period or t_ns < lag:
                    continue
                s = t_ns - lag
                if (s not in bufs.get(key, ()) and not self._has(key, s)) or (key, s) in used:
                    return False
        return True

    def _has(self, key: str, stamp: int) -> bool:
        """A sample (good or held) of input ``key`` for ``stamp``: its own, or one whose
        producer holds ``stamp`` (section 4, "Holding")."""
        buf = self.buf.get(key, ())
        if stamp in buf:
            return True
        cov = self.covered.get(key)
        return cov is not None and cov[0] < stamp <= cov[1] and cov[0] in buf

    def next_due(self) -> int | None:
        """Section 4, step 2: the next tick to act on now, or None. A member answers every
        tick in order: while the next tick's inputs are not all in, no later tick is acted
        on (after a blip the plant re-publishes what was lost, and a later tick answered
        first would make the next one look like a world gone back). The same holds when the
        next tick's clock itself was lost and a later tick is complete: the plant re-publishes
        its last ``REPUBLISH_TICKS`` ticks when the member is back, so the later one waits
        for the next one's clock unless that tick lies beyond what the plant keeps."""
        nxt = None if self._last_acted is None else self._last_acted + self.tick_ns
        for t_ns in sorted(self.pending):
            if not self._complete(t_ns):
                if nxt is not None and self._last_acted < t_ns <= nxt:
                    return None      # the next tick: a later one waits
                continue             # (a stray or the old world's: never holds a tick)
            if (nxt is not None and self.tick_ns and t_ns > nxt
                    and max(self.pending) - nxt < REPUBLISH_TICKS * self.tick_ns):
                return None          # the next tick's clock is still to come (re-published)
            del self.pending[t_ns]
            self._last_acted = t_ns
            return t_ns
        return None

    def missing(self, t_ns: int) -> list[str]:
        """Section 4, step 2: the topics tick ``t_ns`` still waits for (a member whose
        producer left tells why it stops)."""
        return [tp for slot in self.slots if not slot.done
                for key, tp, s in self.needs(slot, t_ns) if not self._has(key, s)]

    def take_observation(self, slot: Slot, t_ns: int) -> Observation:
        """Section 4, step 2: the latest good message of each of a robot's inputs stamped at
        or before ``t_ns`` (a tick earlier for a lagged one), unless it is stale
        (:func:`bus.observe.observations`, which takes them for many robots at once)."""
        return observations(self, (slot,), t_ns)[slot.robot]

    # ------------------------------------------------------------ output (section 4, step 3)
    def act(self, t_ns: int) -> tuple[Sent, bool]:
        """Section 4, step 3: step every robot's controller at tick ``t_ns``; (what to send,
        whether every controller is done: then it is the FINAL). A robot whose controller
        is done is sent its stop command every tick until the others are. A controller for
        many robots (``step_many``) is called once with all the robots it still drives."""
        many: dict[int, tuple[dict, bool]] = {}    # controller id -> ({robot: command}, done)
        for slot in self.slots:
            if not slot.done and id(slot.controller) not in many \
                    and hooks.steps_many(slot.controller):
                ctrl = slot.controller
                obs = observations(self, [s for s in self.slots
                                          if s.controller is ctrl and not s.done], t_ns)
                many[id(ctrl)] = (commands_of(ctrl, ctrl.step_many(obs), list(obs)),
                                  hooks.is_done(ctrl))
        for slot in self.slots:
            if slot.done:
                self.queue_output(hooks.stop_command(slot.controller), t_ns, slot.robot)
                continue
            got = many.get(id(slot.controller))
            if got is not None:             # (stepped with the others: one answer, one done)
                out, done = got[0].get(slot.robot), got[1]
            else:
                out = slot.controller.step(self.take_observation(slot, t_ns))
                done = hooks.is_done(slot.controller)
            self._queue_answer(slot, out, done, t_ns)
        finished = all(slot.done for slot in self.slots)
        return self.send_tick(t_ns, final=finished), finished

    def _queue_answer(self, slot: Slot, out, done: bool, t_ns: int) -> None:
        """Queue ``slot``'s controller's answer ``out`` to tick ``t_ns``; where it is ``done``,
        mark it so and queue its stop command too."""
        if type(out) is Twist:              # (the usual answer: its key asked once)
            self._queue_twist(slot.cmd_key, out, t_ns)
        else:
            self.queue_output(out, t_ns, slot.robot)
        if done:
            slot.done = True
            self.queue_output(hooks.stop_command(slot.controller), t_ns, slot.robot)
            self.log.info("%s%s done at t=%.3f s", self.name,
                          f" ({slot.robot})" if len(self.slots) > 1 else "", t_ns * 1e-9)

    def queue_output(self, out, t_ns: int, robot: str) -> None:
        """Section 4, step 3: queue what ``step`` returned for tick ``t_ns`` for ``robot``
        (a Twist as ``cmd_vel``, WheelSpeeds as ``wheel_cmd``, a dict of outputs)."""
        if out is None:
            return
        if isinstance(out, Twist):
            self._queue_twist(self.key(robot, "cmd_vel"), out, t_ns)
        elif isinstance(out, WheelSpeeds):
            self._out.append(Output(self.key(robot, "wheel_cmd"),
                                    codec.joint_state(t_ns, WHEEL_JOINTS,
                                                      velocity=(out.left, out.right)), True))
        elif isinstance(out, dict):
            for topic, msg in out.items():
                if isinstance(msg, (Twist, WheelSpeeds)):     # a command among other outputs
                    self.queue_output(msg, t_ns, robot)
                else:
                    key = self.key(robot, topic)
                    if type(msg) is Encoded:
                        self.encoded[key] = msg
                    self._out.append(Output(key, msg, topic in PLANT_READS))
        else:
            raise TypeError(f"step() returned {type(out).__name__}; expected Twist, "
                            "WheelSpeeds, dict or None")

    def _queue_twist(self, key: str, out: Twist, t_ns: int) -> None:
        """:meth:`queue_output` of a Twist on cmd_vel key ``key``."""
        linear, angular = float(out.linear), float(out.angular)
        data = codec.twist_stamped_bytes(t_ns, linear, angular)
        self.twists[key] = (data, t_ns, linear, angular)
        self._out.append(Output(key, Encoded(data), True))

    def send_tick(self, t_ns: int, final: bool = False, hold: int = 0) -> Sent:
        """Section 4, step 3: the tick's queued outputs as sent (:meth:`owed`'s order and
        flags), kept for a re-send; a member that is not in lockstep sends them as queued.
        ``hold``: "Holding", the answer also stands for the ``hold`` ticks after this one
        (not with ``final``): the member then passes them with :meth:`skip`."""
        out, self._out = self._out, []
        self.ticks += 1
        if final:
            self.final_tick = t_ns
        if not self.sync:
            return [(o.key, _wire(o.msg), 0, 0) for o in out]
        if final and hold:
            raise ValueError("a FINAL tick holds no tick after it (docs/PROTOCOL.md)")
        sent = [(key, b"" if msg is None else _wire(msg), flags, n_plant)
                for key, msg, flags, n_plant in self.owed(out, self.ack_key, final, hold)]
        # (the old world's last tick, answered after a reset from inside step: no hold)
        self.hold_until = t_ns + hold * self.tick_ns if self._keep_sent else None
        self._keep(t_ns, sent)
        return sent

    def _keep(self, t_ns: int, sent: Sent) -> None:
        if self._keep_sent:           # (not the old world's last tick, after a reset)
            self.sent[t_ns] = sent
            while len(self.sent) > RESEND_TICKS:
                del self.sent[min(self.sent)]
        self._keep_sent = True

    def holds(self, t_ns: int) -> bool:
        """Section 4, "Holding": tick ``t_ns`` is one the member's last answer holds (it
        sends nothing for it: :meth:`skip`)."""
        return self.sync and self.hold_until is not None and t_ns <= self.hold_until

    def skip(self, t_ns: int) -> Sent:
        """Section 4, "Holding": pass a tick the last answer holds, sending nothing (kept as
        such: re-published, it is answered with nothing again). What was queued for it is
        an error: the plant would ignore it."""
        if self._out:
            keys = sorted({o.key for o in self._out})
            self._out = []
            raise ValueError(f"outputs on {', '.join(keys)} for t={t_ns * 1e-9:.3f} s, a "
                             "tick this member holds (docs/PROTOCOL.md section 4, Holding)")
        self.ticks += 1
        self._keep(t_ns, [])
        return []

    def owed(self, outputs: list[Output], ack_key: str, final: bool = False,
             hold: int = 0) -> list[tuple[str, Any, int, int]]:
        """Section 4, step 3: what the member sends for a tick, in order, as (key, message or
        None for the empty ACK, flags, n_plant): plant-read outputs last (a stable sort:
        robot order kept), the very last with ``ACK`` (and ``FINAL``) and ``n_plant``; a tick
        with no plant-read output ends with an empty message on ``sim/ack/<node>``. One
        message per key and tick (the plant keeps only the first, section 7): of two
        outputs queued on one key, the later (e.g. a stop after the last step's command).
        ``hold`` ("Holding") is in the flags of every message of the tick."""
        last = {o.key: o for o in outputs}
        out = sorted(last.values(), key=lambda o: o.plant_read)
        n_plant = sum(1 for o in out if o.plant_read)
        end = codec.with_hold(codec.ACK | (codec.FINAL if final else 0), hold)
        mid = codec.with_hold(0, hold)
        sent = [(o.key, o.msg, end if (n_plant and i == len(out) - 1) else mid,
                 n_plant if (n_plant and i == len(out) - 1) else 0)
                for i, o in enumerate(out)]
        if not n_plant:
            sent.append((ack_key, None, end, 0))
        return sent

    def may_leave(self, final_ns: int, clock_ns: int) -> bool:
        """Section 4, "Finishing": after its FINAL at ``final_ns`` a member keeps its tokens
        until a ``sim/clock`` stamped after ``final_ns`` + the actuation delay (the plant
        publishes it only once it took the FINAL)."""
        return clock_ns > final_ns + self.actuation_delay_ticks * self.tick_ns
