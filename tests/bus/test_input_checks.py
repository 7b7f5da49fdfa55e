"""check_input's quick pass (bus/inputs.py, _Plan) answers as the field-by-field walk does:
the same problem text, or None, on messages with bad values anywhere, hand-built values of
other types, and types it cannot lay out."""
from __future__ import annotations

import copy
import random

import numpy as np
import pytest

from bus import codec, made
from bus.inputs import ABSURD_INPUT, check_input, numbers_problem

T = codec.T
BAD = [float("nan"), float("inf"), -float("inf"), ABSURD_INPUT * 1.0000001, -2e9, 1e308]
EDGE = [ABSURD_INPUT, -ABSURD_INPUT, 0.0, -0.0, 5e-324]


def decoded(msg):
    return codec.decode(codec.encode(msg), msg.__msgtype__)


def samples():
    odom = codec.odometry(40_000_000, 1.0, -2.0, 0.5, 0.3, -0.1)
    js = codec.joint_state(40_000_000, ["left_wheel_joint", "right_wheel_joint"],
                           position=(1.0, 2.0), velocity=(0.5, -0.5))
    v3 = T["geometry_msgs/msg/Vector3"]
    imu = decoded(T["sensor_msgs/msg/Imu"](
        codec.header(40_000_000, "imu"), T["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0),
        np.full(9, 0.01), v3(0.1, 0.2, 0.3), np.zeros(9), v3(0.0, 0.0, 9.8), np.zeros(9)))
    scan = codec.laser_scan(40_000_000, -1.0, 1.0, 0.5, 0.1, 0.05, 5.0,
                            [1.0, float("inf"), 2.0, 3.0, 4.0])
    out = [("odom", decoded(odom)), ("joint_states", decoded(js)), ("imu", imu),
           ("cmd_vel", decoded(codec.twist_stamped(40_000_000, 0.2, 0.1))),
           ("gps", decoded(codec.point_stamped(40_000_000, 1.0, 2.0, 0.0)))]
    built = made.odometry(40_000_000, "odom", "base_link", 1.0, -2.0, 0.0,
                          codec.yaw_quaternion(0.5), 0.3, -0.1)   # (zero covariances shared)
    return out + [("scan", decoded(scan)), ("odom", built)]


def float_leaves(msg, path=""):
    """(owner, field name, path) of every float field and float array of a message."""
    for name in msg.__dataclass_fields__:
        v = getattr(msg, name)
        if isinstance(v, float):
            yield msg, name, None
        elif isinstance(v, np.ndarray) and v.dtype.kind == "f" and v.size:
            for i in range(v.size):
                yield msg, name, i
        elif hasattr(v, "__dataclass_fields__"):
            yield from float_leaves(v)


def reference(topic, msg):
    """check_input's answer by the walk alone."""
    if topic == "joint_states":
        names = list(msg.name)
        if names != ["left_wheel_joint", "right_wheel_joint"] or len(msg.position) != 2 \
                or len(msg.velocity) not in (0, 2):
            return "names"
    return numbers_problem(msg, "")


@pytest.mark.parametrize("k", range(7))
def test_the_quick_pass_answers_as_the_walk_on_every_value_of_every_field(k):
    topic, base = samples()[k]
    assert check_input(topic, base) is None
    rng = random.Random(k)
    n = len(list(float_leaves(base)))
    assert n > 0
    for j in range(n):
        for value in BAD + EDGE + [rng.uniform(-1e3, 1e3)]:
            msg = copy.deepcopy(base)
            owner, name, i = list(float_leaves(msg))[j]
            if i is None:
                setattr(owner, name, value)
            else:
                arr = np.array(getattr(owner, name))
                with np.errstate(over="ignore"):
                    arr[i] = value
                setattr(owner, name, arr)
            want = reference(topic, msg)
            assert check_input(topic, msg) == want, (name, i, value)


def test_a_built_messages_shared_zero_covariance_cannot_change():
    """The quick pass takes bus.made's shared covariance as checked: it is zeros, and
    read-only; a built message with an absurd value is rejected all the same."""
    assert not made.ZERO_COVARIANCE.flags.writeable and not made.ZERO_COVARIANCE.any()
    with pytest.raises(ValueError):
        made.ZERO_COVARIANCE[0] = np.nan
    bad = made.odometry(0, "odom", "base_link", 2e9, 0.0, 0.0, (0.0, 0.0, 0.0, 1.0), 0.0, 0.0)
    assert check_input("odom", bad) == numbers_problem(bad, "") == \
        "pose.pose.position.x = 2000000000.0"


def test_hand_built_values_of_other_types_get_the_walks_answer():
    odom = decoded(codec.odometry(40_000_000, 1.0, -2.0, 0.5, 0.3, -0.1))
    for value in (np.float64("nan"), np.float64(3e9), np.float32(1.0), 7, True, "x"):
        m = copy.deepcopy(odom)
        m.pose.pose.position.x = value
        assert check_input("odom", m) == numbers_problem(m, "")
    m = copy.deepcopy(odom)
    m.pose.covariance = [float("nan")] * 36          # a list, not an array: not checked
    assert check_input("odom", m) == numbers_problem(m, "") is None
    m = copy.deepcopy(odom)
    m.pose.covariance = np.full(36, 1e308)            # finite, though the sum overflows
    assert check_input("odom", m) is None
    m.pose.covariance = np.full(36, np.nan)
    assert check_input("odom", m) == "pose.covariance is not finite"
    big = np.zeros(100)                               # past the small-array path
    big[99] = -np.inf
    js = decoded(codec.joint_state(40_000_000, ["left_wheel_joint", "right_wheel_joint"],
                                   position=(1.0, 2.0)))
    m = copy.deepcopy(js)
    m.effort = big
    assert check_input("joint_states", m) == "effort is not finite"
    big[99] = 2e9
    assert check_input("joint_states", m).startswith("effort has absurd values")


def test_a_message_with_a_list_of_messages_is_walked():
    v3 = T["geometry_msgs/msg/Vector3"]
    tf = T["geometry_msgs/msg/TransformStamped"](
        codec.header(0, "world"), "robot1", T["geometry_msgs/msg/Transform"](
            v3(float("nan"), 0.0, 0.0), T["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0)))
    msg = T["tf2_msgs/msg/TFMessage"](transforms=[tf])
    assert check_input("tf", msg) == numbers_problem(msg, "") is not None


def test_a_member_configured_again_shows_its_inputs_by_the_new_coupling_and_periods():
    """What a robot's observation looks up per input (its key, lag, how old a sample may be)
    is made once, and made again when sim/info changes the coupling or a sensor's period."""
    from bus import codec
    from bus.keys import TOPICS
    from bus.member import MemberTick, Slot

    class Reads:
        inputs = ["odom", "scan"]

        def step(self, obs):
            return None
    tick = 20_000_000
    m = MemberTick("reader", tick, slots=[Slot("r", Reads(), ["odom", "scan"], False)],
                   topics=dict(TOPICS))
    info = {"mode": "lockstep", "control_tick_s": tick * 1e-9,
            "robots": {"r": {"topics": {"scan": 100}}}}
    odom = codec.odometry(tick, 1.0, 2.0, 0.0, 0.0, 0.0)
    scan_t = 10 * tick                    # 1.6 s before the tick looked at: 0.5 s is stale
    shown = []
    for coupling in ({}, {"node_input_delay_ticks": 1}, {"robots": {"r": {"topics": {}}}}):
        m.configure({**info, **coupling})
        m.buf = {"r/odom": {tick: odom}, "r/scan": {scan_t: "scan"}}
        obs = m.take_observation(m.slots[0], tick + 90 * tick)
        shown.append((obs["odom"] is odom, obs["scan"]))
        m.buf = {"r/odom": {tick: odom}}
        shown.append(m.take_observation(m.slots[0], tick)["odom"] is odom)
    # sequential: odom of the tick shown; pipelined: one tick old only; scan every 100 ticks
    # (3 periods may pass), then every tick (stale after 0.5 s)
    assert shown == [(False, "scan"), True, (False, "scan"), False, (False, None), True]


@pytest.mark.parametrize("topic", ["scan", "gps"])
def test_values_checked_before_are_answered_alike_every_time(topic):
    """A type without float arrays keeps the float values that passed (a lidar's constants
    are then checked once): the same message, good or bad, gets the same answer each time,
    however many distinct values came before."""
    base = dict(samples())[topic]
    for k in range(40):                              # (more than the plan keeps)
        good = copy.deepcopy(base)
        if topic == "scan":
            good.range_max = 5.0 + k
        else:
            good.point.x = float(k)
        for _ in range(2):
            assert check_input(topic, good) is None
        bad = copy.deepcopy(good)
        if topic == "scan":
            bad.range_max = 2e9 + k
        else:
            bad.point.y = float("nan")
        want = reference(topic, bad)
        assert want is not None
        for _ in range(3):
            assert check_input(topic, bad) == want, k
