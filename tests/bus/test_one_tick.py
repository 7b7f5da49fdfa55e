"""A member of one robot whose controller answers a Twist answers a tick in one pass
(bus/one.py): the same messages, bytes, flags and member state as MemberTick.act, tick by
tick, whatever the controller answers (a Twist, a dict of outputs, wheel speeds, nothing,
done), and a composed host hands the plant the same messages either way."""
from __future__ import annotations

from bus import codec
from bus.controller import Twist, WheelSpeeds
from bus.keys import TOPICS, Keys
from bus.member import MemberTick, make_slots
from bus.one import OneTick

K = Keys()
T = 20_000_000


class _Script:
    """A Twist that changes every tick; tick 2 a dict of a command and a debug vector, tick
    4 wheel speeds, tick 5 nothing, tick 6 a Twist of ints; done at tick 8 (its stop
    command then)."""
    inputs: list[str] = []

    def __init__(self) -> None:
        self.k = 0
        self.done = False

    def step(self, obs):
        k, self.k = self.k, self.k + 1
        self.done = k == 8
        if k == 2:
            return {"cmd": Twist(0.3, -0.2), "follower/debug": codec.T[
                "std_msgs/msg/Float64MultiArray"](layout=codec.T["std_msgs/msg/MultiArrayLayout"](
                    dim=[], data_offset=0), data=[1.0, 2.0])}
        if k == 4:
            return WheelSpeeds(1.0, 2.0)
        if k == 5:
            return None
        if k == 6:
            return Twist(1, -2)
        return Twist(0.01 * k + 0.1, -0.3 + 0.07 * k)


def _member(mode: str = "lockstep", robots=("r",), ctrl=_Script) -> MemberTick:
    topics = dict(TOPICS)
    m = MemberTick("m", T, slots=make_slots(ctrl, list(robots), topics), topics=topics,
                   key=K.topic, ack_key=K.ack("m"))
    m.configure({"mode": mode, "control_tick_s": 0.02,
                 "robots": {r: {"topics": {}} for r in robots}})
    return m


def _state(m: MemberTick) -> tuple:
    return (m.ticks, m.final_tick, m.hold_until, dict(m.twists), dict(m.sent),
            [s.done for s in m.slots], m._out)


def test_one_pass_answers_as_act_does_tick_by_tick():
    by_act, in_one = _member(), _member()
    one = OneTick.of(in_one)
    fast = []
    for k in range(9):
        want = by_act.act(k * T)
        got = one.act(k * T)
        assert got == want, k
        assert _state(in_one) == _state(by_act), k
        if one.twists_of(got[0]) is not None:
            fast.append(k)
            (key, data, _, _), = got[0]
            assert one.twists_of(got[0]) == ([key], k * T, [by_act.twists[key][2]],
                                             [by_act.twists[key][3]])
    assert want[1] and fast == [0, 1, 3, 6, 7]     # finished at tick 8; the Twists in one pass
    assert one.act(9 * T) is None                  # its robot done: act's (the stop command)


def test_only_lockstep_members_of_one_robot_stepped_alone_answer_in_one_pass():
    m = _member("realtime")
    assert OneTick.of(m).act(0) is None and m.ticks == 0       # not stepped
    assert OneTick.of(_member(robots=("a", "b"))) is None       # two robots

    class _Many:
        inputs: list[str] = []

        def step_many(self, observations):
            return {r: Twist() for r in observations}
    assert OneTick.of(_member(ctrl=_Many)) is None


def test_a_composed_host_emits_the_same_messages_with_or_without_the_one_pass():
    """bus.composed's _send of each answer: the same keys, bytes, attachments (as bytes and
    parsed) and command values, the values also whole where the answer came in one pass."""
    from bus.composed import Composed
    from bus.node import MemberSpec
    emitted = {}
    for way in ("act", "one"):
        comp = Composed([MemberSpec(_Script(), ["r"], "m")], K, None)
        h = comp.hosted[0]
        assert isinstance(h.many, OneTick)
        if way == "act":
            h.many = None
        h.member.configure({"mode": "lockstep", "control_tick_s": 0.02,
                            "robots": {"r": {"topics": {}}}})
        got = emitted[way] = []
        for k in range(9):
            comp.clock(k * T, lambda msgs, twists: got.append((msgs, twists)))
            comp.run(lambda msgs, twists: got.append((msgs, twists)))
    assert [m for m, _ in emitted["one"]] == [m for m, _ in emitted["act"]]
    assert all(tw is None for _, tw in emitted["act"])
    wholes = [(k, tw) for k, (msgs, tw) in enumerate(emitted["one"]) if tw is not None]
    assert [k for k, _ in wholes] == [0, 1, 3, 6, 7]
    for k, (keys, t_ns, linear, angular) in wholes:
        (key, _, _, _, values), = emitted["one"][k][0]
        assert keys == [key] and (t_ns, linear[0], angular[0]) == values
