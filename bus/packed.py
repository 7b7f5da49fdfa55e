"""CDR bytes written directly: the primitives, and the messages a plant sends every tick,
straight from their values.

Building a rosbags message (a tree of dataclasses) and walking it costs ~40 us for an
Odometry, ~115 us for a robot's joint states, GPS and ground truth together, which a
24-robot swarm pays every tick. Here each message has a template per layout (frame ids,
joint names, array lengths): its bytes with the values' places known, so a message is one
copy of the template and a few ``struct.pack_into``. These are the only encoders of Clock,
PointStamped, JointState and Odometry: :func:`bus.codec.encode` of such a message comes
here too. Their bytes are rosbags' (pinned by tests against rosbags, the oracle).
"""
from __future__ import annotations

import struct
from functools import lru_cache

import numpy as np

# ---------------------------------------------------------------- CDR (little endian, XCDR1)
_CDR_LE = b"\x00\x01\x00\x00"
_I_I = struct.Struct("<iI")
_U32 = struct.Struct("<I")


def _pad(buf: bytearray, align: int) -> None:
    # Alignment counts from the end of the 4-byte encapsulation header.
    n = (-(len(buf) - 4)) % align
    if n:
        buf += b"\x00" * n


def _string(buf: bytearray, s: str) -> None:
    b = s.encode()
    _pad(buf, 4)
    buf += _U32.pack(len(b) + 1)
    buf += b
    buf += b"\x00"


def _header(buf: bytearray, h) -> None:
    buf += _I_I.pack(h.stamp.sec, h.stamp.nanosec)
    _string(buf, h.frame_id)


def _doubles(buf: bytearray, values) -> None:
    _pad(buf, 8)
    buf += struct.pack(f"<{len(values)}d", *values)


def _f64_seq(buf: bytearray, arr) -> None:
    a = np.ascontiguousarray(arr, dtype="<f8")
    _pad(buf, 4)
    buf += _U32.pack(a.size)
    if a.size:
        _pad(buf, 8)
        buf += a.tobytes()

_STAMP = struct.Struct("<iI")
_D3 = struct.Struct("<3d")
_D7 = struct.Struct("<7d")
_D6 = struct.Struct("<6d")
_STAMP_AT = 4                      # the header's stamp comes right after the encapsulation
_F8 = np.dtype("<f8")


class _Stamp:
    """A stand-in header for the template (the stamp is written over per message)."""
    class stamp:
        sec = 0
        nanosec = 0

    def __init__(self, frame_id: str) -> None:
        self.frame_id = frame_id


def _split(t_ns: int) -> tuple[int, int]:
    return t_ns // 1_000_000_000, t_ns % 1_000_000_000


@lru_cache(maxsize=256)
def _point_layout(frame_id: str) -> tuple[bytes, int]:
    buf = bytearray(_CDR_LE)
    _header(buf, _Stamp(frame_id))
    _pad(buf, 8)
    at = len(buf)
    buf += bytes(24)
    return bytes(buf), at


def point_stamped(t_ns: int, x: float, y: float, z: float, frame_id: str = "world") -> bytes:
    """The bytes of ``codec.point_stamped(t_ns, x, y, z, frame_id)``."""
    return _point_stamped(*_split(t_ns), frame_id, x, y, z)


def _point_stamped(sec: int, nanosec: int, frame_id: str, x: float, y: float,
                   z: float) -> bytes:
    template, at = _point_layout(frame_id)
    buf = bytearray(template)
    _STAMP.pack_into(buf, _STAMP_AT, sec, nanosec)
    _D3.pack_into(buf, at, x, y, z)
    return bytes(buf)


@lru_cache(maxsize=256)
def _odometry_layout(frame_id: str, child_frame_id: str) -> tuple[bytes, int, int]:
    buf = bytearray(_CDR_LE)
    _header(buf, _Stamp(frame_id))
    _string(buf, child_frame_id)
    _pad(buf, 8)
    pose_at = len(buf)
    buf += bytes(7 * 8 + 36 * 8)           # position, orientation; covariance (zeros)
    twist_at = len(buf)
    buf += bytes(6 * 8 + 36 * 8)           # linear, angular; covariance (zeros)
    return bytes(buf), pose_at, twist_at


def odometry(t_ns: int, x: float, y: float, z: float, quaternion, linear_mps: float,
             angular_radps: float, frame_id: str = "odom",
             child_frame_id: str = "base_link") -> bytes:
    """The bytes of ``codec.odometry(t_ns, x, y, yaw, linear_mps, angular_radps, frame_id,
    child_frame_id, z, quaternion)`` (quaternion x, y, z, w; zero covariances)."""
    return _odometry(*_split(t_ns), frame_id, child_frame_id, (x, y, z, *quaternion),
                     (linear_mps, 0.0, 0.0, 0.0, 0.0, angular_radps))


def _odometry(sec: int, nanosec: int, frame_id: str, child_frame_id: str, pose7, twist6,
              pose_cov=None, twist_cov=None) -> bytes:
    """An Odometry's bytes: pose (x, y, z, qx, qy, qz, qw), twist (linear, angular),
    covariances (36 each; None: zeros)."""
    template, pose_at, twist_at = _odometry_layout(frame_id, child_frame_id)
    buf = bytearray(template)
    _STAMP.pack_into(buf, _STAMP_AT, sec, nanosec)
    _D7.pack_into(buf, pose_at, *pose7)
    _D6.pack_into(buf, twist_at, *twist6)
    view = memoryview(buf)
    for at, cov in ((pose_at + 56, pose_cov), (twist_at + 48, twist_cov)):
        if cov is not None and np.any(cov):
            view[at:at + 288] = np.ascontiguousarray(cov, dtype=_F8).reshape(36).tobytes()
    view.release()
    return bytes(buf)


@lru_cache(maxsize=256)
def _joint_layout(frame_id: str, names: tuple[str, ...], n_pos: int, n_vel: int,
                  n_eff: int) -> tuple[bytes, int, int, int]:
    buf = bytearray(_CDR_LE)
    _header(buf, _Stamp(frame_id))
    _pad(buf, 4)
    buf += _U32.pack(len(names))
    for n in names:
        _string(buf, n)
    at = []
    for n in (n_pos, n_vel, n_eff):
        _pad(buf, 4)
        buf += _U32.pack(n)
        if n:
            _pad(buf, 8)
        at.append(len(buf))
        buf += bytes(8 * n)
    return (bytes(buf), *at)


def joint_state(t_ns: int, names: tuple[str, ...], position, velocity=(), effort=(),
                frame_id: str = "") -> bytes:
    """The bytes of ``codec.joint_state(t_ns, names, position, velocity, effort)`` (its
    header's frame id ``frame_id``); the arrays as sequences of floats."""
    return _joint_state(*_split(t_ns), frame_id, names, position, velocity, effort)


def _joint_state(sec: int, nanosec: int, frame_id: str, names, position, velocity,
                 effort) -> bytes:
    template, pos_at, vel_at, eff_at = _joint_layout(frame_id, tuple(names), len(position),
                                                     len(velocity), len(effort))
    buf = bytearray(template)
    _STAMP.pack_into(buf, _STAMP_AT, sec, nanosec)
    view = memoryview(buf)           # (a slice of the view is written in place, fast)
    for at, values in ((pos_at, position), (vel_at, velocity), (eff_at, effort)):
        if len(values):
            raw = np.asarray(values, dtype=_F8).tobytes()
            view[at:at + len(raw)] = raw
    view.release()
    return bytes(buf)


def clock(t_ns: int) -> bytes:
    """The bytes of ``codec.clock(t_ns)``."""
    return _CDR_LE + _STAMP.pack(*_split(t_ns))


# ------------------------------------------------- the same, from a rosbags message (codec.encode)
def encode_clock(m) -> bytes:
    return _CDR_LE + _STAMP.pack(m.clock.sec, m.clock.nanosec)


def encode_point_stamped(m) -> bytes:
    h, p = m.header, m.point
    return _point_stamped(h.stamp.sec, h.stamp.nanosec, h.frame_id, p.x, p.y, p.z)


def encode_joint_state(m) -> bytes:
    h = m.header
    return _joint_state(h.stamp.sec, h.stamp.nanosec, h.frame_id, m.name, m.position,
                        m.velocity, m.effort)


def encode_odometry(m) -> bytes:
    h, p, q, t = m.header, m.pose.pose.position, m.pose.pose.orientation, m.twist.twist
    return _odometry(h.stamp.sec, h.stamp.nanosec, h.frame_id, m.child_frame_id,
                     (p.x, p.y, p.z, q.x, q.y, q.z, q.w),
                     (t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y,
                      t.angular.z), m.pose.covariance, m.twist.covariance)
