"""A many-robot member handed its scans as one array a tick (bus/rows.py) answers as the same
member handed one LaserScan per robot: the same bytes, flags and lockstep bookkeeping tick
by tick, the stale rule included; and a step_many answering (linear, angular) arrays sends
what its Twists would."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bus import codec
from bus.controller import Twist
from bus.keys import TOPICS, Keys
from bus.many import ManyTick
from bus.member import MemberTick, make_slots
from bus.rows import ROW
from controllers.avoid import Avoid

K = Keys()
ROBOTS = ["a", "b", "c", "d", "e"]
T = 20_000_000
PERIOD = 5                      # a 10 Hz lidar at 20 ms ticks
N = 180


def _member(ctrl) -> MemberTick:
    topics = dict(TOPICS)
    m = MemberTick("m", T, slots=make_slots(ctrl, ROBOTS, topics), topics=topics,
                   key=K.topic, ack_key=K.ack("m"))
    m.configure({"mode": "lockstep", "coupling": "pipelined", "control_tick_s": 0.02,
                 "node_input_delay_ticks": 1,
                 "robots": {r: {"topics": {"scan": PERIOD}} for r in ROBOTS}})
    return m


def _scans(rng, ticks: int):
    """(robots, rays) float32 scans through the stop and slow distances, with dropouts."""
    near = rng.uniform(0.4, 2.0, size=(len(ROBOTS), 1))
    shape = rng.uniform(0.0, 1.5, size=(len(ROBOTS), N))
    for _ in range(ticks):
        near = np.clip(near + rng.normal(0.0, 0.15, size=near.shape), 0.3, 2.5)
        r = near + shape + rng.normal(0.0, 0.01, size=shape.shape)
        r[rng.random(shape.shape) < 0.02] = np.inf
        r[rng.random(shape.shape) < 0.01] = 0.01
        yield r.astype(np.float32)


def _wire(t_ns: int, ranges) -> object:
    """A LaserScan as a process member decodes it from the plant's bytes."""
    msg = codec.laser_scan(t_ns, -math.pi / 2, math.pi / 2, math.pi / (N - 1), 0.1, 0.12,
                           5.0, ranges)
    return codec.decode(codec.encode(msg), "sensor_msgs/msg/LaserScan")


def _state(m: MemberTick) -> tuple:
    return (m.ticks, m.hold_until, dict(m.twists), dict(m.sent), sorted(m.pending),
            m._last_acted)


def _cruise():
    """docs/controllers.md's controller for many robots."""
    import re
    from ..conftest import ROOT
    text = open(f"{ROOT}/docs/controllers.md").read()
    section = text.split("## A controller for many robots", 1)[1]
    space: dict = {}
    exec(compile(re.search(r"```python\n(.*?)```", section, re.S).group(1),
                 "docs/controllers.md", "exec"), space)
    return space["Cruise"]


@pytest.mark.parametrize("make", [Avoid, _cruise()], ids=["avoid", "manual"])
def test_scans_as_one_array_answer_as_one_message_per_robot_tick_by_tick(make):
    """120 ticks; the scans stop coming at tick 60 (the member acting anyway, as a member
    not waiting would): the commands follow the last scan until it is stale, then stop;
    the plant's rows in another order than the member's robots."""
    rng = np.random.default_rng(5)
    each, rows = _member(make()), _member(make())
    one, many = ManyTick.of(each), ManyTick.of(rows)
    assert many.take_rows() and not hasattr(one.ctrl, "nothing")
    plant_rows = np.array([4, 0, 3, 1, 2, 9])        # plant robot rows of the array
    index = {r: i for i, r in enumerate(ROBOTS)}
    gen = _scans(rng, 200)
    moving = stopped = 0
    for k in range(120):
        t = k * T
        if k % PERIOD == 0 and k < 60:
            scans = next(gen)
            head = None
            for i, r in enumerate(ROBOTS):
                msg = _wire(t, scans[i])
                head = (msg.angle_min, msg.angle_max, msg.angle_increment,
                        msg.time_increment, msg.scan_time, msg.range_min, msg.range_max)
                topic, problem, _ = each.receive(K.topic(r, "scan"), b"", None, msg)
                assert problem is None
            plant = np.zeros((len(plant_rows), N), np.float32)
            plant[[list(plant_rows).index(i) for i in range(len(ROBOTS))]] = scans
            assert many.rows.file(t, plant_rows.copy(), plant, head, index)   # (a new array)
        if k < 60:                         # the bookkeeping sees the rows' scans
            for m in (each, rows):
                assert m.clock(t, 1.0) == (None, None)
            assert each.next_due() == t and rows.next_due() == t, k
        want = one.act(t)
        got = many.act(t)
        assert got == want, k
        assert _state(rows) == _state(each), k
        speeds = [tw[2] for tw in rows.twists.values()]
        moving += k < 60 and any(speeds)
        stopped += k >= 60 and not any(speeds) and not any(tw[3] for tw in rows.twists.values())
    assert moving > 30
    if make is Avoid:           # (turning or moving) stale 0.5 s after the last scan (55)
        assert stopped == 120 - 81


def test_a_due_scan_not_filed_holds_the_tick():
    m = _member(Avoid())
    many = ManyTick.of(m)
    assert many.take_rows()
    m.clock(0, 1.0)
    assert m.next_due() is None                    # tick 0's scans are due
    scans = np.ones((len(ROBOTS), N), np.float32)
    assert not many.rows.file(0, np.arange(3), scans[:3], (0.0,) * 7,
                              {r: i for i, r in enumerate(ROBOTS)})     # not all its robots
    assert m.next_due() is None
    assert many.rows.file(0, np.arange(5), scans, (0.0,) * 7,
                          {r: i for i, r in enumerate(ROBOTS)})
    assert m.buf[K.topic("c", "scan")] == {0: ROW}
    assert m.next_due() == 0


def test_only_a_scan_only_controller_with_step_scans_takes_rows():
    class _Many:
        inputs = ["scan"]

        def step_many(self, observations):
            return {}
    assert not ManyTick.of(_member(_Many())).take_rows()

    class _Odom(Avoid):
        inputs = ["scan", "odom"]
    topics = dict(TOPICS)
    m = MemberTick("m", T, slots=make_slots(_Odom(), ROBOTS, topics), topics=topics,
                   key=K.topic, ack_key=K.ack("m"))
    m.configure({"mode": "lockstep", "control_tick_s": 0.02,
                 "robots": {r: {"topics": {"scan": PERIOD}} for r in ROBOTS}})
    assert not ManyTick.of(m).take_rows()


class _Arrays:
    """Commands as arrays, or as Twists (``twists``): the same numbers."""
    inputs: list[str] = []

    def __init__(self, twists: bool, bad=None) -> None:
        self.twists, self.bad, self.k = twists, bad, 0

    def step_many(self, observations):
        self.k += 1
        v = np.linspace(-0.2, 0.3, len(observations)) * self.k / 3.0
        w = np.float32(0.1) * np.arange(len(observations)) - self.k / 7.0
        if self.bad is not None:
            return self.bad
        if self.twists:
            return dict(zip(observations, map(Twist, v.tolist(), w.tolist())))
        return v, w


def test_step_many_answering_arrays_sends_what_its_twists_send():
    twists, arrays = _member(_Arrays(True)), _member(_Arrays(False))
    by_act = _member(_Arrays(False))
    a, b = ManyTick.of(twists), ManyTick.of(arrays)
    for k in range(4):
        want = a.act(k * T)
        assert b.act(k * T) == want and by_act.act(k * T) == want, k
        assert b.twists_of(want[0]) is None and arrays.twists == twists.twists


@pytest.mark.parametrize("bad", [(np.zeros(4), np.zeros(5)), [np.zeros(5), np.zeros(5)],
                                 (np.zeros(5), "fast")])
def test_a_step_many_answer_of_the_wrong_shape_says_so(bad):
    for act in (lambda m: ManyTick.of(m).act(0), lambda m: m.act(0)):
        with pytest.raises(TypeError, match="step_many"):
            act(_member(_Arrays(False, bad)))


class _Session:
    """What Composed.start asks of a Zenoh session: liveliness tokens."""

    def liveliness(self):
        return self

    def declare_token(self, key):
        return self

    def undeclare(self):
        pass


def test_a_composed_member_whose_robots_span_two_lidar_models_takes_them_one_by_one():
    """The plant delivers each lidar model's scans as one array: a member whose robots are
    not all rows of one of them goes back to one message per robot from that tick on (its
    marks gone); another member composed beside it keeps the array."""
    from bus.composed import Composed
    from bus.node import MemberSpec
    specs = [MemberSpec(Avoid(), ["a", "b"], "split"), MemberSpec(Avoid(), ["c", "d"], "whole")]
    host = Composed(specs, K, _Session())
    host.start({"mode": "lockstep", "control_tick_s": 0.02,
                "robots": {r: {"topics": {"scan": PERIOD}} for r in "abcd"}})
    keys = {r: K.topic(r, "scan") for r in "abcd"}
    assert host.takes_scans and all(host.reads(k) and not host.delivers(k)
                                    for k in keys.values())
    index = {r: i for i, r in enumerate("abcd")}
    scans = np.ones((4, N), np.float32)
    host.deliver_scans(0, [((0.0,) * 7, np.arange(4), scans)], index)
    split, whole = (h.member for h in host.hosted)
    assert split.buf[keys["a"]] == {0: ROW} and whole.buf[keys["d"]] == {0: ROW}
    host.deliver_scans(5 * T, [((0.0,) * 7, np.array([0, 2, 3]), scans[:3]),
                               ((1.0,) * 7, np.array([1]), scans[3:])], index)
    assert [h.name for h in host._rows] == ["whole"]
    assert host.delivers(keys["a"]) and host.delivers(keys["b"])
    assert not host.delivers(keys["c"]) and whole.buf[keys["c"]] == {0: ROW, 5 * T: ROW}
    assert split.buf[keys["a"]] == {} and host.hosted[0].many.rows is None
    msg = _wire(5 * T, scans[0])
    host.deliver(keys["a"], b"", None, msg)
    assert split.buf[keys["a"]] == {5 * T: msg}


def test_a_world_gone_back_takes_its_new_scans_as_the_messages_would():
    """A reset (a new epoch, the clock back at 0) after 40 ticks: the new world's scans are
    shown and complete its ticks, as one message per robot does."""
    rng = np.random.default_rng(9)
    each, rows = _member(Avoid()), _member(Avoid())
    one, many = ManyTick.of(each), ManyTick.of(rows)
    assert many.take_rows()
    index = {r: i for i, r in enumerate(ROBOTS)}
    gen = _scans(rng, 100)
    for epoch, ticks in ((1, 40), (2, 30)):
        for k in range(ticks):
            t = k * T
            if k % PERIOD == 0:
                scans = next(gen)
                for i, r in enumerate(ROBOTS):
                    msg = _wire(t, scans[i])
                    each.receive(K.topic(r, "scan"), b"", None, msg)
                head = (msg.angle_min, msg.angle_max, msg.angle_increment,
                        msg.time_increment, msg.scan_time, msg.range_min, msg.range_max)
                assert many.rows.file(t, np.arange(len(ROBOTS)), scans, head, index)
            for m in (each, rows):
                assert m.clock(t, 1.0, epoch) == (None, None)
            assert each.next_due() == t and rows.next_due() == t, (epoch, k)
            assert many.act(t) == one.act(t), (epoch, k)
