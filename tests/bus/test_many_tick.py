"""A member of many robots on one step_many controller answers a tick in one pass
(bus/many.py): the same messages, bytes, flags and member state as MemberTick.act, tick by
tick, whatever the controller answers (a Twist per robot, a robot left out, other outputs,
done)."""
from __future__ import annotations

from bus.controller import Twist, WheelSpeeds
from bus.keys import TOPICS, Keys
from bus.many import ManyTick
from bus.member import MemberTick, make_slots

K = Keys()
ROBOTS = ["a", "b", "c", "d"]
T = 20_000_000


class _Script:
    """Twists that change every tick; tick 3 leaves "c" out, tick 5 gives "b" wheel speeds,
    tick 6 a dict of outputs; done at tick 9 (its stop command then)."""
    inputs: list[str] = []

    def __init__(self) -> None:
        self.k = 0
        self.done = False

    def step_many(self, observations):
        k, self.k = self.k, self.k + 1
        self.done = k == 9
        out = {r: Twist(0.01 * k + 0.1 * i, -0.3 + 0.07 * i * k)
               for i, r in enumerate(observations)}
        if k == 3:
            del out["c"]
        if k == 5:
            out["b"] = WheelSpeeds(1.0, 2.0)
        if k == 6:
            out["d"] = {"cmd_vel": Twist(0.2, 0.1), "odom": None}
        return out


def _member(mode: str = "lockstep") -> MemberTick:
    topics = dict(TOPICS)
    m = MemberTick("m", T, slots=make_slots(_Script(), ROBOTS, topics), topics=topics,
                   key=K.topic, ack_key=K.ack("m"))
    m.configure({"mode": mode, "control_tick_s": 0.02,
                 "robots": {r: {"topics": {}} for r in ROBOTS}})
    return m


def _state(m: MemberTick) -> tuple:
    return (m.ticks, m.final_tick, m.hold_until, dict(m.twists), dict(m.sent),
            [s.done for s in m.slots], m._out)


def test_one_pass_answers_as_act_does_tick_by_tick():
    by_act, in_one = _member(), _member()
    many = ManyTick.of(in_one)
    fast = 0
    for k in range(10):
        want = by_act.act(k * T)
        got = many.act(k * T)
        if got is None:                    # (a robot done: the general way, as act)
            got = in_one.act(k * T)
        else:
            fast += k not in (3, 5, 6, 9)
        assert got == want, k
        assert _state(in_one) == _state(by_act), k
    assert want[1] and fast == 6           # finished at tick 9; the six plain ticks in one pass
    assert many.act(10 * T) is None        # every robot done: act's (the stop commands)


def test_only_lockstep_members_of_one_step_many_controller_answer_in_one_pass():
    m = _member("realtime")
    assert ManyTick.of(m).act(0) is None and m.ticks == 0     # not stepped
    topics = dict(TOPICS)
    apart = MemberTick("m", T, slots=make_slots(_Script, ROBOTS, topics), topics=topics,
                       key=K.topic, ack_key=K.ack("m"))
    assert ManyTick.of(apart) is not None   # a factory of a step_many controller: one object

    class _One:
        inputs: list[str] = []

        def step(self, obs):
            return Twist()
    assert ManyTick.of(MemberTick("o", T, slots=make_slots(_One, ROBOTS, topics),
                                  topics=topics, key=K.topic)) is None


def test_an_answer_s_attachments_packed_at_once_are_those_made_one_by_one():
    """Also no name, one too long, a name not ASCII, one message, the sequence wrapping."""
    from bus import codec
    from bus.keys import NAME_MAX
    from bus.many import answer_attachments
    for node in ("avoid_g0", None, "é" * 3, "x" * (NAME_MAX + 1), "x" * NAME_MAX):
        for seq, n in ((41, 8), (0, 1), (2**64 - 3, 5)):
            marks = [(0, 0)] * (n - 1) + [(codec.ACK, n)]
            assert answer_attachments(seq, 20 * T, n, node) == \
                codec.attachments_parsed(seq, 20 * T, marks, node), (node, seq, n)
