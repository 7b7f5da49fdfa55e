"""CDR bytes written directly: the primitives, and the messages a plant sends every tick,
straight from their values.

Building a rosbags message (a tree of dataclasses) and walking it costs ~40 us for an
Odometry, ~115 us for a robot's joint states, GPS and ground truth together, which a
24-robot swarm pays every tick. Here each message has a template per layout (frame ids,
joint names, array lengths): its bytes with the values' places known, so a message is one
copy of the template and a few ``struct.pack_into``. These are the only encoders of Clock,
PointStamped, JointState, Odometry and Float64MultiArray: :func:`bus.codec.encode` of such
a message comes here too. Their bytes are rosbags' (pinned by tests against rosbags, the
oracle).
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
    for at, cov in ((pose_at + 56, pose_cov), (twist_at + 48, twist_cov)):
        # (a message's covariance is an array: its own any() is a cheaper call than np.any)
        if cov is not None and (cov.any() if isinstance(cov, np.ndarray) else np.any(cov)):
            buf[at:at + 288] = np.ascontiguousarray(cov, dtype=_F8).reshape(36).tobytes()
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


_U_U = struct.Struct("<II")


@lru_cache(maxsize=64)
def _multi_array_layout(dims: tuple, data_offset: int) -> bytes:
    """A Float64MultiArray's bytes before its data: its layout, ``dims`` as (label, size,
    stride) each."""
    buf = bytearray(_CDR_LE)
    buf += _U32.pack(len(dims))
    for label, size, stride in dims:
        _string(buf, label)
        _pad(buf, 4)
        buf += _U_U.pack(size, stride)
    _pad(buf, 4)
    buf += _U32.pack(data_offset)
    return bytes(buf)


def encode_f64_array(m) -> bytes:
    """std_msgs/Float64MultiArray (a node's small debug vectors: one a frame, say)."""
    lay = m.layout
    buf = bytearray(_multi_array_layout(tuple((d.label, d.size, d.stride) for d in lay.dim),
                                        lay.data_offset))
    _f64_seq(buf, m.data)
    return bytes(buf)


# ------------------------------------------------- many messages of one type at once (batches)
_U8 = np.uint8


class Rows:
    """The bytes of N messages of one type in one pass: a template per row (its frame ids,
    so its length and its fields' places may differ from row to row), stacked once in an
    (N, longest) byte matrix; :meth:`pack` writes every row's stamp and values with a few
    array assignments and cuts the rows out. Row i's bytes equal the single-message
    encoder's for the same values (the same templates, the same IEEE bits)."""

    def __init__(self, templates: list[bytes], fields: dict[str, list[int]]) -> None:
        n = len(templates)
        self.lengths = np.array([len(t) for t in templates], np.int64)
        width = int(self.lengths.max()) if n else 0
        self.width = width
        self.matrix = np.zeros((n, width), _U8)
        for i, t in enumerate(templates):
            self.matrix[i, :len(t)] = np.frombuffer(t, _U8)
        self.templates = list(templates)
        self.fields = {k: np.asarray(v, np.int64) for k, v in fields.items()}
        self._at = {k: [int(a) for a in v] for k, v in fields.items()}
        #: a field at the same place in every row is written as one slice
        self.same = {k: int(v[0]) if n and (v == v[0]).all() else None
                     for k, v in self.fields.items()}
        self.uniform = n > 0 and bool((self.lengths == width).all())

    def __len__(self) -> int:
        return len(self.lengths)

    def pack(self, t_ns: int, values: dict[str, np.ndarray], rows=None) -> list[bytes]:
        """The messages of ``rows`` (indices, None: every row) stamped ``t_ns``, each field
        of ``values`` (name -> (len(rows), k) array in the field's wire dtype) written at its
        place."""
        n = len(self.lengths) if rows is None else len(rows)
        if n <= _FEW:
            return self._pack_few(t_ns, values, rows, n)
        if rows is None:
            buf = self.matrix.copy()
            lengths, fields = self.lengths, self.fields
        else:
            rows = np.asarray(rows, np.int64)
            buf = self.matrix[rows]
            lengths = self.lengths[rows]
            fields = {k: v[rows] for k, v in self.fields.items()}
        same = self.same
        buf[:, _STAMP_AT:_STAMP_AT + 8] = np.frombuffer(_STAMP.pack(*_split(t_ns)), _U8)
        for name, vals in values.items():
            raw = np.ascontiguousarray(vals).reshape(n, -1).view(_U8)
            at = same[name]
            if at is not None:
                buf[:, at:at + raw.shape[1]] = raw
            else:
                cols = fields[name][:, None] + np.arange(raw.shape[1])
                buf[np.arange(n)[:, None], cols] = raw
        data = buf.tobytes()
        w = buf.shape[1]
        if rows is None and self.uniform:
            return [data[i:i + w] for i in range(0, n * w, w)]
        return [data[i * w:i * w + m] for i, m in enumerate(lengths.tolist())]

    def _pack_few(self, t_ns: int, values: dict, rows, n: int) -> list[bytes]:
        """:meth:`pack` of a few rows, each a copy of its template written in place (numpy's
        cost per call outweighs the matrix below ``_FEW`` rows); the same bytes."""
        if n == 0:
            return []
        stamp = _STAMP.pack(*_split(t_ns))
        rows = range(n) if rows is None else [int(r) for r in rows]
        fields = [(self._at[k], np.ascontiguousarray(v).reshape(n, -1).view(_U8).tobytes())
                  for k, v in values.items()]
        out = []
        for i, r in enumerate(rows):
            buf = bytearray(self.templates[r])
            buf[_STAMP_AT:_STAMP_AT + 8] = stamp
            for at, raw in fields:
                w = len(raw) // n
                buf[at[r]:at[r] + w] = raw[i * w:(i + 1) * w]
            out.append(bytes(buf))
        return out


#: up to this many rows, :meth:`Rows.pack` writes each message's bytes on its own
_FEW = 8


def joint_state_rows(frame_ids: list[str], names: tuple[str, ...], n_pos: int,
                     n_vel: int) -> Rows:
    """:class:`Rows` of JointState messages (fields ``position``, ``velocity``: <f8, no
    effort), the bytes of :func:`joint_state`."""
    layouts = [_joint_layout(f, tuple(names), n_pos, n_vel, 0) for f in frame_ids]
    return Rows([t for t, *_ in layouts], {"position": [p for _, p, _, _ in layouts],
                                           "velocity": [v for _, _, v, _ in layouts]})


def point_stamped_rows(frame_ids: list[str]) -> Rows:
    """:class:`Rows` of PointStamped messages (field ``point``: 3 <f8), the bytes of
    :func:`point_stamped`."""
    layouts = [_point_layout(f) for f in frame_ids]
    return Rows([t for t, _ in layouts], {"point": [at for _, at in layouts]})


def odometry_rows(frame_ids: list[str], child_frame_ids: list[str]) -> Rows:
    """:class:`Rows` of Odometry messages (fields ``pose``: x, y, z, qx, qy, qz, qw and
    ``twist``: linear xyz, angular xyz, <f8; zero covariances), the bytes of
    :func:`odometry`."""
    layouts = [_odometry_layout(f, c) for f, c in zip(frame_ids, child_frame_ids)]
    return Rows([t for t, _, _ in layouts], {"pose": [p for _, p, _ in layouts],
                                             "twist": [w for _, _, w in layouts]})


def laser_scan_rows(frame_ids: list[str], num_rays: int, angle_min: float, angle_max: float,
                    angle_increment: float, scan_time: float, range_min: float,
                    range_max: float) -> Rows:
    """:class:`Rows` of LaserScan messages of one lidar (field ``ranges``: num_rays <f4; no
    intensities), the bytes of ``codec.encode(codec.laser_scan(...))``."""
    templates, at = [], []
    head = struct.pack("<7f", angle_min, angle_max, angle_increment, 0.0, scan_time,
                       range_min, range_max)
    for f in frame_ids:
        buf = bytearray(_CDR_LE)
        _header(buf, _Stamp(f))
        _pad(buf, 4)
        buf += head
        _pad(buf, 4)
        buf += _U32.pack(num_rays)
        if num_rays:
            _pad(buf, 4)
        at.append(len(buf))
        buf += bytes(4 * num_rays)
        _pad(buf, 4)
        buf += _U32.pack(0)
        templates.append(bytes(buf))
    return Rows(templates, {"ranges": at})
