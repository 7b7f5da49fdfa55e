"""What the plant takes in from its members, and the commands that act at a tick.

:class:`Intake` files a member's message on a key the plant reads: in lockstep in the ACK
ledger (:class:`bus.lockstep.AckLedger`), a command checked and filed in the plant's
:class:`plant.commands.CommandBook` (docs/PROTOCOL.md sections 4 and 7). A process member's
message comes one by one from Zenoh (:meth:`Intake.output`); a composed member's answer to a
tick comes whole (:meth:`Intake.answer`), with the same effects as its messages one by one,
its shared attachment checked once and its commands checked on the values they were packed
from. :meth:`Intake.apply` hands every robot the command the mode picks for the tick.
"""
from __future__ import annotations

import time

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
        self._names: list[str] = []                     # (the same, apart)
        self._timeouts: list[float] = []
        self._checks: dict[str, TwistCheck] = {}

    def _tables(self):
        """The world's robots in order with their command timeouts, and each robot's
        :class:`TwistCheck`: made once per world."""
        p = self.plant
        sim = p.sim
        if sim is not self._sim:
            self._sim = sim
            self._robots = [(n, r.spec.drive.cmd_timeout_s) for n, r in sim.robots.items()]
            self._names = [n for n, _ in self._robots]
            self._timeouts = [t for _, t in self._robots]
            check_age = p.strategy.check_age
            self._checks = {n: TwistCheck(r.spec.drive, p.tick_ns, check_age)
                            for n, r in sim.robots.items()}
        return sim

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

    def answer(self, msgs: list[Emitted]) -> None:
        """A composed member's answer to one tick: of its messages, those on keys the plant
        reads, as :meth:`output` of each in order (the ledger's filing and reports, the
        commands and their rejections), with the attachment they share checked once
        (:meth:`bus.lockstep.AckLedger.file_many`) and each cmd_vel's values checked by the
        robot's :class:`TwistCheck` (one it refuses goes through :meth:`output`'s path, for
        its error)."""
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

    # ------------------------------------------------------------------ the tick's commands
    def apply(self) -> None:
        """Hand each robot the command that acts at this tick (the mode's), or zero if it
        has none or it timed out; in lockstep, any other than the rule's is a protocol error."""
        p = self.plant
        sim = self._tables()
        strategy = p.strategy
        robots, names = self._robots, self._names
        picked = strategy.commands(names)
        # lockstep: an older command than the rule's acting here is a protocol error (asked
        # only where a robot's command is not the tick's: nothing else can be stale)
        if strategy.lockstep and not p.stop_event.is_set():
            due = sim.time_ns - strategy.delay_ns
            if due >= 0 and picked and _stamps(picked) != {due}:
                keys = lambda r: (p._key(r, "cmd_vel"), p._key(r, "wheel_cmd"))  # noqa: E731
                stale_commands(p.ledger, p.commands, due, dict(zip(names, picked)), keys,
                               p.protocol_errors.reject)
        expired = strategy.expired_all(picked, self._timeouts)
        drive = p.tick.drive
        if True not in expired:          # (the usual tick: no command timed out)
            for name, cmd in zip(names, picked):
                drive(name, cmd.value if cmd is not None else None)
            return
        for (name, timeout), cmd, old in zip(robots, picked, expired):
            if old:
                if cmd.moving:       # a robot told to stand still needs no stopping
                    p.log.warning("%s: no command for %.2f s (cmd_timeout %.2f s): "
                                  "stopping it", name, strategy.age_s(cmd), timeout)
                p.commands.forget(name, cmd.t_ns)
                cmd = None
            drive(name, cmd.value if cmd is not None else None)
