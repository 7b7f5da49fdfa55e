"""A lockstep member whose robots are all driven by one ``step_many`` controller (the
swarm's avoid members): its answer to a tick made in one pass, :class:`ManyTick`.

:meth:`bus.member.MemberTick.act` steps such a controller once and then, robot by robot,
queues each command as an output, orders the outputs (:meth:`~bus.member.MemberTick.owed`)
and packs them. When every robot gets a :class:`Twist` and the controller is not done, that
answer is always the same shape: one ``cmd_vel`` per robot in the robots' order, the last
carrying the ACK and the count. :meth:`ManyTick.act` makes it so directly, the same bytes,
flags and member state as ``act`` (tests/bus/test_many_tick.py compares them tick by tick);
any other answer (a robot left without a command, another kind of output, the controller
done) goes the general way. The values its commands were packed from stay beside them
(:meth:`ManyTick.twists_of`): a plant hosting the member takes them whole
(:meth:`plant.intake.Intake.answer`). The commands may come as arrays (``step_many``'s
``(linear, angular)``), and a member composed into the plant may take its scans as one
array and step ``step_scans`` (:class:`bus.rows.ScanRows`): no Twist nor LaserScan object
per robot on either side.
"""
from __future__ import annotations

import struct
from itertools import repeat

from . import codec
from . import controller as hooks
from .controller import Twist
from .member import MemberTick, Sent
from .observe import observations
from .rows import ScanRows, arrays_of


_PACKS: dict[int, struct.Struct] = {}     # a member's attachment by its name's length


def answer_attachments(seq: int, t_ns: int, n: int,
                       node: str | None) -> list[tuple[bytes, codec.Attachment | None]]:
    """``codec.attachments_parsed(seq, t_ns, marks, node)`` of :meth:`ManyTick.act`'s
    answer of ``n`` messages (``marks``: no flags, the last ACK with ``n``): each attachment
    packed in one call, header, trailer and name together."""
    name = node.encode("utf-8") if node is not None else b""
    if node is None or not 0 < len(name) <= codec.NAME_MAX or n < 1:
        return codec.attachments_parsed(seq, t_ns, [(0, 0)] * (n - 1) + [(codec.ACK, n)],
                                        node)
    pack = _PACKS.get(len(name))
    if pack is None:
        pack = _PACKS[len(name)] = struct.Struct(f"<QQBHB{len(name)}s")
    pack, k, mask = pack.pack, len(name), 0xFFFFFFFFFFFFFFFF
    make, kind = tuple.__new__, codec.Attachment      # (as attachments_parsed makes them)
    out = [(pack(s, t_ns, 0, 0, k, name), make(kind, (s, t_ns, 0, 0, node, None)))
           for s in ((seq + i) & mask for i in range(1, n))]
    s = (seq + n) & mask
    out.append((pack(s, t_ns, codec.ACK, n, k, name),
                make(kind, (s, t_ns, codec.ACK, n, node, None))))
    return out


class OnePass:
    """A member's answer of one Twist per robot made in one pass: what :class:`ManyTick`
    and :class:`bus.one.OneTick` share (each packs its commands its own way: a list of
    robots, or one). ``member``'s robots' ``cmd_vel`` keys and the Twist's CDR layout are
    taken once."""

    #: its scans as one array (:class:`bus.rows.ScanRows`), where it takes them so
    #: (:meth:`take_rows`); else None: they come message by message
    rows: ScanRows | None = None

    def __init__(self, member: MemberTick) -> None:
        self.member = member
        self.keys = [s.cmd_key for s in member.slots]
        self.layout, self.frame = codec._twist_layout("base_link")   # (twist_stamped_bytes')
        #: the last answer made in one pass, and its commands as (cmd_vel keys, stamp,
        #: linear values, angular values): what :meth:`twists_of` hands the plant
        self.last: tuple | None = None

    def take_rows(self) -> bool:
        """Whether the member takes its scans as one array from now on (only a
        :class:`ManyTick`'s may)."""
        return False

    def twists_of(self, sent: Sent) -> tuple | None:
        """(keys, stamp, linear, angular) of ``sent`` if it is the answer :meth:`answered`
        took last (its cmd_vel messages in the keys' order, the values they were packed
        from), else None."""
        last = self.last
        return last[1] if last is not None and last[0] is sent else None

    def answered(self, t_ns: int, sent: Sent, linear: list,
                 angular: list) -> tuple[Sent, bool]:
        """``member.act(t_ns)``'s answer ``sent``, the cmd_vel messages packed from one
        Twist per robot (``linear``, ``angular``: their values in the robots' order; the
        member's ``twists`` hold them): act's bookkeeping of a tick sent, the controller not
        done."""
        m = self.member
        m.ticks += 1
        m.hold_until = t_ns if m._keep_sent else None
        m._keep(t_ns, sent)
        # (the plant takes the values whole: plant.intake.Intake.answer's ``twists``)
        self.last = (sent, (self.keys, t_ns, linear, angular))
        return sent, False


class ManyTick(OnePass):
    """:meth:`MemberTick.act` for ``member``, whose robots share one ``step_many``
    controller (:meth:`of`: None for any other member)."""

    def __init__(self, member: MemberTick) -> None:
        super().__init__(member)
        self.ctrl = member.slots[0].controller
        self.robots = [s.robot for s in member.slots]

    def take_rows(self) -> bool:
        """Take the scans as one array from now on where the member may (configured: its
        controller has ``step_scans``, its only input is ``scan``): whether it does."""
        self.rows = ScanRows.of(self.member)
        return self.rows is not None

    @classmethod
    def of(cls, member: MemberTick) -> "ManyTick | None":
        slots = member.slots
        if not slots or not hooks.steps_many(slots[0].controller) \
                or any(s.controller is not slots[0].controller for s in slots):
            return None
        return cls(member)

    def act(self, t_ns: int) -> tuple[Sent, bool] | None:
        """``member.act(t_ns)``'s (what to send, finished), or None without stepping
        anything where the member is not in lockstep, has outputs queued already or a robot
        done (the caller then calls ``act``)."""
        m = self.member
        slots = m.slots
        if not m.sync or any(s.done for s in slots) or (m._out and self.rows is None):
            return None
        ctrl = self.ctrl
        if self.rows is not None:        # (its scans as one array, its commands as arrays)
            linear, angular = self.rows.step(t_ns)
        else:
            answer = ctrl.step_many(observations(m, slots, t_ns))
            if isinstance(answer, dict):
                cmds = list(map(answer.get, self.robots))
                if all(type(c) is Twist for c in cmds):
                    linear = [float(c.linear) for c in cmds]
                    angular = [float(c.angular) for c in cmds]
                else:
                    linear = None
            else:
                linear, angular = arrays_of(ctrl, answer, len(slots), "step_many")
        done = hooks.is_done(ctrl)
        if linear is None or done or m._out:
            if linear is not None:
                cmds = list(map(Twist, linear, angular))
            return self._general(cmds, done, t_ns)
        # act's queue, owed and send_tick for one Twist per robot: cmd_vel keys distinct,
        # all read by the plant (owed's order is theirs), the last with ACK and n_plant
        sec, nanosec = divmod(t_ns, 1_000_000_000)
        pack, cdr, frame = self.layout.pack, codec._CDR_LE, self.frame
        keys = self.keys
        datas = [pack(cdr, sec, nanosec, frame, a, 0.0, 0.0, 0.0, 0.0, b)
                 for a, b in zip(linear, angular)]
        m.twists.update(zip(keys, zip(datas, repeat(t_ns), linear, angular)))
        sent: Sent = list(zip(keys, datas, repeat(0), repeat(0)))
        sent[-1] = (keys[-1], datas[-1], codec.ACK, len(sent))
        return self.answered(t_ns, sent, linear, angular)

    def _general(self, cmds: list, done: bool, t_ns: int) -> tuple[Sent, bool]:
        """The rest of :meth:`MemberTick.act` for the commands ``step_many`` gave."""
        m = self.member
        for slot, out in zip(m.slots, cmds):
            m._queue_answer(slot, out, done, t_ns)
        finished = all(slot.done for slot in m.slots)
        return m.send_tick(t_ns, final=finished), finished
