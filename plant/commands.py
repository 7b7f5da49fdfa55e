"""Commands the plant receives: decoded, checked, filed per robot, and picked for a tick.

A bad command (undecodable, NaN/inf, absurd speeds, wrong frame, unknown joints, a stamp
in the future or older than ``cmd_timeout_s``) raises :class:`ValueError` here and never
reaches the physics (docs/PROTOCOL.md section 7). Which command acts at a tick follows
the mode: in lockstep the one computed for the latest tick at or before ``t_k -
actuation delay`` (section 4, "Couplings"), otherwise the latest one received; in
lockstep :func:`stale_commands` checks every tick that the older one acts only where the
rule allows it (a held tick stepped with the previous tick's command would be silent
otherwise: a protocol error says it).
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np

from bus import codec
from bus.lockstep import RECENT_TICKS      # commands per robot remembered by tick stamp
from bus.controller import Twist, WheelSpeeds
from bus.keys import frame
from bus.lockstep import AckLedger

from .command_rows import CommandRows

#: Commands beyond this multiple of a robot's limit are rejected as absurd, not clamped.
ABSURD_FACTOR = 10.0


@dataclass
class Command:
    value: Twist | WheelSpeeds
    t_ns: int          # the tick it was computed for (its stamp; sim time when received if 0)
    wall: float        # monotonic wall time when received
    member: str | None = None   # lockstep: the member that sent it (its trailer's name)

    @property
    def moving(self) -> bool:
        """Whether the command asks for any motion (a zero command needs no stopping)."""
        return any(float(v) != 0.0 for v in vars(self.value).values())


def wheel_speeds(msg) -> WheelSpeeds:
    """The two wheel velocities of a ``wheel_cmd`` JointState (unnamed: left, right)."""
    vel = np.asarray(msg.velocity, dtype=float)
    if len(vel) != 2:
        raise ValueError(f"wheel_cmd needs 2 velocities, got {len(vel)}")
    names = list(msg.name)
    if not names:
        return WheelSpeeds(float(vel[0]), float(vel[1]))
    if sorted(names) != ["left_wheel_joint", "right_wheel_joint"]:
        raise ValueError(f"unknown joint names {names}")
    d = dict(zip(names, vel))
    return WheelSpeeds(float(d["left_wheel_joint"]), float(d["right_wheel_joint"]))


class _Stamp(NamedTuple):
    sec: int
    nanosec: int


_TWIST_HEAD = struct.Struct("<4siII")           # encapsulation, stamp, frame_id's length
_SIX = struct.Struct("<6d")
_CDR_LE = b"\x00\x01\x00\x00"


def _twist_stamped(payload: bytes):
    """(stamp, frame_id, (vx, vy, vz, wx, wy, wz)) of a little-endian CDR TwistStamped laid
    out as every encoder lays it (no trailing bytes), or None for anything else, which
    :func:`codec.decode` then decodes or refuses (the same values: CDR has one layout)."""
    n = len(payload)
    if n < 64 or payload[:4] != _CDR_LE:
        return None
    _, sec, nanosec, length = _TWIST_HEAD.unpack_from(payload)
    end = 16 + length
    if length < 1 or n != 4 + ((end - 4 + 7) & ~7) + 48 or payload[end - 1] != 0:
        return None
    try:
        frame_id = payload[16:end - 1].decode("utf-8")
    except UnicodeDecodeError:
        return None
    return _Stamp(sec, nanosec), frame_id, _SIX.unpack_from(payload, n - 48)


def decode_command(payload: bytes, topic: str, drive, now_ns: int, tick_ns: int,
                   check_age: bool, robot: str = "") -> tuple[Twist | WheelSpeeds, int]:
    """(command, stamp in ns, 0 if unstamped) of a ``cmd_vel`` or ``wheel_cmd`` payload for
    ``robot`` with ``drive`` limits; ValueError (or codec.CodecError) says why it is bad.
    A twist is in the robot's ``<robot>/base_link`` (or an unprefixed ``base_link``)."""
    if topic == "cmd_vel":
        fast = _twist_stamped(payload)       # the generic decoder costs ~10x its work
        if fast is None:
            msg = codec.decode(payload, "geometry_msgs/msg/TwistStamped")
            tw = msg.twist
            stamp, frame_id = msg.header.stamp, msg.header.frame_id
            six = (tw.linear.x, tw.linear.y, tw.linear.z, tw.angular.x, tw.angular.y,
                   tw.angular.z)
        else:
            stamp, frame_id, six = fast
        if not all(math.isfinite(v) for v in six):
            raise ValueError("non-finite twist")
        base = frame(robot, "base_link") if robot else "base_link"
        if frame_id not in ("", "base_link", base):
            raise ValueError(f"twist in frame {frame_id!r}; expected {base}")
        value: Twist | WheelSpeeds = Twist(float(six[0]), float(six[5]))
        a, b = value.linear, value.angular
        lim_a, lim_b = drive.max_linear_mps, drive.max_angular_radps
    else:
        msg = codec.decode(payload, "sensor_msgs/msg/JointState")
        value = wheel_speeds(msg)
        a, b = value.left, value.right
        lim_a = lim_b = drive.max_wheel_speed_radps
        stamp = msg.header.stamp
    return _checked(value, a, b, lim_a, lim_b, stamp, drive, now_ns, tick_ns, check_age)


def twist_command(stamp_ns: int, linear: float, angular: float, drive, now_ns: int,
                  tick_ns: int, check_age: bool) -> tuple[Twist, int]:
    """What :func:`decode_command` gives, or raises, for the bytes
    ``codec.twist_stamped_bytes(stamp_ns, linear, angular)`` (a composed member's command,
    handed over with the values it was packed from), without parsing them back: the same
    checks on the same values (float64 on the wire, in ``base_link``)."""
    a, b = float(linear), float(angular)
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ValueError("non-finite twist")
    stamp = _Stamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)
    return _checked(Twist(a, b), a, b, drive.max_linear_mps, drive.max_angular_radps, stamp,
                    drive, now_ns, tick_ns, check_age)


class TwistCheck:
    """:func:`twist_command`'s checks for one robot, its limits multiplied out once:
    :meth:`ok` is True exactly where :func:`twist_command` would take the command (the same
    comparisons of the same values); one it refuses goes through :func:`twist_command`,
    for its error."""
    __slots__ = ("lim_a", "lim_b", "tick_ns", "timeout_ns")

    def __init__(self, drive, tick_ns: int, check_age: bool) -> None:
        self.lim_a = ABSURD_FACTOR * drive.max_linear_mps
        self.lim_b = ABSURD_FACTOR * drive.max_angular_radps
        self.tick_ns = tick_ns
        self.timeout_ns = drive.cmd_timeout_s * 1e9 if check_age else None

    def ok(self, stamp_ns: int, linear: float, angular: float, now_ns: int) -> bool:
        """Whether ``twist_command(stamp_ns, linear, angular, ...)`` at ``now_ns`` takes it:
        finite, not absurd, stamped now (0) or neither in the future nor past the timeout."""
        if not (math.isfinite(linear) and math.isfinite(angular)
                and abs(linear) <= self.lim_a and abs(angular) <= self.lim_b):
            return False
        if stamp_ns == 0:
            return True
        timeout = self.timeout_ns
        return (0 < stamp_ns <= now_ns + self.tick_ns
                and (timeout is None or now_ns - stamp_ns <= timeout))


def _checked(value, a: float, b: float, lim_a: float, lim_b: float, stamp, drive, now_ns: int,
             tick_ns: int, check_age: bool) -> tuple[Twist | WheelSpeeds, int]:
    check_stamp(stamp, now_ns, tick_ns, drive.cmd_timeout_s if check_age else None)
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"non-finite command ({a}, {b})")
    if abs(a) > ABSURD_FACTOR * lim_a or abs(b) > ABSURD_FACTOR * lim_b:
        raise ValueError(f"absurd command ({a:g}, {b:g}); limits are {lim_a:g}, {lim_b:g}")
    return value, codec.stamp_ns(stamp)


def check_stamp(stamp, now_ns: int, tick_ns: int, timeout_s: float | None) -> None:
    """Raise ValueError for a command stamped in the future, or (``timeout_s`` given) older
    than the robot's ``cmd_timeout_s``. A zero stamp means "now" (unstamped)."""
    if stamp.sec < 0 or not 0 <= stamp.nanosec < 1_000_000_000:
        raise ValueError(f"invalid stamp ({stamp.sec} s, {stamp.nanosec} ns)")
    t = codec.stamp_ns(stamp)
    if t == 0:
        return
    if t > now_ns + tick_ns:
        raise ValueError(f"stamped t={t * 1e-9:.3f} s, in the future (now "
                         f"{now_ns * 1e-9:.3f} s)")
    if timeout_s is not None and now_ns - t > timeout_s * 1e9:
        raise ValueError(f"stamped t={t * 1e-9:.3f} s, older than cmd_timeout "
                         f"{timeout_s:g} s (now {now_ns * 1e-9:.3f} s)")


class CommandBook:
    """The commands received per robot: the latest, and in lockstep one per tick stamp.
    Lockstep, once :meth:`bind` names the world's robots, a member's Twists for many robots
    at one tick are filed as arrays (:meth:`file_twists`, :mod:`plant.command_rows`) and
    the tick's commands picked for all of them at once (:meth:`pick_rows`); the rest, robot
    by robot, in the dicts :attr:`latest` and :attr:`by_tick` (reading either brings every
    robot's commands there)."""

    def __init__(self, lockstep: bool) -> None:
        self.lockstep = lockstep
        self._latest: dict[str, Command] = {}
        self._by_tick: dict[str, dict[int, Command]] = {}
        self.refused: dict[str, int] = {}      # robot -> stamp of its last rejected command
        self.rows: CommandRows | None = None

    @property
    def latest(self) -> dict[str, Command]:
        """robot -> the latest command filed for it."""
        self._out_all()
        return self._latest

    @property
    def by_tick(self) -> dict[str, dict[int, Command]]:
        """Lockstep: robot -> {tick stamp: its command}."""
        self._out_all()
        return self._by_tick

    def bind(self, names) -> CommandRows | None:
        """Lockstep: the world's robots ``names`` (in order), whose Twists may be filed
        whole from now on (:mod:`plant.command_rows`; a robot with commands in the dicts
        already stays there until its next)."""
        if not self.lockstep:
            return None
        names = tuple(names)
        if self.rows is None or self.rows.names != names:
            self._out_all()
            self.rows = CommandRows(names)
            for i, n in enumerate(names):
                if n in self._latest or self._by_tick.get(n):
                    self.rows.apart.add(i)
        return self.rows

    def _out(self, robot: str) -> None:
        """``robot``'s commands, if kept whole, into the dicts (until its next Twists come
        whole: :meth:`_in`)."""
        rows = self.rows
        i = rows.row.get(robot) if rows is not None else None
        if i is None or i in rows.apart:
            return
        kept, latest = rows.take_out(i)
        if kept:
            self._by_tick[robot] = {t: Command(Twist(a, b), t, w, m)
                                    for t, (a, b, w, m) in kept.items()}
        if latest is not None:
            t, a, b, w, m = latest
            self._latest[robot] = Command(Twist(a, b), t, w, m)

    def _in(self, robot: str, i: int) -> None:
        """``robot``'s commands (row ``i``) from the dicts back to the rows, if they are all
        Twists."""
        by_tick = self._by_tick.get(robot) or {}
        latest = self._latest.get(robot)
        cmds = list(by_tick.values()) + ([latest] if latest is not None else [])
        if any(type(c.value) is not Twist for c in cmds):
            return
        self.rows.take_in(i, {t: (c.value.linear, c.value.angular, c.wall, c.member)
                              for t, c in by_tick.items()},
                          None if latest is None else
                          (latest.t_ns, latest.value.linear, latest.value.angular,
                           latest.wall, latest.member))
        self._by_tick.pop(robot, None)
        self._latest.pop(robot, None)

    def _out_all(self) -> None:
        rows = self.rows
        if rows is not None and len(rows.apart) < len(rows.names):
            for i, name in enumerate(rows.names):
                self._out(name)

    def file(self, robot: str, cmd: Command) -> str | None:
        """Keep ``cmd``. Lockstep: one command per robot per tick, the same whatever the
        arrival order (docs/PROTOCOL.md section 7): a member's first for the tick (the
        ledger drops its later ones), and of two members' the one whose name sorts first;
        then what is wrong, for the protocol error count."""
        self._out(robot)
        self._latest[robot] = cmd
        if not self.lockstep:
            return None
        by_tick = self._by_tick.setdefault(robot, {})
        had = by_tick.get(cmd.t_ns)
        if had is None or had.member == cmd.member:
            if had is None:
                by_tick[cmd.t_ns] = cmd
            if len(by_tick) > RECENT_TICKS:
                del by_tick[min(by_tick)]
            return None
        keep = min(had, cmd, key=lambda c: c.member or "")
        by_tick[cmd.t_ns] = keep
        return (f"{had.member} and {cmd.member} for t={cmd.t_ns * 1e-9:.3f} s; "
                f"{keep.member}'s applied")

    def file_twists(self, robots: list[str], rows: tuple, rowset: frozenset, t_ns: int,
                    linear: list, angular: list, wall: float, member: str | None,
                    ix: np.ndarray | None = None) -> list[tuple[str, str]]:
        """Lockstep, bound: :meth:`file` of ``Command(Twist(linear[j], angular[j]), t_ns,
        wall, member)`` for each robot ``robots[j]`` (row ``rows[j]`` of :meth:`bind`'s
        names; ``rowset``, ``ix``: the same as a set, as an array), in order: whole where
        it can (:meth:`plant.command_rows.CommandRows.file`), else one by one; (robot, what
        is wrong) of each that :meth:`file` reports."""
        book = self.rows
        if book.apart and not book.apart.isdisjoint(rowset):   # (back whole, if they can)
            for robot, i in zip(robots, rows):
                if i in book.apart:
                    self._in(robot, i)
        if book.file(rows, rowset, t_ns, linear, angular, wall, member, ix):
            return []
        said = []
        for robot, a, b in zip(robots, linear, angular):
            problem = self.file(robot, Command(Twist(a, b), t_ns, wall, member))
            if problem:
                said.append((robot, problem))
        return said

    def pick_rows(self, upto_ns: int, value: np.ndarray) -> bool:
        """Lockstep, bound: where every robot kept whole has a command for exactly
        ``upto_ns`` (or none has any: ``upto_ns`` < 0), their :meth:`for_tick` at once into
        ``value`` ((R, 2) by row, zero for the rest), True; else False, nothing changed.
        The robots kept in the dicts (:attr:`plant.command_rows.CommandRows.apart`) are
        asked :meth:`for_tick` one by one."""
        return self.rows.pick(upto_ns, value)

    def for_tick(self, robot: str, upto_ns: int) -> Command | None:
        """Lockstep: the command computed for the latest tick at or before ``upto_ns`` (the
        current tick in sequential coupling, the one before in pipelined): what arrives early
        for a later tick waits for its turn, so runs are the same whatever the timing."""
        self._out(robot)
        by_tick = self._by_tick.get(robot)
        if not by_tick:
            return None
        cmd = by_tick.get(upto_ns)
        if cmd is not None:                # (the usual case: that very tick's command)
            if len(by_tick) > 1:
                for t in [t for t in by_tick if t < upto_ns]:
                    del by_tick[t]
            return cmd
        ticks = [t for t in by_tick if t <= upto_ns]
        if not ticks:
            return None
        best = max(ticks)
        for t in [t for t in ticks if t < best]:          # older ones are done with
            del by_tick[t]
        return by_tick[best]

    def refuse(self, robot: str, t_ns: int) -> None:
        """A command for ``robot`` stamped ``t_ns`` was rejected (bad values): the robot has
        none for that tick, which :func:`stale_commands` must not count."""
        self.refused[robot] = t_ns

    def forget(self, robot: str, upto_ns: int) -> None:
        """The robot's command stamped ``upto_ns`` timed out: it and every older one are
        dropped, so the robot has none until a newer one acts. A command already filed for a
        later tick (pipelined: the next answer, often in before this tick is applied) stays:
        what acts never depends on when it arrived (docs/PROTOCOL.md section 4)."""
        self._out(robot)
        cmd = self._latest.get(robot)
        if cmd is not None and cmd.t_ns <= upto_ns:
            del self._latest[robot]
        by_tick = self._by_tick.get(robot)
        if by_tick:
            for t in [t for t in by_tick if t <= upto_ns]:
                del by_tick[t]

    def clear(self) -> None:
        self._latest.clear()
        self._by_tick.clear()
        self.refused.clear()
        if self.rows is not None:
            self.rows.clear()


#: the protocol error kind of a robot driven by a command other than the coupling's rule's
STALE = "stale command"


def stale_commands(ledger: AckLedger, book: CommandBook, t_ns: int,
                   picked: dict[str, Command | None],
                   keys: Callable[[str], tuple[str, ...] | None],
                   report: Callable[[str, str], None]) -> int:
    """Lockstep, once per tick, before the plant steps with ``picked`` (robot -> the command
    that acts, or None): how many robots are driven by anything but the command stamped
    ``t_ns`` (the tick whose commands act: t_k sequential, t_(k-1) pipelined) or the
    documented fallback (docs/PROTOCOL.md section 4, "Couplings";
    :meth:`bus.lockstep.AckLedger.stale_command`); each is reported as ``STALE``, a
    protocol error, never silent. ``keys(robot)``: its command keys."""
    n = 0
    owing = None                          # who still owes t_ns: asked once, if at all
    for robot, cmd in picked.items():
        cmd_t = None if cmd is None else cmd.t_ns
        if cmd_t == t_ns or t_ns < 0:
            continue
        if owing is None:
            owing = ledger.waiting_for(t_ns)
        why = ledger.stale_command(t_ns, keys(robot) or (), cmd_t,
                                   book.refused.get(robot) == t_ns, owing)
        if why:
            report(STALE, f"{robot}: {why}")
            n += 1
    return n
