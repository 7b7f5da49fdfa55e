"""The plant process: owns simulated time, steps DART, publishes sensors, applies commands.

Each tick the loop runs three phases: **publish** the sensors due and then ``sim/clock``,
wait at the tick's **barrier**, **step** to the next tick with the commands that act on
it. What the barrier waits for is the mode's (:mod:`plant.modes`; docs/PROTOCOL.md for
lockstep, whose ledger is :class:`bus.lockstep.AckLedger`):

* **lockstep** — the ACKs of every lockstep member (liveliness ``sim/sync/<node>``) for
  the tick (sequential coupling) or the one before (pipelined: the plant steps while the
  members compute). A member that dies leaves the set at once; a frozen one when its
  lease runs out.
* **realtime** — the wall clock, times ``--rate``; the last command is held; a robot whose
  command is older than its ``cmd_timeout_s`` is stopped.
* **fast** — nothing: free running.

With ``--physics-process`` DART steps in a process of its own and, where the mode allows,
publishing overlaps the step (:mod:`plant.stepper`). Bad commands (undecodable, NaN/inf,
absurd speeds, unknown joints) are counted and logged at a limited rate; they never reach
the physics (:mod:`plant.commands`).

Threads: Zenoh callbacks only queue events in the inbox (:mod:`bus.inbox`); the main
thread alone touches the plant's state, and ``sim/info`` is answered from a snapshot
the main thread keeps.
"""
from __future__ import annotations

import json
import threading
import time

import zenoh

from bus import codec, jsonio, packed
from bus.composed import Composed
from bus.inbox import Event, Inbox
from bus.keys import Keys
from bus.lockstep import AckLedger
from bus.log import RejectCounter
from bus.protocol import PLANT_READS, world_max_hold

from . import core, modes, report
from .commands import CommandBook
from .camera_handover import CameraHandover
from .intake import Emitted, Intake
from .outbox import Outbox, Reads
from .presence import PLANT_TOKEN, Presence
from .reset import parse_reset
from .routerwatch import RouterWatch
from .tick import Tick
from .world import WorldSpec

#: how long the sim/end text goes before the sim/end token (wall s)
END_TEXT_HEAD_START_S = 0.1


class Plant:
    """The plant's bus side around the world's tick (:class:`plant.tick.Tick`): it
    publishes, waits at the mode's barrier, applies the commands and steps."""

    def __init__(self, spec: WorldSpec, session: zenoh.Session, keys: Keys, mode: str, log,
                 rate: float = 1.0, expect: tuple[str, ...] = (), duration_s: float | None = None,
                 join_timeout_s: float = 30.0, disabled: tuple[str, ...] = (),
                 end_with: tuple[str, ...] = (), coupling: str = "sequential",
                 physics_process: bool = False, rejoin_timeout_s: float = 0.0,
                 skip_unread: bool = True, composed: Composed | None = None,
                 watchers: tuple[str, ...] = ()) -> None:
        self.spec = spec
        self.session = session
        self.keys = keys
        self.mode = mode
        self.log = log
        self.rate = rate
        self.expect = tuple(expect)
        self.watchers = set(watchers)      # processes (sim/alive) to wait for, not members
        self.duration_ns = None if duration_s is None else int(round(duration_s * 1e9))
        self.join_timeout_s = join_timeout_s
        # lockstep: how long time is held for a lost member to come back (0: end at once)
        self.rejoin_timeout_s = rejoin_timeout_s
        self.exit_code = 0
        self.tick_ns = spec.tick_ns
        self.coupling = coupling
        # what the loop waits for between publishing and stepping (plant/modes.py), and
        # what the mode asks of the plant; the coupling's delays, in ticks (docs/PROTOCOL.md)
        self.strategy = modes.make(mode, self, coupling)
        self.delays = self.strategy.delays
        lockstep = self.strategy.lockstep
        self.seed = spec.seed
        #: the world's epoch, in every attachment the plant sends and in sim/info: +1 at
        #: each reset or rebuild (restart_world; docs/PROTOCOL.md section 3)
        self.epoch = 0
        # the world's tick (plant/tick.py); DART in a process of its own with physics_process
        self.tick = Tick(spec, disabled, physics_process, overlap=self.strategy.overlaps)
        self.commands = CommandBook(lockstep=lockstep)
        # members composed into this process (bus/composed.py): fed the plant's bytes directly
        self.composed = composed
        self.rejects = RejectCounter(log)
        # lockstep protocol problems (no or bad attachment, a tick not due, missing outputs),
        # counted per kind and said at most every 2 s
        self.protocol_errors = RejectCounter(log, verb="lockstep protocol:")
        self.ledger = AckLedger(self.tick_ns, self.protocol_errors.reject, end_with, expect)
        self.ledger.max_hold = world_max_hold(
            self.tick_ns, (r.spec.drive.cmd_timeout_s for r in self.sim.robots.values()),
            self.delays["actuation_delay_ticks"])
        self.stop_event = threading.Event()
        self.reset_in_tick = False               # a sim/reset came during the current tick
        self.ticks = 0
        self.timing = {"publish_s": 0.0, "wait_s": 0.0, "physics_s": 0.0}
        self.wall_start = 0.0
        self.end_reason = "stopped"
        self.wall_end = 0.0
        self.cpu_start = self.cpu_end = (0.0, None)   # (report.cpu_now) around the loop
        # In lockstep nothing may be lost: block rather than drop when a queue is full.
        self.congestion = (zenoh.CongestionControl.BLOCK if lockstep
                           else zenoh.CongestionControl.DROP)
        # (only on the plant's own router session: see plant/outbox.py); in lockstep the
        # last ticks are kept to re-publish for a member that rejoins
        self.outbox = Outbox(session, self.congestion, skip_unread, keep=lockstep)
        self.published = self.outbox.published
        self._keys: dict[tuple[str, str], str] = {}
        self.inbox = Inbox(session)
        self._robot_of_key: dict[str, tuple[str, str]] = {}
        self._ack_prefix = keys.ack("")
        # members' outputs filed, commands checked, and the tick's commands handed over
        self.intake = Intake(self)
        self._listen()
        # who is here (sim/alive, sim/sync tokens) and what the plant does when one comes
        # or goes; who time is held for is the ledger's
        self.presence = Presence(self)
        # sim/info is answered on Zenoh's thread, from what the main thread last put here
        self._info = self.info()
        self._info_queryable = session.declare_queryable(keys.info, self._answer_info)
        self._token = session.liveliness().declare_token(keys.alive(PLANT_TOKEN))
        self.router = RouterWatch(session, log, mode, on_lost=self.presence.link_lost)

    def _listen(self) -> None:
        """What the plant reads, as inbox events: its robots' commands and (lockstep) the
        members' outputs and ACKs, the watchers' sim/seen, another process's outputs that a
        composed member reads, the sim/sync and sim/alive tokens, sim/reset queries."""
        keys, inbox, lockstep = self.keys, self.inbox, self.strategy.lockstep
        for name in self.sim.robots:
            for topic in PLANT_READS:
                if topic == "odom" and not lockstep:
                    continue                     # read only for lockstep members' ACKs
                key = keys.topic(name, topic)
                self._robot_of_key[key] = (name, topic)
                inbox.subscribe(key, "out", remote_only=True)
        inbox.subscribe(keys.ack(), "out", remote_only=True)
        if lockstep:                             # watchers that keep up (a recorder)
            inbox.subscribe(keys.seen(), "seen", remote_only=True)
        composed = self.composed
        for key in sorted(composed.foreign_input_keys() if composed else ()):
            if key not in self._robot_of_key:    # another process member's output
                inbox.subscribe(key, "input", remote_only=True)
        inbox.watch_liveliness(keys.sync(), "member")
        inbox.watch_liveliness(keys.alive(), "alive")
        inbox.serve(keys.reset, "reset")

    @property
    def sim(self):
        return self.tick.sim

    @property
    def time_ns(self) -> int:
        return self.tick.sim.time_ns

    def restart_world(self, reason: str, rebuilt: bool = False) -> None:
        """Rebuild the world at t = 0 (a sim/reset, or the physics diverged: ``rebuilt``
        already) and forget everything of the old one: commands, ACKs (docs/PROTOCOL.md
        section 4, "Reset"), the realtime pacing origin."""
        if not rebuilt:
            self.tick.build()
        self.commands.clear()
        self.outbox.recent.clear()     # the old world's ticks are never re-published
        self.epoch += 1                # a new world: members tell it from a re-publish
        self.ledger.restart()
        self.strategy.restarted()
        self._info = self.info()
        self.log.info("world rebuilt (seed %d): %s", self.seed, reason)

    # ------------------------------------------------------------------ queryables
    def info(self) -> dict:
        """What ``sim/info`` answers (docs/PROTOCOL.md section 5; :mod:`plant.report`)."""
        return report.info(self)

    def _answer_info(self, query: zenoh.Query) -> None:
        """Zenoh's thread: the snapshot, with the time the main thread last published."""
        query.reply(self.keys.info, jsonio.dumps(self._info))

    def _reset(self, query: zenoh.Query, payload: bytes) -> None:
        """Rebuild the world (``world.reset()`` only resets DART's clock), optionally with a
        new seed or new start poses: ``{"seed": 3, "poses": {"robot1": [x, y, yaw]}}``."""
        try:
            req = json.loads(payload) if payload.strip() else {}
            seed, poses = parse_reset(req, self.spec, self.sim.robots)
        except (ValueError, RecursionError) as exc:   # JSONDecodeError is a ValueError
            self.rejects.reject("reset", str(exc))
            query.reply_err(jsonio.dumps({"error": str(exc)}))
            return
        # Checked in full before anything changes: a bad request leaves the world as it was.
        if seed is not None:
            self.seed = seed
        self.tick.reset(seed, poses)
        self.restart_world("sim/reset", rebuilt=True)
        # Answered at once, even while the plant waits for a tick's ACKs (a node may ask
        # from inside its step); the loop then starts over at the new world's t = 0.
        self.reset_in_tick = True
        query.reply(self.keys.reset, jsonio.dumps({"ok": True, "seed": self.seed, "time_ns": 0,
                                                   "epoch": self.epoch}))

    # ------------------------------------------------------------------ publishing
    def republish(self) -> None:
        """A lost member is back: the messages of the last ticks again, as they were (the
        member answers the ones it has not, re-sends its answer to the others; section 4,
        "Lost members"); whatever of them the blip swallowed reaches everyone now. (A key
        once read is built from then on, :mod:`plant.outbox`: the member's keys are here.)"""
        ticks = self.outbox.republish(self.sim.time_ns, self.epoch)
        self.ledger.resent_upto = max(ticks, default=-1)
        if ticks:
            self.log.info("re-published ticks t=%s s", ", ".join(f"{t * 1e-9:.3f}" for t in ticks))

    def publish_sensors(self) -> None:
        """The sensors due at this tick that someone reads (:mod:`plant.outbox`), robot by
        robot, ``sim/poses`` if read, then ``sim/clock``; then the next tick's sensor noise
        is drawn ahead (prefetch), off the members' critical path. Where every lockstep
        member is composed here, no process waits for the tick's messages before its
        members have answered: its puts then go out together, after those answers
        (:meth:`plant.outbox.Outbox.hold`)."""
        together = (self.composed is not None and self.strategy.lockstep
                    and self.composed.hosts(self.ledger.members))
        if together:
            self.outbox.hold()
        try:
            self._sensors_out()
        finally:
            if together:
                self.outbox.flush()
        self.tick.prefetch()

    def _sensors_out(self) -> None:
        t = self.sim.time_ns
        out, composed = self.outbox, self.composed
        due, msgs = self.tick.messages_read(self._wanted_all())
        if composed is not None:                      # (values its members take: no decoding)
            self._handover = CameraHandover.of(self._handover, self.tick.model,
                                               self.tick.data)
            handed = self._handover.at(t)
            if composed.takes_scans and (rows := self._handover.scan_rows(t)):
                composed.deliver_scans(t, rows, self.tick.model.index)   # (as arrays)
        at = 0                                        # the due messages numbered so far
        for k, name, topic, data in msgs:
            if k > at:
                out.skip(k - at)                      # due, but nobody reads them
            at = k + 1
            key = self._key(name, topic)
            if composed is None or out.reads(key):    # (else only a composed member reads it)
                if data is core.UNENCODED:            # (a reader came since the tick's plan)
                    data = codec.encode(handed(name, topic))
                out.put(key, data, t, self.epoch)
            else:
                out.skip()
            if composed is not None and composed.delivers(key):
                composed.deliver(key, data, None, handed(name, topic))
        if due > at:
            out.skip(due - at)
        key = self.keys.poses                         # every robot's pose, one message
        if out.reads(key):
            out.put(key, core.poses(self.tick.model, self.tick.data, 0, t), t, self.epoch)
        else:
            out.skip()
        key = self.keys.clock                         # (members composed here are told below)
        if composed is None or out.reads(key):
            out.put(key, packed.clock(t), t, self.epoch)
        else:
            out.skip()
        if composed is not None:
            composed.clock(t, self._emit_many, self.epoch)
            composed.run(self._emit_many)

    def publish_pending(self) -> None:
        """This tick's sensors, if they have not gone out yet (the run ends)."""
        if self.tick.publish_due():
            self._publish()

    def _publish(self) -> None:
        c0 = time.perf_counter()
        self.publish_sensors()
        self.timing["publish_s"] += time.perf_counter() - c0

    def _emit_many(self, msgs: list[Emitted], twists: tuple | None = None) -> None:
        """A composed member's answer to a tick (bus/composed.py): each message on the bus
        for whoever listens, then those the plant reads filed at once as if they came from
        Zenoh (a command as the values it was packed from: :meth:`Intake.answer`), and each
        to the other composed members."""
        relay = self.outbox.relay
        for key, payload, att, parsed, _ in msgs:
            relay(key, payload, parsed.t_ns, att)
        self.intake.answer(msgs, twists)
        if twists is not None and not self.composed.reads_any(twists[0]):
            return                       # (one Twist per robot that no composed member reads)
        deliver = self.composed.deliver
        for key, payload, att, _, _ in msgs:
            deliver(key, payload, att)

    def _key(self, robot: str, topic: str) -> str:
        key = self._keys.get((robot, topic))
        if key is None:
            key = self._keys[(robot, topic)] = self.keys.topic(robot, topic)
        return key

    _handover: CameraHandover | None = None  # composed members' tick values (plant.handover)
    _wanted: tuple = (None, None)    # (the outbox's readers, :meth:`_wanted_all`'s dict)

    def _wanted_all(self) -> dict:
        """Every robot's ``wanted(topic)``: whether anyone reads that topic of the robot now
        (a subscriber on the bus, a composed member). Each topic is asked once and the
        answers kept until the bus's subscribers change (:meth:`plant.outbox.Outbox.readers`),
        so a tick asks a dict, not the bus, for every robot's topics."""
        readers = self.outbox.readers()
        if self._wanted[0] is not readers or self._wanted[1] is None:
            reads, key = self.outbox.reads, self._key
            local = self.composed.reads if self.composed is not None else None

            def ask(robot: str):
                if local is None:
                    return lambda topic: reads(key(robot, topic))
                return lambda topic: reads(key(robot, topic)) or local(key(robot, topic))

            def only_local(robot_topic: tuple[str, str]) -> bool:
                k = key(*robot_topic)           # (only composed members read it: values)
                return local(k) and not reads(k)
            bare = Reads(only_local).__getitem__

            self._wanted = (readers, core.Settled(
                {name: Reads(ask(name)).__getitem__ for name in self.tick.sensors},
                (lambda robot, topic: bare((robot, topic))) if local is not None else None))
        return self._wanted[1]

    # ------------------------------------------------------------------ input
    def handle(self, ev: Event) -> None:
        if ev.tag == "reset":
            self._reset(ev.query, ev.payload)
            return
        if ev.tag == "out":
            self._on_output(ev)
        if ev.tag in ("out", "input"):
            if self.composed is not None:     # a process member's output a composed one reads
                self.composed.deliver(ev.key, ev.payload, ev.attachment)
            return
        if ev.tag == "seen":
            self.presence.on_seen(ev)
            return
        self.router.check(self.sim.time_ns, now=True)   # a token came or went: the router?
        if ev.tag == "alive":
            self.presence.on_alive(ev)
        elif ev.tag == "member":
            self.presence.on_member(ev)

    def _on_output(self, ev: Event) -> None:
        """A process member's message on a key the plant reads (:meth:`Intake.output`)."""
        self.intake.output(ev.key, ev.payload, ev.attachment)

    def apply_commands(self) -> None:
        """Hand each robot the command that acts at this tick (:meth:`Intake.apply`)."""
        self.intake.apply()

    def drain(self, timeout: float | None = 0.0) -> bool:
        """Handle queued events; wait up to ``timeout`` for the first. True if any came."""
        self.router.check(self.sim.time_ns)
        self.presence.settle()
        ev = self.inbox.get(timeout=timeout) if timeout else self.inbox.get_nowait()
        if ev is None:
            return False
        self.handle(ev)
        while (ev := self.inbox.get_nowait()) is not None:
            self.handle(ev)
        if self.composed is not None:
            self.composed.run(self._emit_many)      # what came may complete a composed member's tick
        return True

    # ------------------------------------------------------------------ loop
    def wait_for_members(self) -> bool:
        """Before the first tick: wait for the expected nodes (in lockstep, for any member
        if none were named)."""
        want = set(self.expect)
        deadline = time.monotonic() + self.join_timeout_s
        if want or self.watchers:
            self.log.info("waiting for nodes: %s", ", ".join(sorted(want | self.watchers)))
        else:
            self.log.info("lockstep: waiting for a controller to join (or use --mode fast)")
        while not self.stop_event.is_set():
            self.drain(0.1)
            alive = self.presence.alive
            present = self.ledger.members if self.strategy.lockstep else alive
            watched = self.watchers <= alive
            if watched and ((want and want <= present) or (not want and present)):
                return True
            if (want or self.watchers) and time.monotonic() > deadline:
                missing = (want - present) | (self.watchers - alive)
                self.log.error("nodes did not join within %.0f s: %s",
                               self.join_timeout_s, ", ".join(sorted(missing)))
                return False
        return False

    def run(self) -> int:
        """Publish, wait at the barrier, step; until stopped, the duration, or an end-with
        member's FINAL."""
        if self.composed is not None:
            self.composed.start(self.info())
        self.drain(0.05)
        if (self.strategy.lockstep or self.expect or self.watchers) \
                and not self.wait_for_members():
            return 1 if not self.stop_event.is_set() else 0
        self.wall_start = time.monotonic()
        self.cpu_start = report.cpu_now(self)
        self.strategy.start()
        report.say_running(self)
        # each phase's wall time (summary.json's plant_per_tick_ms), read around it in the
        # loop (a context manager a phase a tick costs more than the reads)
        timing, clock = self.timing, time.perf_counter
        try:
            while not self.stop_event.is_set():
                t = self.sim.time_ns
                self.ledger.begin_tick(t)
                if self.tick.begin():           # (else the step publishes them: overlap)
                    self._publish()
                c0 = clock()
                ended = self._duration_reached(t) or self.strategy.barrier(t)
                timing["wait_s"] += clock() - c0
                if ended:
                    self.end_reason = ended
                    break
                if self.reset_in_tick:          # the world was rebuilt: publish its t = 0
                    self.reset_in_tick = False
                    continue
                self.apply_commands()
                c0 = clock()
                overlap = self.tick.start_step()
                c1 = clock()
                if overlap:                     # this tick's, while the physics process steps
                    self._publish()
                c2 = clock()
                finite = self.tick.finish_step()
                timing["physics_s"] += (c1 - c0) + (clock() - c2)
                self.ticks += 1
                self._info = dict(self._info, time_ns=self.sim.time_ns)
                if not finite:
                    self.log.error("physics diverged at t=%.3f s", t * 1e-9)
                    self.restart_world("the physics diverged", rebuilt=True)
        finally:
            self.wall_end = time.monotonic()
            self.cpu_end = report.cpu_now(self)
        if self.end_reason != "stopped":      # (an end of its own, not a stop signal)
            self.presence.last_tick_taken_in(self.sim.time_ns)
        return 0

    def _duration_reached(self, t_ns: int) -> str | None:
        if self.duration_ns is None or t_ns < self.duration_ns:
            return None
        self.publish_pending()
        self.strategy.at_end(t_ns)
        return "duration reached"

    def stats(self) -> dict:
        return report.stats(self)

    def close(self, reason: str = "stopped") -> None:
        """Tell the nodes the simulation ended (so they exit 0, not "plant gone"), then leave."""
        end_token = None
        try:
            self.session.put(self.keys.end, reason.encode())
            # The text goes first; data and liveliness take different paths, so give it a
            # head start (a client that sees the token first waits for the text:
            # docs/PROTOCOL.md section 4, "End").
            time.sleep(END_TEXT_HEAD_START_S)
            # Also as a liveliness token: declarations are ordered with the undeclaration
            # of sim/alive/plant below, so a node always sees the end before the absence.
            end_token = self.session.liveliness().declare_token(self.keys.end)
            time.sleep(0.05)
        except Exception:
            pass
        self._token.undeclare()
        if end_token is not None:
            end_token.undeclare()
        self._info_queryable.undeclare()
        self.inbox.close()
        self.outbox.undeclare()
        if self.composed is not None:
            self.composed.close()
        self.tick.close()

