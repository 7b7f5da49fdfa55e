"""The stamp rules for commands (docs/PROTOCOL.md section 7), on ``plant.commands.check_stamp``
itself and through ``decode_command``: a stamp in the future or older than the robot's
``cmd_timeout_s`` is rejected, a zero stamp means "now" (an unstamped command), and an
invalid time is rejected whatever the clock says."""
from __future__ import annotations

import pytest

from bus import codec
from plant.commands import check_stamp, decode_command
from plant.world import DriveSpec

TICK = 20_000_000
NOW = 50 * 10**9                         # t = 50 s
TIMEOUT_S = 0.5                          # the default cmd_timeout_s


def stamp(t_ns: int):
    return codec.time_msg(t_ns)


@pytest.mark.parametrize("t_ns", [NOW, NOW - TICK, NOW - 3 * TICK])
def test_a_stamp_of_now_or_a_few_ticks_ago_is_accepted(t_ns):
    check_stamp(stamp(t_ns), NOW, TICK, TIMEOUT_S)


def test_a_stamp_for_the_tick_being_stepped_is_accepted_one_further_is_the_future():
    # a command computed for tick k may reach the plant while it is still at t_(k-1)
    check_stamp(stamp(NOW + TICK), NOW, TICK, TIMEOUT_S)
    for ahead in (TICK + 1, 2 * TICK, 10**12):
        with pytest.raises(ValueError, match="in the future"):
            check_stamp(stamp(NOW + ahead), NOW, TICK, TIMEOUT_S)


def test_older_than_cmd_timeout_is_rejected_and_not_before():
    timeout_ns = int(TIMEOUT_S * 1e9)
    check_stamp(stamp(NOW - timeout_ns), NOW, TICK, TIMEOUT_S)        # exactly at the limit
    for older in (timeout_ns + 1, timeout_ns + TICK, NOW - 1):
        with pytest.raises(ValueError, match="older than cmd_timeout 0.5 s"):
            check_stamp(stamp(NOW - older), NOW, TICK, TIMEOUT_S)
    # the limit is the robot's, not a constant
    check_stamp(stamp(NOW - 2 * 10**9), NOW, TICK, 2.5)
    with pytest.raises(ValueError, match="older than cmd_timeout 1.5 s"):
        check_stamp(stamp(NOW - 2 * 10**9), NOW, TICK, 1.5)


def test_without_a_timeout_age_is_not_checked_the_future_still_is():
    check_stamp(stamp(TICK), NOW, TICK, None)
    with pytest.raises(ValueError, match="in the future"):
        check_stamp(stamp(NOW + 2 * TICK), NOW, TICK, None)


@pytest.mark.parametrize("now", [0, TICK, NOW, 10**15])
def test_a_zero_stamp_means_now_at_any_time(now):
    check_stamp(stamp(0), now, TICK, TIMEOUT_S)


@pytest.mark.parametrize("sec,nanosec", [(-1, 0), (-5, 999), (3, 1_000_000_000),
                                         (3, 2**32 - 1)])
def test_an_invalid_time_is_rejected(sec, nanosec):
    T = codec.T["builtin_interfaces/msg/Time"]
    with pytest.raises(ValueError, match="invalid stamp"):
        check_stamp(T(sec=sec, nanosec=nanosec), NOW, TICK, TIMEOUT_S)


def test_decode_command_applies_the_rules_to_both_command_keys():
    drive = DriveSpec()
    assert drive.cmd_timeout_s == TIMEOUT_S
    old = NOW - int(TIMEOUT_S * 1e9) - TICK
    msgs = {"cmd_vel": lambda t: codec.twist_stamped(t, 0.1, 0.0),
            "wheel_cmd": lambda t: codec.joint_state(
                t, ["left_wheel_joint", "right_wheel_joint"], [], [1.0, 1.0])}
    for topic, make in msgs.items():
        def decode(t, check_age=True):
            return decode_command(codec.encode(make(t)), topic, drive, NOW, TICK, check_age,
                                  "robot1")
        assert decode(NOW)[1] == NOW
        assert decode(0)[1] == 0                                   # unstamped: "now"
        with pytest.raises(ValueError, match="in the future"):
            decode(NOW + 2 * TICK)
        with pytest.raises(ValueError, match="older than cmd_timeout"):
            decode(old)
        assert decode(old, check_age=False)[1] == old              # lockstep: no age check


def test_the_twist_fast_path_reads_what_the_generic_decoder_reads():
    """plant.commands reads a TwistStamped's canonical CDR layout itself (the generic
    decoder costs ~10x): the same stamp, frame and six numbers for frames of every length
    modulo 8, and anything else (a byte more or less, big-endian, no NUL, bad UTF-8) goes
    to the generic decoder."""
    import numpy as np
    from rosbags.typesys.stores.ros2_humble import (builtin_interfaces__msg__Time as Time,
                                                    geometry_msgs__msg__Twist as Twist,
                                                    geometry_msgs__msg__TwistStamped as TS,
                                                    geometry_msgs__msg__Vector3 as V3,
                                                    std_msgs__msg__Header as Header)

    from plant.commands import _twist_stamped
    rng = np.random.default_rng(0)
    for fid in ("", "a", "base_link", "r0/base_link", "robot12/base_link", "é/x", "b" * 37):
        for _ in range(8):
            v = rng.normal(size=6)
            m = TS(header=Header(stamp=Time(sec=int(rng.integers(0, 2**31)),
                                            nanosec=int(rng.integers(0, 10**9))), frame_id=fid),
                   twist=Twist(linear=V3(*v[:3]), angular=V3(*v[3:])))
            b = bytes(codec.TYPESTORE.serialize_cdr(m, "geometry_msgs/msg/TwistStamped"))
            got, want = _twist_stamped(b), codec.decode(b, "geometry_msgs/msg/TwistStamped")
            assert got is not None
            assert (got[0].sec, got[0].nanosec) == (want.header.stamp.sec, want.header.stamp.nanosec)
            assert got[1] == want.header.frame_id
            tw = want.twist
            assert got[2] == (tw.linear.x, tw.linear.y, tw.linear.z, tw.angular.x, tw.angular.y,
                              tw.angular.z)
            for other in (b + b"\0", b[:-1], b"\0\0" + b[2:]):
                assert _twist_stamped(other) is None
    bad = bytearray(b)
    bad[16 + len(fid.encode())] = 1                     # no terminating NUL
    assert _twist_stamped(bytes(bad)) is None
    bad = bytearray(codec.TYPESTORE.serialize_cdr(
        TS(header=Header(stamp=Time(sec=1, nanosec=0), frame_id="ab"),
           twist=Twist(linear=V3(0, 0, 0), angular=V3(0, 0, 0))), "geometry_msgs/msg/TwistStamped"))
    bad[16] = 0xFF                                      # not UTF-8
    assert _twist_stamped(bytes(bad)) is None


def test_a_composed_member_s_command_taken_from_its_values_is_what_its_bytes_decode_to():
    """twist_command (the plant takes a composed member's command from the values it packed)
    against decode_command of those bytes: the same command and stamp, or the same error,
    over finite, non-finite and absurd speeds and stamps now, ahead, in the future and
    older than cmd_timeout_s, with the age checked or not."""
    import itertools
    import math

    from plant.commands import twist_command
    drive = DriveSpec()
    speeds = [0.0, -0.0, 0.3, -1.25, 1e-300, 9.99, 1e3, -1e300, math.nan, math.inf, -math.inf]
    stamps = [0, NOW, NOW + TICK, NOW + TICK + 1, NOW - TICK, NOW - 10**9, 1]
    for v, w, t, age in itertools.product(speeds, speeds, stamps, (True, False)):
        data = codec.twist_stamped_bytes(t, v, w)
        try:
            want = decode_command(data, "cmd_vel", drive, NOW, TICK, age, robot="r1")
        except ValueError as exc:
            with pytest.raises(ValueError) as got:
                twist_command(t, v, w, drive, NOW, TICK, age)
            assert str(got.value) == str(exc), (v, w, t, age)
        else:
            got = twist_command(t, v, w, drive, NOW, TICK, age)
            assert got == want and [math.copysign(1, x) for x in (got[0].linear,
                                                                 got[0].angular)] == \
                [math.copysign(1, x) for x in (want[0].linear, want[0].angular)], (v, w, t)
