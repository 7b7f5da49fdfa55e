"""CDR bytes of the messages a plant sends every tick, straight from their values.

``codec.encode(codec.odometry(...))`` builds a rosbags message (a tree of dataclasses) and
walks it: ~40 us for an Odometry, ~115 us for a robot's joint states, GPS and ground truth
together, which a 24-robot swarm pays every tick. Here each message has a template per
layout (frame ids, joint names, array lengths): its bytes with the values' places known,
so a message is one copy of the template and a few ``struct.pack_into``. The bytes are
those of :func:`bus.codec.encode` of the message the same values build (pinned by tests
against rosbags).
"""
from __future__ import annotations

import struct
from functools import lru_cache

import numpy as np

from .codec import _CDR_LE, _U32, _header, _pad, _string

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


def _stamped(buf: bytearray, t_ns: int) -> None:
    _STAMP.pack_into(buf, _STAMP_AT, t_ns // 1_000_000_000, t_ns % 1_000_000_000)


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
    template, at = _point_layout(frame_id)
    buf = bytearray(template)
    _stamped(buf, t_ns)
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
    template, pose_at, twist_at = _odometry_layout(frame_id, child_frame_id)
    buf = bytearray(template)
    _stamped(buf, t_ns)
    qx, qy, qz, qw = quaternion
    _D7.pack_into(buf, pose_at, x, y, z, qx, qy, qz, qw)
    _D6.pack_into(buf, twist_at, linear_mps, 0.0, 0.0, 0.0, 0.0, angular_radps)
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
    template, pos_at, vel_at, eff_at = _joint_layout(frame_id, tuple(names), len(position),
                                                     len(velocity), len(effort))
    buf = bytearray(template)
    _stamped(buf, t_ns)
    view = memoryview(buf)           # (a slice of the view is written in place, fast)
    for at, values in ((pos_at, position), (vel_at, velocity), (eff_at, effort)):
        if len(values):
            raw = np.asarray(values, dtype=_F8).tobytes()
            view[at:at + len(raw)] = raw
    view.release()
    return bytes(buf)


def clock(t_ns: int) -> bytes:
    """The bytes of ``codec.clock(t_ns)``."""
    return _CDR_LE + _STAMP.pack(t_ns // 1_000_000_000, t_ns % 1_000_000_000)
