"""A lockstep member of one robot whose controller steps it alone (``step``): its answer to
a tick made in one pass when the controller answers a Twist, :class:`OneTick`.

:meth:`bus.member.MemberTick.act` queues the controller's answer as an output, orders the
tick's outputs (:meth:`~bus.member.MemberTick.owed`) and packs them, the same way for every
member. When a one-robot member's controller answers a :class:`Twist` and is not done, that
answer always has one shape: the robot's ``cmd_vel``, with the ACK and a count of one.
:meth:`OneTick.act` makes it so directly, as :class:`bus.many.ManyTick` does for one
``step_many`` controller of many robots: the same bytes, flags and member state as ``act``
(tests/bus/test_one_tick.py compares them tick by tick), and the command's values beside
its bytes for the plant hosting the member (:meth:`OneTick.twists_of`). Any other answer (a
dict of outputs, wheel speeds, nothing, the controller done) goes the general way, the
controller stepped once all the same.
"""
from __future__ import annotations

from . import codec
from . import controller as hooks
from .controller import Twist
from .many import OnePass
from .member import MemberTick, Sent


class OneTick(OnePass):
    """:meth:`MemberTick.act` for ``member``, which drives one robot with a controller's
    ``step`` (:meth:`of`: None for any other member)."""

    def __init__(self, member: MemberTick) -> None:
        super().__init__(member)
        self.slot = member.slots[0]

    @classmethod
    def of(cls, member: MemberTick) -> "OneTick | None":
        slots = member.slots
        if len(slots) != 1 or hooks.steps_many(slots[0].controller):
            return None
        return cls(member)

    def act(self, t_ns: int) -> tuple[Sent, bool] | None:
        """``member.act(t_ns)``'s (what to send, finished), or None without stepping
        anything where the member is not in lockstep, has outputs queued already or its
        robot done (the caller then calls ``act``)."""
        m, slot = self.member, self.slot
        if not m.sync or m._out or slot.done:
            return None
        ctrl = slot.controller
        out = ctrl.step(m.take_observation(slot, t_ns))
        done = hooks.is_done(ctrl)
        if done or type(out) is not Twist:       # (act's rest, for this answer)
            m._queue_answer(slot, out, done, t_ns)
            return m.send_tick(t_ns, final=slot.done), slot.done
        # act's queue, owed and send_tick for one Twist: one cmd_vel, read by the plant,
        # with ACK and n_plant 1
        linear, angular = float(out.linear), float(out.angular)
        sec, nanosec = divmod(t_ns, 1_000_000_000)
        data = self.layout.pack(codec._CDR_LE, sec, nanosec, self.frame, linear, 0.0, 0.0,
                                0.0, 0.0, angular)
        key = self.keys[0]
        m.twists[key] = (data, t_ns, linear, angular)
        return self.answered(t_ns, [(key, data, codec.ACK, 1)], [linear], [angular])
