import math

import numpy as np
import pytest

from bus import codec
from bus.keys import TOPICS, BadName, Keys, check_name


@pytest.mark.parametrize("bad", ["", "*", "**", "a*", "$x", "a/b", "robot 1", "sim", "1abc",
                                 "a" * 65, "ro$bot", "a?b", "a#b"])
def test_names_that_would_change_key_expressions_are_refused(bad):
    with pytest.raises(BadName):
        check_name(bad)
    with pytest.raises(BadName):
        Keys(bad) if bad else check_name(bad, "namespace")


def test_namespace_prefixes_every_key():
    k = Keys("lab2")
    assert k.clock == "lab2/sim/clock"
    assert k.topic("robot1", "cmd_vel") == "lab2/robot1/cmd_vel"
    assert k.topic("robot1", "camera/image_raw") == "lab2/robot1/camera/image_raw"
    assert k.sync("n1") == "lab2/sim/sync/n1"
    assert k.all == "lab2/**"
    assert k.robot_topic_of("lab2/robot1/odom") == ("robot1", "odom")
    assert k.robot_topic_of("robot1/odom") is None
    assert k.msgtype_of("lab2/sim/clock") == "rosgraph_msgs/msg/Clock"
    assert Keys().topic("r", "gps") == "r/gps"


def test_diffbot_topics_types_a_namespaced_run_s_keys_without_namespace():
    from bridges.topics import RateMeter
    meter = RateMeter()
    for key in ("lab2/robot1/odom", "lab2/sim/clock", "robot1/odom", "lab2/x/y", "a$b/robot1/odom"):
        meter.seen[key] = [1, 0.0, 0.0, None, None]
    types = {r["key"]: r["type"] for r in meter.table(Keys())}
    assert types == {"lab2/robot1/odom": "nav_msgs/msg/Odometry",
                     "lab2/sim/clock": "rosgraph_msgs/msg/Clock",
                     "robot1/odom": "nav_msgs/msg/Odometry", "lab2/x/y": "-",
                     "a$b/robot1/odom": "-"}
    # with --namespace only that run's keys are its own
    assert {r["key"]: r["type"] for r in meter.table(Keys("lab3"))}["lab2/robot1/odom"] == "-"


def test_unknown_topic_is_an_error():
    with pytest.raises(BadName):
        Keys().topic("robot1", "nope")


def test_every_topic_type_is_a_known_ros2_message():
    for t in TOPICS.values():
        assert t.msgtype in codec.TYPESTORE.types


def test_messages_round_trip_through_cdr():
    t = 12_345_678_901
    tw = codec.decode(codec.encode(codec.twist_stamped(t, 0.3, -0.2)), "geometry_msgs/msg/TwistStamped")
    assert codec.msg_stamp_ns(tw) == t
    assert (tw.twist.linear.x, tw.twist.angular.z) == (0.3, -0.2)
    js = codec.decode(codec.encode(codec.joint_state(t, ["l", "r"], [1.5, 2.5], [0.1, 0.2])),
                      "sensor_msgs/msg/JointState")
    assert js.name == ["l", "r"] and np.allclose(js.position, [1.5, 2.5])
    od = codec.decode(codec.encode(codec.odometry(t, 1.0, 2.0, 0.7, 0.1, 0.2)), "nav_msgs/msg/Odometry")
    assert math.isclose(codec.quaternion_to_yaw(od.pose.pose.orientation), 0.7)
    assert od.pose.pose.position.y == 2.0
    assert codec.msg_stamp_ns(codec.decode(codec.encode(codec.clock(t)), "rosgraph_msgs/msg/Clock")) == t
    assert codec.parse_attachment(codec.attachment(7, t))[:2] == (7, t)
    assert codec.parse_attachment(b"short") is None


@pytest.mark.parametrize("payload", [b"", b"\x00", b"\x00\x01\x00\x00\xff\xff\xff\xff" * 3,
                                     bytes(range(256)), b"\x00\x01\x00\x00" + b"\x7f" * 40])
def test_malformed_payloads_raise_codec_error(payload):
    with pytest.raises(codec.CodecError):
        codec.decode(payload, "sensor_msgs/msg/JointState")


def test_summarize_shortens_large_arrays():
    js = codec.joint_state(0, ["a"] * 20, np.arange(100.0))
    s = codec.summarize(js)
    assert "100" in s["position"] and len(s["name"]) == 7


from hypothesis import example, given, settings, strategies as st  # noqa: E402

from ..conftest import examples  # noqa: E402

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
names = st.text(st.characters(
    blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=12)
stamps = st.integers(0, (2**31 - 1) * 10**9)   # int32 seconds, as builtin_interfaces/Time


def _rosbags(msg) -> bytes:
    return bytes(codec.TYPESTORE.serialize_cdr(msg, msg.__msgtype__))


@settings(max_examples=examples(150), deadline=None)
@given(dims=st.lists(st.tuples(names, st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1)),
                     max_size=3), offset=st.integers(0, 2**32 - 1),
       data=st.lists(st.floats(width=64), max_size=9))
def test_fast_float64_multi_array_bytes_equal_rosbags(dims, offset, data):
    T = codec.T
    layout = T["std_msgs/msg/MultiArrayLayout"](
        dim=[T["std_msgs/msg/MultiArrayDimension"](label=lb, size=n, stride=s)
             for lb, n, s in dims], data_offset=offset)
    m = T["std_msgs/msg/Float64MultiArray"](layout=layout, data=np.array(data, dtype=np.float64))
    assert codec.encode(m) == _rosbags(m)
    assert codec.encode(m) == _rosbags(m)          # (its layout's bytes kept: the same again)


@settings(max_examples=examples(150), deadline=None)
@given(t=stamps, v=finite, w=finite, frame=names)
def test_fast_twist_and_clock_bytes_equal_rosbags(t, v, w, frame):
    m = codec.twist_stamped(t, v, w, frame_id=frame)
    assert codec.encode(m) == _rosbags(m)
    # a member's command, packed straight from its values
    assert codec.twist_stamped_bytes(t, v, w, frame) == _rosbags(m)
    c = codec.clock(t)
    assert codec.encode(c) == _rosbags(c)


@settings(max_examples=examples(150), deadline=None)
@given(t=stamps, xyz=st.tuples(finite, finite, finite), frame=names, child=names,
       yaw=st.floats(-10, 10))
def test_fast_point_and_odometry_bytes_equal_rosbags(t, xyz, frame, child, yaw):
    p = codec.point_stamped(t, *xyz, frame_id=frame)
    assert codec.encode(p) == _rosbags(p)
    o = codec.odometry(t, xyz[0], xyz[1], yaw, xyz[2], -xyz[0], frame_id=frame,
                       child_frame_id=child, z=xyz[1])
    assert codec.encode(o) == _rosbags(o)


def _odometry_full(t, frame, child, pose7, twist6, pose_cov, twist_cov):
    """An Odometry with every field of its pose, twist and both covariances set."""
    T = codec.T
    V = T["geometry_msgs/msg/Vector3"]
    return T["nav_msgs/msg/Odometry"](
        header=codec.header(t, frame), child_frame_id=child,
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=pose7[0], y=pose7[1], z=pose7[2]),
                orientation=T["geometry_msgs/msg/Quaternion"](
                    x=pose7[3], y=pose7[4], z=pose7[5], w=pose7[6])),
            covariance=np.array(pose_cov, dtype=np.float64)),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=V(x=twist6[0], y=twist6[1], z=twist6[2]),
                                               angular=V(x=twist6[3], y=twist6[4], z=twist6[5])),
            covariance=np.array(twist_cov, dtype=np.float64)))


_COV_STEPS = (np.arange(36, dtype=np.float64) + 1.0) / 64.0   # no zero: every slot is seen


@settings(max_examples=examples(60), deadline=None)
@given(t=stamps, frame=names, child=names, pose7=st.lists(finite, min_size=7, max_size=7),
       twist6=st.lists(finite, min_size=6, max_size=6),
       pose_cov=st.lists(finite, min_size=36, max_size=36),
       twist_cov=st.lists(finite, min_size=36, max_size=36))
@example(t=7, frame="odom", child="base_link", pose7=[1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.9],
         twist6=[0.5, 0.6, 0.7, 0.8, 0.9, 1.25], pose_cov=list(_COV_STEPS),
         twist_cov=list(-_COV_STEPS))
def test_fast_odometry_with_covariances_bytes_equal_rosbags(t, frame, child, pose7, twist6,
                                                            pose_cov, twist_cov):
    """The fast encoder writes each covariance in its own 36 slots after its pose or twist
    (a filter's odometry carries them; zero covariances alone would not show a misplaced one)."""
    m = _odometry_full(t, frame, child, pose7, twist6, pose_cov, twist_cov)
    data = codec.encode(m)
    assert data == _rosbags(m)
    back = codec.decode(data, "nav_msgs/msg/Odometry")
    assert back.twist.twist.angular.z == twist6[5]
    assert list(back.pose.covariance) == list(pose_cov)
    assert list(back.twist.covariance) == list(twist_cov)


@settings(max_examples=examples(150), deadline=None)
@given(t=stamps, frame=names, joints=st.lists(names, max_size=4),
       data=st.lists(finite, max_size=5), n_vel=st.integers(0, 3))
def test_fast_joint_state_bytes_equal_rosbags(t, frame, joints, data, n_vel):
    m = codec.joint_state(t, joints, data, data[:n_vel], data[:1])
    m.header.frame_id = frame
    assert codec.encode(m) == _rosbags(m)


@settings(max_examples=examples(100), deadline=None)
@given(t=stamps, frame=names, h=st.integers(0, 5), w=st.integers(0, 5), enc=names,
       seed=st.integers(0, 2**32 - 1))
def test_fast_image_bytes_equal_rosbags(t, frame, h, w, enc, seed):
    rgb = np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)
    m = codec.image(t, rgb, frame_id=frame)
    m.encoding = enc
    assert codec.encode(m) == _rosbags(m)


f32 = st.floats(allow_nan=False, allow_infinity=False, width=32)


@settings(max_examples=examples(100), deadline=None)
@given(t=stamps, frame=names, head=st.lists(f32, min_size=6, max_size=6),
       ranges=st.lists(st.floats(width=32), max_size=8))
def test_fast_laser_scan_bytes_equal_rosbags(t, frame, head, ranges):
    m = codec.laser_scan(t, *head, ranges, frame_id=frame)
    m.intensities = np.asarray(ranges[:2], dtype=np.float32)
    assert codec.encode(m) == _rosbags(m)


@settings(max_examples=examples(100), deadline=None)
@given(t=stamps, frame=names, model=names, d=st.lists(finite, max_size=8),
       k=st.lists(finite, min_size=9, max_size=9), size=st.tuples(st.integers(0, 4096),
                                                                   st.integers(0, 4096)))
def test_fast_camera_info_bytes_equal_rosbags(t, frame, model, d, k, size):
    m = codec.camera_info(t, size[1], size[0], model, d, k, k[::-1], k + k[:3], frame_id=frame)
    assert codec.encode(m) == _rosbags(m)


# ---------------------------------------------------------------- bus.packed: bytes from values
from bus import packed  # noqa: E402


@settings(max_examples=examples(150), deadline=None)
@given(t=stamps, xyz=st.tuples(finite, finite, finite), q=st.tuples(finite, finite, finite, finite),
       v=finite, w=finite, frame=names, child=names)
def test_packed_point_and_odometry_are_the_bytes_of_their_messages(t, xyz, q, v, w, frame, child):
    assert packed.point_stamped(t, *xyz, frame_id=frame) == \
        _rosbags(codec.point_stamped(t, *xyz, frame_id=frame))
    m = codec.odometry(t, xyz[0], xyz[1], 0.0, v, w, frame_id=frame, child_frame_id=child,
                       z=xyz[2], quaternion=q)
    assert packed.odometry(t, *xyz, q, v, w, frame_id=frame, child_frame_id=child) == _rosbags(m)
    assert packed.clock(t) == _rosbags(codec.clock(t))


@settings(max_examples=examples(150), deadline=None)
@given(t=stamps, joints=st.lists(names, max_size=4), data=st.lists(finite, max_size=5),
       n_vel=st.integers(0, 3))
def test_packed_joint_state_is_the_bytes_of_its_message(t, joints, data, n_vel):
    want = _rosbags(codec.joint_state(t, joints, data, data[:n_vel], data[:1]))
    assert packed.joint_state(t, tuple(joints), data, data[:n_vel], data[:1]) == want
    assert packed.joint_state(t, tuple(joints), np.array(data), np.array(data[:n_vel]),
                              np.array(data[:1])) == want


@pytest.mark.slow
def test_the_bus_s_own_types_are_rosbags_jazzy_types_and_the_rest_load_on_first_use():
    """bus/msgtypes.py is rosbags' Jazzy definitions of the bus's types (regenerate with
    ``python -m bus.msgtypes_build`` after a rosbags upgrade); a process that meets no other
    type never imports the full store, one that does gets it as if it had been there."""
    import dataclasses
    import subprocess
    import sys

    from rosbags.typesys import Stores, get_typestore

    from bus import msgtypes, msgtypes_build
    full = get_typestore(Stores.ROS2_JAZZY)
    import re
    same = re.compile(r"from rosbags [^:]*: do not edit")   # (any release with these types)
    assert same.sub("", open(msgtypes.__file__).read()) == same.sub("", msgtypes_build.source()), \
        "bus/msgtypes.py differs from the installed rosbags: python -m bus.msgtypes_build"
    for name, defs in msgtypes.FIELDDEFS.items():
        assert defs == full.fielddefs[name]
        ours, theirs = codec.T[name], full.types[name]
        assert [(f.name, f.default) for f in dataclasses.fields(ours)] == \
            [(f.name, f.default) for f in dataclasses.fields(theirs)]
    for name in msgtypes_build.ROOTS:                      # the bus's types come from ours
        assert codec.T[name].__module__ == "bus.msgtypes"
    probe = ("import sys; from bus import codec; "
             "s = 'rosbags.typesys.stores.ros2_jazzy'; print(s in sys.modules); "
             "codec.encode(codec.twist_stamped(5, 0.1, 0.2)); print(s in sys.modules); "
             "m = codec.T['std_msgs/msg/Int32'](data=7); "
             "print(codec.decode(codec.encode(m), 'std_msgs/msg/Int32').data, s in sys.modules); "
             "print('diagnostic_msgs/msg/KeyValue' in codec.TYPESTORE.fielddefs, "
             "len(codec.TYPESTORE.types) == %d)" % len(full.types))
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True, timeout=60).stdout.split("\n")
    assert out[:4] == ["False", "False", "7 True", "True True"], out


@settings(max_examples=examples(150), deadline=None)
@given(seq=st.integers(0, 2**65), t=st.integers(0, 2**64 - 1), flags=st.integers(0, 255),
       n_plant=st.integers(0, 2**16 - 1),
       node=st.one_of(st.none(), st.text(max_size=90).filter(lambda s: len(s.encode()) < 256)))
@example(seq=1, t=0, flags=codec.FINAL | 4, n_plant=1, node="m")      # FINAL with a hold
@example(seq=1, t=0, flags=0, n_plant=0, node="")                      # no name
def test_a_member_s_attachment_comes_with_what_parsing_it_gives(seq, t, flags, n_plant, node):
    """A composed member hands the plant its attachment and its parsed form, built from the
    values: always what parse_attachment reads from the bytes, bad ones included."""
    att, parsed = codec.attachment_parsed(seq, t, flags, n_plant, node)
    assert att == codec.attachment(seq, t, flags, n_plant, node)
    assert parsed == codec.parse_attachment(att)
