"""A controller for many robots (``step_many``): one object for all the robots of a member,
called once a tick with every robot it still drives; its hooks run once; a controller
without it keeps being stepped robot by robot."""
from __future__ import annotations

import pytest

from bus import codec
from bus.controller import Twist, make_controllers
from bus.keys import TOPICS, Keys
from bus.member import MemberTick, make_slots, with_own_stats

K = Keys()
ROBOTS = ["a", "b", "c"]


class _Many:
    inputs: list[str] = []

    def __init__(self) -> None:
        self.calls: list[list[str]] = []
        self.done = False

    def step(self, obs):
        raise AssertionError("a controller with step_many is not stepped robot by robot")

    def step_many(self, observations):
        self.calls.append(list(observations))
        if len(self.calls) == 3:
            self.done = True
        # robot "c" gets nothing on the first tick
        return {r: Twist(0.1 * (i + 1), 0.0) for i, r in enumerate(observations)
                if not (r == "c" and len(self.calls) == 1)}

    def stats(self):
        return {"rejected": {"odd": 1}}


class _One:
    inputs: list[str] = []

    def __init__(self) -> None:
        self.steps = 0

    def step(self, obs):
        self.steps += 1
        return Twist(0.2, 0.0)


def _member(controller) -> MemberTick:
    topics = dict(TOPICS)
    m = MemberTick("m", 20_000_000, slots=make_slots(controller, ROBOTS, topics),
                   topics=topics, key=K.topic, ack_key=K.ack("m"))
    m.configure({"control_tick_s": 0.02, "robots": {r: {"topics": {}} for r in ROBOTS}})
    return m


def _commands(sent) -> dict[str, float]:
    return {key: codec.decode(p, TOPICS["cmd_vel"].msgtype).twist.linear.x
            for key, p, _, _ in sent if key.endswith("/cmd_vel")}


@pytest.mark.parametrize("given", ["object", "factory"])
def test_one_object_steps_every_robot_once_a_tick(given):
    m = _member(_Many() if given == "object" else _Many)
    ctrl = m.slots[0].controller
    assert all(s.controller is ctrl for s in m.slots)        # never copied per robot
    sent, finished = m.act(0)
    assert ctrl.calls == [ROBOTS] and not finished
    assert _commands(sent) == {K.topic("a", "cmd_vel"): 0.1, K.topic("b", "cmd_vel"): 0.2}
    assert sent[-1][3] == 2                                  # n_plant: the commands it sent
    sent, _ = m.act(20_000_000)
    assert _commands(sent)[K.topic("c", "cmd_vel")] == pytest.approx(0.3)
    sent, finished = m.act(40_000_000)                       # done: every robot stops
    assert finished and all(v == 0.0 for v in _commands(sent).values())
    assert len(_commands(sent)) == 3 and len(ctrl.calls) == 3
    # its own stats count once, not once per robot
    assert with_own_stats({"rejected": {}}, [s.controller for s in m.slots])["rejected"] \
        == {"odd": 1}


def test_a_controller_without_it_is_stepped_per_robot():
    m = _member(_One)
    assert len({id(s.controller) for s in m.slots}) == 3
    sent, _ = m.act(0)
    assert [s.controller.steps for s in m.slots] == [1, 1, 1]
    assert len(_commands(sent)) == 3
    one, two = make_controllers(_Many, ["x", "y"])
    assert one is two


def test_step_many_must_answer_a_dict():
    class Bad(_Many):
        def step_many(self, observations):
            return [Twist()]
    with pytest.raises(TypeError, match="step_many"):
        _member(Bad).act(0)


def test_the_manual_s_controller_for_many_robots_runs_as_a_member():
    """docs/controllers.md, "A controller for many robots": its example, run by a member over
    three robots' scans, gives each robot its speed from one step_many call."""
    import re
    from ..conftest import ROOT
    text = open(f"{ROOT}/docs/controllers.md").read()
    section = text.split("## A controller for many robots", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    space: dict = {}
    exec(compile(code, "docs/controllers.md", "exec"), space)
    topics = dict(TOPICS)
    m = MemberTick("m", 20_000_000, slots=make_slots(space["Cruise"](), ROBOTS, topics),
                   topics=topics, key=K.topic, ack_key=K.ack("m"))
    m.configure({"control_tick_s": 0.02,
                 "robots": {r: {"topics": {"scan": 1}} for r in ROBOTS}})
    for near, r in zip([0.4, 1.0, float("inf")], ROBOTS):
        scan = codec.laser_scan(0, -1.0, 1.0, 1.0, 0.1, 0.1, 5.0, [2.0, near, 3.0])
        m.receive(K.topic(r, "scan"), codec.encode(scan), None)
    assert m.clock(0) == (None, None) and m.next_due() == 0
    sent, _ = m.act(0)
    assert _commands(sent) == pytest.approx(
        {K.topic("a", "cmd_vel"): 0.0, K.topic("b", "cmd_vel"): 0.15,
         K.topic("c", "cmd_vel"): 0.3})


def test_observations_in_one_pass_equal_each_robot_s_own():
    """A step_many controller's observations, taken for all its robots in one pass, show,
    keep and mark used what taking them robot by robot does (two inputs a robot, buffers of
    one to three samples, good, held, stale or newer than the tick; the used stamps pruned)."""
    import random
    from bus.member import _HELD
    from bus.observe import observations

    class Two(_Many):
        inputs = ["scan", "odom"]

    rng = random.Random(5)
    T = 20_000_000
    stamps = [0, T, 2 * T, 5 * T, 40 * T]
    for trial in range(40):
        one, each = _member(Two), _member(Two)
        t = rng.choice(stamps[1:])
        bufs = {}
        for r in ROBOTS:
            for topic in Two.inputs:
                picked = rng.sample(stamps, rng.randint(0, 3))
                bufs[K.topic(r, topic)] = {s: _HELD if rng.random() < 0.3 else f"{r}{topic}{s}"
                                           for s in picked}
        old = {(K.topic("a", "scan"), -k) for k in range(200 if trial % 2 else 3)}
        for m in (one, each):
            m.buf = {k: dict(v) for k, v in bufs.items()}
            m.used = set(old)
        got = observations(one, one.slots, t)
        want = {s.robot: each.take_observation(s, t) for s in each.slots}
        assert list(got) == ROBOTS
        assert {r: o.msgs for r, o in got.items()} == {r: o.msgs for r, o in want.items()}
        assert (one.buf, one.used) == (each.buf, each.used), trial
