"""The hand-written decoders (bus/cdrfast.py) give rosbags' objects, or leave the payload
to rosbags: on valid messages, every truncation, trailing bytes and corrupted bytes."""
from __future__ import annotations

import dataclasses
import random

import numpy as np
import pytest

from bus import codec

FAST = codec._FAST_DECODE


def rosbags(data: bytes, msgtype: str):
    try:
        return codec.TYPESTORE.deserialize_cdr(memoryview(data), msgtype)
    except Exception:
        return None


def same(a, b) -> bool:
    """Equal field by field, floats by their bits, arrays by dtype, shape, bits and
    writability."""
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        return (a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
                and a.flags.writeable == b.flags.writeable)
    if isinstance(a, float):
        return np.float64(a).tobytes() == np.float64(b).tobytes()
    if isinstance(a, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if dataclasses.is_dataclass(a):
        return all(same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))
    return a == b


def messages():
    rng = random.Random(3)
    vals = [0.0, -0.0, 1.5, -2.25e-300, float("nan"), float("inf"), -float("inf"), 1e300]
    f32 = [0.0, -0.0, 1.5, 1e-40, float("nan"), float("inf"), -float("inf"), 3e38]
    for i in range(6):
        v = [rng.choice(vals) if i % 3 == 0 else rng.uniform(-10, 10) for _ in range(6)]
        frame = ["", "odom", "r1/odom", "ödöm", "x" * (i + 1)][i % 5]
        odom = codec.odometry(rng.randrange(0, 10**12), 0.0, 0.0, 0.3, 0.0, 0.0,
                              frame_id=frame, child_frame_id=frame[::-1],
                              quaternion=None if i % 2 else v[2:6])
        p = odom.pose.pose.position
        p.x, p.y, p.z = v[:3]
        odom.twist.twist.linear.x, odom.twist.twist.angular.z = v[3:5]
        cov = np.array([rng.choice(vals) for _ in range(36)])
        odom.pose.covariance = cov
        yield odom, "nav_msgs/msg/Odometry"
        n = i % 4
        yield codec.joint_state(rng.randrange(0, 10**12), [frame + str(k) for k in range(n)],
                                position=v[:n], velocity=v[:n] if i % 2 else (),
                                effort=v[:i % 3]), "sensor_msgs/msg/JointState"
        yield codec.twist_stamped(rng.randrange(0, 10**12), v[0], v[1], frame), \
            "geometry_msgs/msg/TwistStamped"
        scan = codec.laser_scan(rng.randrange(0, 10**12), -v[0], v[1], 0.1, 0.1, 0.05, 8.0,
                                [rng.choice(f32) for _ in range(i + n)], frame_id=frame)
        scan.time_increment = v[2]
        scan.intensities = np.array(v[:i % 3], np.float32)
        yield scan, "sensor_msgs/msg/LaserScan"


@pytest.mark.parametrize("i", range(24))
def test_a_fast_decode_equals_rosbags_on_valid_truncated_extended_and_corrupted_bytes(i):
    msg, msgtype = list(messages())[i]
    data = codec.encode(msg)
    got = FAST.decode(data, msgtype)
    assert got is not None and same(got, rosbags(data, msgtype))
    variants = [data[:k] for k in range(len(data))]                       # truncated
    variants += [data + b"\x00" * k for k in range(1, 9)]                  # extended
    rng = random.Random(i)
    for pos in range(len(data)):                                          # corrupted
        for byte in (0, 0xFF, rng.randrange(256)):
            variants.append(data[:pos] + bytes((byte,)) + data[pos + 1:])
    for v in variants:
        fast, oracle = FAST.decode(v, msgtype), rosbags(v, msgtype)
        if fast is not None:       # decoded here only where rosbags decodes the same
            assert oracle is not None and same(fast, oracle), v.hex()
    # and codec.decode accepts and refuses what rosbags does
    for v in variants:
        oracle = rosbags(v, msgtype)
        if oracle is None:
            with pytest.raises(codec.CodecError):
                codec.decode(v, msgtype)
        else:
            assert same(codec.decode(v, msgtype), oracle)


def test_other_types_and_encapsulations_are_left_to_rosbags():
    msg = codec.twist_stamped(20_000_000, 0.5, 0.1)
    data = codec.encode(msg)
    assert FAST.decode(data, "geometry_msgs/msg/PointStamped") is None
    assert FAST.decode(b"\x00\x01\x00\x01" + data[4:], "geometry_msgs/msg/TwistStamped") is None
    assert FAST.decode(bytearray(data), "geometry_msgs/msg/TwistStamped") is None
    assert codec.decode(codec.encode(codec.clock(5)), "rosgraph_msgs/msg/Clock").clock.nanosec == 5
