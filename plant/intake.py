"""What the plant takes in from its members, and the commands that act at a tick.

:class:`Intake` files a member's message on a key the plant reads: in lockstep in the ACK
ledger (:class:`bus.lockstep.AckLedger`), a command checked and filed in the plant's
:class:`plant.commands.CommandBook` (docs/PROTOCOL.md sections 4 and 7). A process member's
message comes one by one from Zenoh (:meth:`Intake.output`); a composed member's answer to a
tick comes whole (:meth:`Intake.answer`), with the same effects as its messages one by one,
its shared attachment checked once and its commands checked on the values they were packed
from; one Twist per robot from a many-robot member (:class:`bus.many.ManyTick`) is checked
and filed whole (:mod:`plant.command_rows`). :meth:`Intake.apply` hands every robot the
command the mode picks for the tick: in lockstep, where each is the tick's own, all at once.
"""
from __future__ import annotations

import math
import time

import numpy as np

from bus import codec
from bus.controller import Twist

from .commands import Command, TwistCheck, decode_command, stale_commands, twist_command

#: a composed member's message as the plant takes it: (key, payload, attachment bytes, the
#: attachment parsed, the (stamp, linear, angular) a cmd_vel was packed from or None)
Emitted = tuple[str, bytes, bytes, "codec.Attachment | None", "tuple | None"]
_COMMANDS = ("cmd_vel", "wheel_cmd")
_ACK = (None, "ack")


def _stamps(cmds: list) -> set:
    """The stamps of ``cmds``, with None among them if any is None (no command)."""
    try:
        return {c.t_ns for c in cmds}
    except AttributeError:
        return {None}


class Intake:
    """A plant's intake of its members' outputs and its commands' hand-over (module
    docstring). ``plant``: the :class:`plant.process.Plant` (its strategy, ledger, command
    book, counters, tick and keys, read as they are at each call)."""

    def __init__(self, plant) -> None:
        self.plant = plant
        self._sim = None                     # the world the per-robot tables below are of
        self._robots: list[tuple[str, float]] = []     # (robot, cmd_timeout_s) in order
        self._names: tuple[str, ...] = ()                # (the same, apart)
        self._many: dict[int, tuple] = {}                # _rows_of's answers
        self._timeouts: list[float] = []
        self._checks: dict[str, TwistCheck] = {}

    def _tables(self):
        """The world's robots in order with their command timeouts, and each robot's
        :class:`TwistCheck`: made once per world (and the same as arrays, by robot row of
        the command book's :meth:`~plant.commands.CommandBook.bind`)."""
        p = self.plant
        sim = p.sim
        if sim is not self._sim:
            self._sim = sim
            self._robots = [(n, r.spec.drive.cmd_timeout_s) for n, r in sim.robots.items()]
            self._names = tuple(n for n, _ in self._robots)
            self._timeouts = [t for _, t in self._robots]
            check_age = p.strategy.check_age
            self._checks = {n: TwistCheck(r.spec.drive, p.tick_ns, check_age)
                            for n, r in sim.robots.items()}
            # (command_expired's bound, in whole ns: the least of any robot's)
            self._expiry_ns = min((round(t * 1e9) for t in self._timeouts), default=0)
            self._value = np.zeros((len(self._names), 2))
            self._many = {}
            p.commands.bind(self._names)
        return sim

    def _rows_of(self, keys: list[str]) -> tuple | None:
        """For ``keys``, a composed member's cmd_vel keys (its robots' in order): (their
        robots, their rows in :meth:`plant.commands.CommandBook.bind`'s order, the rows as
        a set, the keys as a set, the least of the robots' :class:`TwistCheck` limits
        (linear, angular, age), the rows as an array), or None if one is not a distinct
        cmd_vel key of this world's robots; made once per list of keys and world."""
        got = self._many.get(id(keys))
        if got is None or got[0] is not keys:
            robot_of, book = self.plant._robot_of_key, self.plant.commands.rows
            robots = [robot_of.get(k, _ACK) for k in keys]
            made = None
            if book is not None and keys and len(set(keys)) == len(keys) \
                    and all(t == "cmd_vel" and r in book.row for r, t in robots):
                names = [r for r, _ in robots]
                rows = tuple(book.row[r] for r in names)
                checks = [self._checks[r] for r in names]
                ages = [c.timeout_ns for c in checks]
                made = (names, rows, frozenset(rows), frozenset(keys),
                        min(c.lim_a for c in checks), min(c.lim_b for c in checks),
                        None if None in ages else min(ages), np.array(rows, np.intp))
            got = self._many[id(keys)] = (keys, made)
        return got[1]

    # ------------------------------------------------------------------ members' outputs
    def output(self, key: str, payload: bytes, raw: bytes | None,
               att: codec.Attachment | None = None, twist: tuple | None = None) -> None:
        """A message on a key the plant reads: a command to apply, and in lockstep a
        member's output, filed in the ledger for its tick (``raw``: its attachment bytes;
        ``att``: parsed already by a composed member's emit; ``twist``: the values its
        cmd_vel was packed from, :func:`plant.commands.twist_command`)."""
        p = self.plant
        robot, topic = p._robot_of_key.get(key, (None, "ack"))
        if att is None:
            att = codec.parse_attachment(raw)
        now = p.sim.time_ns
        if p.strategy.lockstep and not p.ledger.file(key, topic, att, raw, now):
            return
        if topic in ("cmd_vel", "wheel_cmd"):
            self._command(robot, topic, payload, att, twist, now)

    def _command(self, robot: str, topic: str, payload: bytes, att: codec.Attachment | None,
                 twist: tuple | None, now: int) -> None:
        p = self.plant
        lockstep = p.strategy.lockstep
        drive = p.sim.robots[robot].spec.drive
        try:
            value, t = (twist_command(*twist, drive, now, p.tick_ns, p.strategy.check_age)
                        if twist is not None else
                        decode_command(payload, topic, drive, now, p.tick_ns,
                                       check_age=p.strategy.check_age, robot=robot))
        except (codec.CodecError, ValueError) as exc:
            p.rejects.reject(f"{robot}/{topic}", str(exc))
            if att is not None:
                p.commands.refuse(robot, att.t_ns)      # (not a stale command)
            return
        if lockstep and att is not None:
            t_cmd = att.t_ns           # the tick it was computed for (0: tick 0, not "now")
        else:
            t_cmd = t or now
        member = att.node if att is not None else None
        self._file(robot, Command(value, t_cmd, time.monotonic(), member))

    def _file(self, robot: str, cmd: Command) -> None:
        p = self.plant
        problem = p.commands.file(robot, cmd)
        if problem:
            p.protocol_errors.reject(f"{robot}: two members command it", problem)

    def answer(self, msgs: list[Emitted], twists: tuple | None = None) -> None:
        """A composed member's answer to one tick: of its messages, those on keys the plant
        reads, as :meth:`output` of each in order (the ledger's filing and reports, the
        commands and their rejections), with the attachment they share checked once
        (:meth:`bus.lockstep.AckLedger.file_many`) and each cmd_vel's values checked by the
        robot's :class:`TwistCheck` (one it refuses goes through :meth:`output`'s path, for
        its error). ``twists``: (keys, stamp, linear, angular) where the answer is one
        Twist per robot (:class:`bus.many.ManyTick`), ``msgs`` their cmd_vel on ``keys``
        in order, the last with the ACK, ``linear``, ``angular`` the values they were
        packed from: in lockstep filed and checked whole (:meth:`_answer_twists`)."""
        if twists is not None and self._answer_twists(msgs, twists):
            return
        p = self.plant
        robot_of, ack_prefix = p._robot_of_key, p._ack_prefix
        ours = [(m, robot_of.get(m[0], _ACK)) for m in msgs
                if m[0] in robot_of or m[0].startswith(ack_prefix)]
        if not ours:
            return
        sim = self._tables()
        now = sim.time_ns
        lockstep = p.strategy.lockstep
        if lockstep:
            taken = p.ledger.file_many([(m[0], topic, m[3], m[2]) for m, (_, topic) in ours],
                                       now)
        else:
            taken = [True] * len(ours)
        checks, book = self._checks, p.commands
        wall = time.monotonic()      # (one reading for the answer: it came in one call)
        for ((key, payload, _, att, twist), (robot, topic)), took in zip(ours, taken):
            if not took or topic not in _COMMANDS:
                continue
            if twist is None or att is None:
                self._command(robot, topic, payload, att, twist, now)
                continue
            t, a, b = twist
            if not checks[robot].ok(t, a, b, now):
                self._command(robot, topic, payload, att, twist, now)
                continue
            problem = book.file(robot, Command(Twist(float(a), float(b)),
                                               att.t_ns if lockstep else (t or now), wall,
                                               att.node))
            if problem:
                p.protocol_errors.reject(f"{robot}: two members command it", problem)

    def _answer_twists(self, msgs: list[Emitted], twists: tuple) -> bool:
        """:meth:`answer` of one Twist per robot, whole (lockstep): the ledger's filing in
        one update (:meth:`bus.lockstep.AckLedger.file_answer`), every value checked
        against the least of the robots' limits, the commands filed as one batch
        (:meth:`plant.commands.CommandBook.file_twists`); False, with nothing done, where
        any of it has something to say or to check robot by robot (then message by
        message, for what it says)."""
        p = self.plant
        if not p.strategy.lockstep or not msgs:
            return False
        self._tables()
        keys, t_ns, linear, angular = twists
        got = self._rows_of(keys)
        if got is None or len(msgs) != len(keys):
            return False
        robots, rows, rowset, keyset, lim_a, lim_b, age_ns, ix = got
        first, last = msgs[0][3], msgs[-1][3]
        if first is None or last is None or first.t_ns != t_ns or last.t_ns != t_ns \
                or first.node != last.node:
            return False
        now = p.sim.time_ns
        # TwistCheck.ok of each: finite (a finite sum has no inf or NaN in it), not absurd,
        # stamped now (0) or neither in the future nor past the timeout
        if not (math.isfinite(sum(linear) + sum(angular))
                and max(linear) <= lim_a and -min(linear) <= lim_a
                and max(angular) <= lim_b and -min(angular) <= lim_b):
            return False
        if t_ns != 0 and not (0 < t_ns <= now + p.tick_ns
                              and (age_ns is None or now - t_ns <= age_ns)):
            return False
        key, _, _, att, _ = msgs[-1]
        if not p.ledger.file_answer(keyset, key, "cmd_vel", att, now):
            return False
        said = p.commands.file_twists(robots, rows, rowset, t_ns, linear, angular,
                                      time.monotonic(), att.node, ix)
        for robot, problem in said:
            p.protocol_errors.reject(f"{robot}: two members command it", problem)
        return True

    # ------------------------------------------------------------------ the tick's commands
    def apply(self) -> None:
        """Hand each robot the command that acts at this tick (the mode's), or zero if it
        has none or it timed out; in lockstep, any other than the rule's is a protocol error."""
        p = self.plant
        sim = self._tables()
        strategy = p.strategy
        if strategy.lockstep and p.commands.rows is not None \
                and hasattr(p.tick, "drive_twists") and self._apply_rows(sim):
            return
        picked = strategy.commands(self._names)
        self._stale(sim, picked)
        self._drive(picked)

    def _stale(self, sim, picked: list) -> None:
        """Lockstep: an older command than the rule's acting here is a protocol error (asked
        only where a robot's command is not the tick's: nothing else can be stale)."""
        p = self.plant
        strategy = p.strategy
        if strategy.lockstep and not p.stop_event.is_set():
            due = sim.time_ns - strategy.delay_ns
            if due >= 0 and picked and _stamps(picked) != {due}:
                names = self._names
                keys = lambda r: (p._key(r, "cmd_vel"), p._key(r, "wheel_cmd"))  # noqa: E731
                stale_commands(p.ledger, p.commands, due, dict(zip(names, picked)), keys,
                               p.protocol_errors.reject)

    def _drive(self, picked: list) -> None:
        """Each robot driven by its picked command, a timed-out one stopped and forgotten."""
        p = self.plant
        strategy = p.strategy
        names = self._names
        expired = strategy.expired_all(picked, self._timeouts)
        drive = p.tick.drive
        if True not in expired:          # (the usual tick: no command timed out)
            for name, cmd in zip(names, picked):
                drive(name, cmd.value if cmd is not None else None)
            return
        for (name, timeout), cmd, old in zip(self._robots, picked, expired):
            if old:
                if cmd.moving:       # a robot told to stand still needs no stopping
                    p.log.warning("%s: no command for %.2f s (cmd_timeout %.2f s): "
                                  "stopping it", name, strategy.age_s(cmd), timeout)
                p.commands.forget(name, cmd.t_ns)
                cmd = None
            drive(name, cmd.value if cmd is not None else None)

    def _apply_rows(self, sim) -> bool:
        """:meth:`apply` in lockstep with the command book's batches: where every robot's
        command is the tick's own (none stale, none timed out), those kept whole handed to
        the core's command arrays in one assignment, those kept one by one asked and driven
        after them; True. False where any is not (then robot by robot, with what it says)."""
        p = self.plant
        book = p.commands
        now = sim.time_ns
        upto = now - p.strategy.delay_ns
        if upto >= 0 and now - upto > self._expiry_ns:
            return False
        value = self._value
        if not book.pick_rows(upto, value):
            return False
        names = self._names
        apart = [(names[i], book.for_tick(names[i], upto)) for i in book.rows.apart]
        if upto >= 0 and any(c is None or c.t_ns != upto for _, c in apart):
            return False
        p.tick.drive_twists(names, value)
        drive = p.tick.drive
        for name, cmd in apart:
            drive(name, cmd.value if cmd is not None else None)
        return True
