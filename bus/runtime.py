"""The node runtime: runs controller objects on the bus as one node (:class:`NodeRunner`).

It opens nothing itself: given a session, it learns the simulation's mode from the plant
(``sim/info``), subscribes to the controllers' inputs and ``sim/clock``, takes part in
lockstep (liveliness token ``sim/sync/<node>``; the member's half of the handshake is
:class:`bus.member.MemberTick`), stamps and sends the outputs, and stops on a stop
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

import zenoh

from . import codec
from . import controller as hooks
from .inbox import Event, Inbox
from .inputs import stamp_of
from .keys import TOPICS, Keys, check_name, check_names
from .log import RejectCounter
from .member import MemberTick, Sent, make_slots
from .plantwatch import EXIT_PLANT_GONE, PlantWatch
from .process import EXIT_BAD_CONFIG, EXIT_INPUT_GONE
from .protocol import ProtocolError, check_version
from .session import query_info

# (the exit codes are bus.process's: 2 bad configuration; 4 a lockstep node whose awaited
# input comes from a node that left, as it would wait forever)

#: the Zenoh lease (bus.session.DEFAULT_LEASE_MS): a peer silent for longer is dropped
LEASE_S = 1.0
#: how long a lockstep node waits for another node's output once a member has left
PRODUCER_GRACE_S = 0.5
#: after the sim/end token, how long the end's text is waited for (docs/PROTOCOL.md section 4,
#: "End": data and liveliness take different paths)
END_TEXT_WAIT_S = 1.0


@dataclass
class _Run:
    """What one :meth:`NodeRunner.run` keeps between events."""
    tokens: dict                 # this node's liveliness tokens ("alive", "sync")
    max_ticks: int | None
    plant_seen: bool = False
    plant_here: bool = False
    #: the sim/end token came (wall time): it may overtake the run's last data (liveliness
    #: travels apart), so the end's text, which comes after that data, is waited for
    end_token_at: float | None = None
    left: dict[str, float] = field(default_factory=dict)   # lockstep members that left -> wall
    last_loop: float = 0.0
    stalled: float = -math.inf   # when this process was last found stopped or starved
    stall_s: float = 0.0

    def enough(self, ticks: int) -> bool:
        return self.max_ticks is not None and ticks >= self.max_ticks


class NodeRunner:
    """Runs controller objects on the bus as one node: one per robot (module docstring)."""

    def __init__(self, controller, robot: str | None, name: str, session: zenoh.Session,
                 keys: Keys, log: logging.Logger, wait_for_plant_s: float = 15.0,
                 wait: bool = False, robots: list[str] | None = None) -> None:
        robots = check_names(robots if robots else [robot or "robot1"])
        self.robots = robots
        self.robot = robots[0]
        self.name = check_name(name, "node name")
        self.session = session
        self.keys = keys
        self.log = log
        #: --wait: when the plant goes away, wait for it to come back instead of exiting 3
        self.wait = wait
        # the topic catalog, plus the bus-wide ``fmu/...`` keys a controller declares in
        # ``topics`` ({name: bus.keys.Topic}; message types without a header are stamped by
        # the attachment)
        self.topics = dict(TOPICS)
        slots = make_slots(controller, robots, self.topics)
        self._keys: dict[tuple[str, str], str] = {}
        #: the member's state and rules (docs/PROTOCOL.md section 4): this class moves bytes
        self.member = MemberTick(self.name, 0, slots=slots, topics=self.topics, key=self._key,
                                 ack_key=keys.ack(self.name), log=log)
        self.slots = self.member.slots
        self.rejects = RejectCounter(log)
        self.stop_event = threading.Event()
        self.exit_code = 0
        self.published: dict[str, int] = {}
        self.plant_lost = 0           # times the plant went away while --wait kept us here
        #: how long a lost plant is waited for (--wait): the run's rejoin timeout
        self.watch = PlantWatch()
        self._seq = 0
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._apply_info(query_info(session, keys, wait_for_plant_s, log))
        for slot in self.slots:
            hooks.configure(slot.controller, self.info, slot.robot)
        for ctrl in hooks.distinct(s.controller for s in self.slots):
            hooks.on_session(ctrl, session, keys)   # e.g. to declare a queryable

    def _apply_info(self, info: dict) -> None:
        """Take the simulation's protocol, mode, coupling, tick and sensor periods from the
        plant's ``sim/info`` (a plant of another protocol version is a ProtocolError)."""
        check_version(info)
        self.info = info
        self.watch.learn(info)
        self.member.configure(info)
        self.mode, self.coupling, self.sync = self.member.mode, self.member.coupling, \
            self.member.sync
        self.tick_ns = self.member.tick_ns

    def _key(self, robot: str, topic: str) -> str:
        key = self._keys.get((robot, topic))
        if key is None:
            key = self._keys[robot, topic] = self.keys.topic(robot, topic)
        return key

    @property
    def ticks(self) -> int:
        return self.member.ticks

    @property
    def final_tick(self) -> int | None:
        return self.member.final_tick

    # ----------------------------------------------------------------- output
    def _send(self, sent: Sent, t_ns: int) -> None:
        """Send (again) what this member sent for tick ``t_ns``, byte for byte but for the
        seq: after a rejoin the plant re-publishes its last ticks, and a member answers a
        tick it already answered this way, never by stepping again (docs/PROTOCOL.md
        section 4, "Lost members")."""
        name = self.name if self.sync else None
        for key, payload, flags, n_plant in sent:
            self._seq += 1
            self._put(key, payload, codec.attachment(self._seq, t_ns, flags, n_plant, name))

    def _put(self, key: str, payload: bytes, att: bytes) -> None:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self.session.declare_publisher(
                key, encoding=zenoh.Encoding.APPLICATION_CDR,
                congestion_control=zenoh.CongestionControl.BLOCK)
        pub.put(payload, attachment=att)
        self.published[key] = self.published.get(key, 0) + 1

    # ----------------------------------------------------------------- input
    def _input(self, key: str, payload: bytes, att: bytes | None = None) -> None:
        """Decode one input sample and file it (:meth:`bus.member.MemberTick.receive`)."""
        topic, problem, _ = self.member.receive(key, payload, att)
        if problem is not None:
            self.rejects.reject(topic, problem)

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
        return t_ns

    def reset_inputs(self) -> None:
        """Forget every input sample and pending tick (the plant went, or its world was reset
        from inside ``step``: the new world's clock starts again at 0)."""
        self.member.reset()

    # ----------------------------------------------------------------- loop
    def run(self, max_ticks: int | None = None) -> int:
        inbox = Inbox(self.session)
        for key in self.member.slot_of:
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
        run = _Run(tokens, max_ticks, last_loop=time.monotonic())
        # one handler per event tag (bus.inbox.Event.tag); each says whether to stop
        handlers = {"end": self._on_end, "plant": self._on_plant, "member": self._on_member,
                    "clock": self._on_clock, "input": self._on_input}
        self.log.info("%s on robot%s %s: mode %s, inputs %s%s", self.name,
                      "s" if len(self.slots) > 1 else "", ", ".join(self.robots), self.mode,
                      ", ".join(self.slots[0].inputs) or "none", ", lockstep member" if self.sync else "")
        try:
            while not self.stop_event.is_set():
                ev = inbox.get(timeout=0.2)
                now = time.monotonic()
                if self._time_is_up(run, now):
                    break
                if ev is None:
                    if self.sync and run.plant_here and self._producer_gone(run.left, now):
                        break
                    continue
                if handlers[ev.tag](ev, run, now):
                    break
            if self.final_tick is not None and self.sync:
                self._linger(inbox, self.final_tick)
        finally:
            for tok in tokens.values():
                tok.undeclare()
            inbox.close()
        return self.exit_code

    def _time_is_up(self, run: _Run, now: float) -> bool:
        """Before each event: note a stall of this process, and stop once the end's text
        is overdue or (--wait) a lost plant has been waited for long enough."""
        if now - run.last_loop > LEASE_S:      # this process was stopped (SIGSTOP) or starved
            run.stall_s, run.stalled = now - run.last_loop, now
        run.last_loop = now
        if run.end_token_at is not None and now - run.end_token_at >= END_TEXT_WAIT_S:
            self.log.info("the simulation ended (the plant ended it); stopping")
            return True
        if self.wait and self.watch.expired(now):      # --wait, not past a run's end
            self.log.error("%s; stopping", self.watch.why(now))
            self.exit_code = EXIT_PLANT_GONE
            return True
        return False

    def _on_end(self, ev: Event, run: _Run, now: float) -> bool:
        """``sim/end``: its token (the text follows) or its text (stop, or with --wait and
        no plant seen yet, wait for one)."""
        if not ev.alive or (not run.plant_here and not ev.payload):
            return False             # the end token withdrawn, or a repeat of the end
        if not ev.payload and not (self.wait and not run.plant_seen):
            run.end_token_at = run.end_token_at or now     # the token: the text follows
            return False
        reason = ev.payload.decode("utf-8", "replace") or "the plant ended it"
        if self.wait and not run.plant_seen:     # --wait: for a plant to start
            self.log.warning("the simulation ended (%s); waiting for a plant (--wait)", reason)
            run.plant_here = False
            self.reset_inputs()
            return False
        self.log.info("the simulation ended (%s); stopping", reason)
        return True

    def _on_plant(self, ev: Event, run: _Run, now: float) -> bool:
        """The plant's ``sim/alive`` token came (again) or went."""
        if ev.alive:
            if run.plant_seen and not run.plant_here and not self._plant_back(run.tokens):
                return True
            run.plant_seen = run.plant_here = True
            self.watch.here()
            return False
        if not run.plant_here:
            return False
        run.plant_here = False
        if run.end_token_at is not None:     # gone after its end: the text may still come,
            return False                     # END_TEXT_WAIT_S at most
        if self.wait:       # inputs kept: the plant may be the same, back
            self.plant_lost += 1
            self.watch.gone(now)
            self.log.warning("the plant is gone; waiting for it to come back (--wait), up to "
                             "%g s (the run's rejoin timeout + %g s)", self.watch.limit_s,
                             self.watch.limit_s - self.watch.rejoin_timeout_s)
            return False
        if now - run.stalled < 5.0:
            self.log.error("the plant is gone: this process was stopped for %.1f s, longer "
                           "than the %.0f s bus lease, so the simulation dropped it; stopping",
                           run.stall_s, LEASE_S)
        else:
            self.log.error("the plant is gone; stopping")
        self.reset_inputs()
        self.exit_code = EXIT_PLANT_GONE
        return True

    def _on_member(self, ev: Event, run: _Run, now: float) -> bool:
        """A lockstep member's ``sim/sync`` token: who left, and when (_producer_gone)."""
        node = self.keys.node_of(ev.key)
        if not ev.alive and node != self.name:
            run.left[node] = now
        elif ev.alive:
            run.left.pop(node, None)
        return False

    def _on_clock(self, ev: Event, run: _Run, now: float) -> bool:
        """``sim/clock``: free running, act on it; lockstep, answer a re-published tick again
        or act on every tick now due."""
        t_ns = self._clock(ev.payload)
        if t_ns is None:
            return False
        att = codec.parse_attachment(ev.attachment)
        resend, problem = self.member.clock(t_ns, now, att.epoch if att is not None else None)
        if problem:
            self.rejects.reject("clock", problem)
        if not self.sync:
            return self._act(t_ns) or run.enough(self.ticks)
        if resend is not None:       # re-published after a rejoin
            self._send(resend, t_ns)
            return False
        return self._act_due(run)

    def _on_input(self, ev: Event, run: _Run, now: float) -> bool:
        """An input sample: filed; lockstep, it may complete a tick."""
        self._input(ev.key, ev.payload, ev.attachment)
        return self.sync and self._act_due(run)

    def _act_due(self, run: _Run) -> bool:
        """Lockstep: act on every tick whose inputs are all in; True once finished."""
        while (t_ns := self.member.next_due()) is not None:
            if self._act(t_ns) or run.enough(self.ticks):
                return True
        return False

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
        True once every controller is done (:meth:`bus.member.MemberTick.act`)."""
        sent, finished = self.member.act(t_ns)
        self._send(sent, t_ns)
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
        last = self.member.last_clock
        if last is None or t_plant < last:
            self.reset_inputs()                # another run (or world): start afresh
        # else the same run, back after a blip (its router or link): carry on where we were
        self.log.warning("the plant is back (%s mode, t=%.3f s); carrying on", self.mode,
                         t_plant * 1e-9)
        return True

    def _producer_gone(self, left: dict[str, float], now: float) -> bool:
        """Lockstep: a tick has every plant sensor it needs but waits for another node's
        output, and a member left the simulation since: that output will never come."""
        if not left or not self.member.pending:
            return False
        for t_ns, came in self.member.pending.items():
            missing = self.member.missing(t_ns)
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
