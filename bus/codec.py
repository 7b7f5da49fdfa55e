"""ROS 2 messages in CDR, without ROS: build, encode and decode the bus's messages.

Every payload on the bus is a standard ROS 2 message serialised as CDR by the
``rosbags`` type store, so the same bytes go into MCAP recordings and open in
Foxglove or ROS 2 tools. Times on the bus are integer nanoseconds of simulated time.
"""
from __future__ import annotations

import math
import struct
import threading
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from rosbags.typesys.store import Typestore

from . import msgtypes
from .cdrfast import Decoders
from .keys import NAME_MAX
from .packed import (_CDR_LE, _U32, _doubles, _f64_seq, _header, _pad, _string, encode_clock,
                     encode_f64_array, encode_joint_state, encode_odometry, encode_point_stamped)


class _Table(dict):
    """A type store's table (``types`` or ``fielddefs``) that loads the full store the
    first time it is asked for a type it lacks, or for all of them."""

    def __init__(self, store: "_Store", data: dict) -> None:
        super().__init__(data)
        self._store = store

    def __missing__(self, name: str):
        self._store.load_all()
        if dict.__contains__(self, name):
            return dict.__getitem__(self, name)
        raise KeyError(name)

    def __contains__(self, name) -> bool:
        if dict.__contains__(self, name):
            return True
        self._store.load_all()
        return dict.__contains__(self, name)

    def get(self, name, default=None):
        return self[name] if name in self else default

    def __iter__(self):
        self._store.load_all()
        return dict.__iter__(self)

    def __len__(self) -> int:
        self._store.load_all()
        return dict.__len__(self)

    def keys(self):
        self._store.load_all()
        return dict.keys(self)

    def values(self):
        self._store.load_all()
        return dict.values(self)

    def items(self):
        self._store.load_all()
        return dict.items(self)


class _Store(Typestore):
    """rosbags' ROS 2 Jazzy type store, started with the bus's own types
    (:mod:`bus.msgtypes`, the same classes) and completed with the rest of Jazzy's on
    first use of another type: importing all ~460 costs ~0.2 s, a quarter of a node's
    start-up, and most processes never meet one."""

    def __init__(self) -> None:
        super().__init__(msgtypes)
        self._all = False
        self._lock = threading.Lock()      # (Zenoh's callback threads decode too)
        self.types = _Table(self, self.types)
        self.fielddefs = _Table(self, self.fielddefs)

    def load_all(self) -> None:
        """Add every Jazzy type not here yet (once; a caller meanwhile waits for it)."""
        if self._all:
            return
        with self._lock:
            if self._all:
                return
            from rosbags.typesys import Stores, get_typestore
            full = get_typestore(Stores.ROS2_JAZZY)
            for name, defs in full.fielddefs.items():
                if not dict.__contains__(self.fielddefs, name):
                    dict.__setitem__(self.types, name, full.types[name])
                    dict.__setitem__(self.fielddefs, name, defs)
            self._all = True


TYPESTORE = _Store()
T = TYPESTORE.types

_Time = T["builtin_interfaces/msg/Time"]
_Header = T["std_msgs/msg/Header"]
_Vector3 = T["geometry_msgs/msg/Vector3"]
_Point = T["geometry_msgs/msg/Point"]
_Quaternion = T["geometry_msgs/msg/Quaternion"]
_Pose = T["geometry_msgs/msg/Pose"]
_Twist = T["geometry_msgs/msg/Twist"]

#: Zenoh attachment (docs/PROTOCOL.md): sequence number, sim-time stamp (ns), both uint64
#: little-endian; then, on every message a lockstep member publishes for a tick, the
#: member trailer: flags (u8), n_plant (u16 LE), name length (u8), node name (UTF-8).
ATTACHMENT = struct.Struct("<QQ")
TRAILER = struct.Struct("<BHB")
#: the plant's attachment ends with its world's epoch: 0 for the world it started with, +1 at
#: each reset or rebuild (docs/PROTOCOL.md section 3), so a reset is told from a re-publish
EPOCH = struct.Struct("<I")
#: trailer flags: ACK = the member published everything for this tick (this is its last
#: message for it); FINAL = the member's last tick (it leaves after it); bits 2-7 the
#: *hold*: how many ticks after this one the member will not answer (docs/PROTOCOL.md
#: section 4, "Holding"; :func:`hold_of`, :func:`with_hold`)
ACK, FINAL = 1, 2
HOLD_SHIFT, HOLD_MAX = 2, 63


def hold_of(flags: int) -> int:
    """The hold in trailer ``flags``: ticks after this one the member will not answer."""
    return flags >> HOLD_SHIFT


def with_hold(flags: int, hold: int) -> int:
    """``flags`` with hold ``hold`` (0..:data:`HOLD_MAX`)."""
    if not 0 <= hold <= HOLD_MAX:
        raise ValueError(f"a hold is 0..{HOLD_MAX} ticks, got {hold}")
    return (flags & (ACK | FINAL)) | (hold << HOLD_SHIFT)

_EMPTY = np.zeros(0, dtype=np.float64)
_ZERO_COV = np.zeros(36, dtype=np.float64)


class CodecError(ValueError):
    """A payload that is not a valid message of the expected type."""


def encode(msg) -> bytes:
    """CDR bytes of a rosbags message (its type is its ``__msgtype__``).

    The messages sent every tick have hand-written encoders that produce the same
    bytes as rosbags (pinned by tests) several times faster; the rest go through rosbags.
    """
    fast = _FAST.get(msg.__msgtype__)
    if fast is not None:
        return fast(msg)
    return bytes(TYPESTORE.serialize_cdr(msg, msg.__msgtype__))


# ---------------------------------------------------------------- fast CDR (bus/packed.py)
def _fast_twist_stamped(m) -> bytes:
    buf = bytearray(_CDR_LE)
    _header(buf, m.header)
    t = m.twist
    _doubles(buf, (t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z))
    return bytes(buf)


_F32_7 = struct.Struct("<7f")
_U32_U32 = struct.Struct("<II")


def _seq(buf: bytearray, arr, dtype: str, align: int) -> None:
    """A sequence of a fixed-size type (length, then its elements aligned to ``align``)."""
    a = np.ascontiguousarray(arr, dtype=dtype).reshape(-1)
    _pad(buf, 4)
    buf += _U32.pack(a.size)
    if a.size:
        _pad(buf, align)
        buf += a.data


def _frame_start(m, name: str) -> bytearray:
    """An Image's or CameraInfo's first fields: header, height, width, then a string."""
    buf = bytearray(_CDR_LE)
    _header(buf, m.header)
    _pad(buf, 4)
    buf += _U32_U32.pack(m.height, m.width)
    _string(buf, name)
    return buf


def _fast_image(m) -> bytes:
    buf = _frame_start(m, m.encoding)
    buf += bytes((m.is_bigendian,))
    _pad(buf, 4)
    buf += _U32.pack(m.step)
    data = np.ascontiguousarray(m.data, dtype=np.uint8).reshape(-1)
    buf += _U32.pack(data.size)
    return b"".join((buf, data.data))      # the pixels copied once


def _fast_laser_scan(m) -> bytes:
    buf = bytearray(_CDR_LE)
    _header(buf, m.header)
    _pad(buf, 4)
    buf += _F32_7.pack(m.angle_min, m.angle_max, m.angle_increment, m.time_increment,
                       m.scan_time, m.range_min, m.range_max)
    _seq(buf, m.ranges, "<f4", 4)
    _seq(buf, m.intensities, "<f4", 4)
    return bytes(buf)


def _fast_camera_info(m) -> bytes:
    buf = _frame_start(m, m.distortion_model)
    _f64_seq(buf, m.d)
    for fixed, n in ((m.k, 9), (m.r, 9), (m.p, 12)):
        a = np.ascontiguousarray(fixed, dtype="<f8").reshape(-1)
        if a.size != n:
            raise ValueError(f"CameraInfo array of {a.size} values, expected {n}")
        _pad(buf, 8)
        buf += a.tobytes()
    roi = m.roi
    buf += _U32_U32.pack(m.binning_x, m.binning_y)
    buf += struct.pack("<4I?", roi.x_offset, roi.y_offset, roi.height, roi.width,
                       roi.do_rectify)
    return bytes(buf)


_FAST = {
    "rosgraph_msgs/msg/Clock": encode_clock,
    "geometry_msgs/msg/TwistStamped": _fast_twist_stamped,
    "geometry_msgs/msg/PointStamped": encode_point_stamped,
    "sensor_msgs/msg/JointState": encode_joint_state,
    "nav_msgs/msg/Odometry": encode_odometry,
    "sensor_msgs/msg/Image": _fast_image,
    "sensor_msgs/msg/LaserScan": _fast_laser_scan,
    "sensor_msgs/msg/CameraInfo": _fast_camera_info,
    "std_msgs/msg/Float64MultiArray": encode_f64_array,
}


def decode(data: bytes, msgtype: str):
    """Decode CDR bytes as ``msgtype``; raise :class:`CodecError` on any malformed input.
    The types read every tick take hand-written decoders (:mod:`bus.cdrfast`, the same
    objects); rosbags decodes the rest, and whatever those leave to it."""
    if (msg := _FAST_DECODE.decode(data, msgtype)) is not None:
        return msg
    try:
        return TYPESTORE.deserialize_cdr(memoryview(data), msgtype)
    except Exception as exc:  # rosbags raises SerdeError, struct.error, UnicodeDecodeError...
        raise CodecError(f"not a valid {msgtype}: {exc}") from None


_FAST_DECODE = Decoders(T)


class Attachment(NamedTuple):
    """A parsed attachment. ``node`` is None (and flags, n_plant 0) without a trailer."""
    seq: int
    t_ns: int
    flags: int = 0
    n_plant: int = 0
    node: str | None = None
    epoch: int | None = None     # the plant's attachment only


def attachment(seq: int, t_ns: int, flags: int = 0, n_plant: int = 0,
               node: str | None = None, epoch: int | None = None) -> bytes:
    """Attachment bytes: ``seq``, ``t_ns`` and, for a lockstep member (``node`` given), the
    trailer with ``flags`` (:data:`ACK`, :data:`FINAL`) and ``n_plant``; for the plant
    (``epoch`` given), its world's epoch."""
    head = ATTACHMENT.pack(seq & 0xFFFFFFFFFFFFFFFF, t_ns)
    if node is None:
        return head if epoch is None else head + EPOCH.pack(epoch & 0xFFFFFFFF)
    name = node.encode("utf-8")
    return head + TRAILER.pack(flags, n_plant, len(name)) + name


def attachment_parsed(seq: int, t_ns: int, flags: int = 0, n_plant: int = 0,
                      node: str | None = None) -> tuple[bytes, Attachment | None]:
    """A member's :func:`attachment` bytes and the :class:`Attachment`
    :func:`parse_attachment` reads from them, built from the values rather than parsed back
    (a composed member hands both to the plant)."""
    return attachments_parsed(seq - 1, t_ns, [(flags, n_plant)], node)[0]


def attachments_parsed(seq: int, t_ns: int, marks: list[tuple[int, int]],
                       node: str | None = None) -> list[tuple[bytes, Attachment | None]]:
    """:func:`attachment_parsed` of each ``(flags, n_plant)`` of ``marks``, numbered from
    ``seq`` + 1 (a member's answer to a tick): the name's bytes and each trailer made once."""
    mask, head = 0xFFFFFFFFFFFFFFFF, ATTACHMENT.pack
    if node is None:
        return [(head(s, t_ns), Attachment(s, t_ns))
                for s in ((seq + i) & mask for i in range(1, len(marks) + 1))]
    name = node.encode("utf-8")
    named = 0 < len(name) <= NAME_MAX
    make = tuple.__new__       # (an Attachment made as a plain tuple: half its __new__'s cost)
    tails: dict[tuple[int, int], bytes] = {}
    out = []
    for i, (flags, n_plant) in enumerate(marks, 1):
        tail = tails.get((flags, n_plant))
        if tail is None:
            tail = tails[(flags, n_plant)] = TRAILER.pack(flags, n_plant, len(name)) + name
        s = (seq + i) & mask
        att = head(s, t_ns) + tail
        if named and not (flags & FINAL and hold_of(flags)):
            out.append((att, make(Attachment, (s, t_ns, flags, n_plant, node, None))))
        else:
            out.append((att, parse_attachment(att)))     # (what parsing makes of a bad one)
    return out


def parse_attachment(data: bytes | None) -> Attachment | None:
    """The :class:`Attachment` in ``data`` (plain: 16 bytes; the plant's: 20, with the epoch;
    a member's: 21 and more, with the trailer), or None if absent or malformed (wrong length,
    a hold with FINAL, a name that is not UTF-8 or not as long as it says)."""
    if data is None or len(data) < ATTACHMENT.size:
        return None
    seq, t_ns = ATTACHMENT.unpack_from(data)
    if len(data) == ATTACHMENT.size:
        return Attachment(seq, t_ns)
    if len(data) == ATTACHMENT.size + EPOCH.size:          # (a trailer is longer)
        return Attachment(seq, t_ns, epoch=EPOCH.unpack_from(data, ATTACHMENT.size)[0])
    if len(data) < ATTACHMENT.size + TRAILER.size:
        return None
    flags, n_plant, n = TRAILER.unpack_from(data, ATTACHMENT.size)
    name = data[ATTACHMENT.size + TRAILER.size:]
    if (flags & FINAL and hold_of(flags)) or len(name) != n or not 0 < n <= NAME_MAX:
        return None
    try:
        return Attachment(seq, t_ns, flags, n_plant, name.decode("utf-8"))
    except UnicodeDecodeError:
        return None


# ---------------------------------------------------------------- time
def time_msg(t_ns: int):
    return _Time(sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))


def stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def header(t_ns: int, frame_id: str = ""):
    return _Header(stamp=time_msg(t_ns), frame_id=frame_id)


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """The rotation by ``yaw`` about z as a quaternion (x, y, z, w)."""
    return 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def yaw_to_quaternion(yaw: float):
    x, y, z, w = yaw_quaternion(yaw)
    return _Quaternion(x=x, y=y, z=z, w=w)


def quaternion_to_yaw(q) -> float:
    return yaw_of(q.x, q.y, q.z, q.w)


def yaw_of(x: float, y: float, z: float, w: float) -> float:
    """The yaw (rad) of the quaternion (x, y, z, w): :func:`quaternion_to_yaw` of floats."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def pose_2d(odometry) -> tuple[float, float, float]:
    """(x, y, yaw) of a nav_msgs/Odometry's pose (``odom``, ``ground_truth``)."""
    p = odometry.pose.pose
    return p.position.x, p.position.y, quaternion_to_yaw(p.orientation)


# ---------------------------------------------------------------- message builders
def clock(t_ns: int):
    return T["rosgraph_msgs/msg/Clock"](clock=time_msg(t_ns))


def twist_stamped(t_ns: int, linear_mps: float, angular_radps: float, frame_id: str = "base_link"):
    return T["geometry_msgs/msg/TwistStamped"](
        header=header(t_ns, frame_id),
        twist=_Twist(linear=_Vector3(x=float(linear_mps), y=0.0, z=0.0),
                     angular=_Vector3(x=0.0, y=0.0, z=float(angular_radps))))


@lru_cache(maxsize=64)
def _twist_layout(frame_id: str) -> tuple[struct.Struct, bytes]:
    buf = bytearray(_CDR_LE + bytes(8))
    _string(buf, frame_id)
    _pad(buf, 8)
    frame = bytes(buf[12:])        # the frame id's length, text, NUL and padding
    return struct.Struct(f"<4siI{len(frame)}s6d"), frame


def twist_stamped_bytes(t_ns: int, linear_mps: float, angular_radps: float,
                        frame_id: str = "base_link") -> bytes:
    """``encode(twist_stamped(...))``'s bytes in one pack (a member sends one per robot
    per tick)."""
    layout, frame = _twist_layout(frame_id)
    return layout.pack(_CDR_LE, int(t_ns // 1_000_000_000), int(t_ns % 1_000_000_000), frame,
                       float(linear_mps), 0.0, 0.0, 0.0, 0.0, float(angular_radps))


def joint_state(t_ns: int, names, position=(), velocity=(), effort=()):
    return T["sensor_msgs/msg/JointState"](
        header=header(t_ns),
        name=list(names),
        position=np.asarray(position, dtype=np.float64),
        velocity=np.asarray(velocity, dtype=np.float64),
        effort=np.asarray(effort, dtype=np.float64))


def point_stamped(t_ns: int, x: float, y: float, z: float, frame_id: str = "world"):
    return T["geometry_msgs/msg/PointStamped"](
        header=header(t_ns, frame_id), point=_Point(x=float(x), y=float(y), z=float(z)))


def odometry(t_ns: int, x: float, y: float, yaw: float, linear_mps: float, angular_radps: float,
             frame_id: str = "odom", child_frame_id: str = "base_link", z: float = 0.0,
             quaternion=None):
    """nav_msgs/Odometry of a planar pose (or a full orientation if ``quaternion`` is given)."""
    q = yaw_to_quaternion(yaw) if quaternion is None else _Quaternion(
        x=float(quaternion[0]), y=float(quaternion[1]), z=float(quaternion[2]), w=float(quaternion[3]))
    PoseWC = T["geometry_msgs/msg/PoseWithCovariance"]
    TwistWC = T["geometry_msgs/msg/TwistWithCovariance"]
    return T["nav_msgs/msg/Odometry"](
        header=header(t_ns, frame_id),
        child_frame_id=child_frame_id,
        pose=PoseWC(pose=_Pose(position=_Point(x=float(x), y=float(y), z=float(z)), orientation=q),
                    covariance=_ZERO_COV),
        twist=TwistWC(twist=_Twist(linear=_Vector3(x=float(linear_mps), y=0.0, z=0.0),
                                   angular=_Vector3(x=0.0, y=0.0, z=float(angular_radps))),
                      covariance=_ZERO_COV))


def laser_scan(t_ns: int, angle_min: float, angle_max: float, angle_increment: float,
               scan_time: float, range_min: float, range_max: float, ranges, frame_id="laser"):
    """sensor_msgs/LaserScan; ranges in m, ``inf`` where nothing was hit."""
    return T["sensor_msgs/msg/LaserScan"](
        header=header(t_ns, frame_id), angle_min=float(angle_min), angle_max=float(angle_max),
        angle_increment=float(angle_increment), time_increment=0.0, scan_time=float(scan_time),
        range_min=float(range_min), range_max=float(range_max),
        ranges=np.asarray(ranges, dtype=np.float32), intensities=np.zeros(0, dtype=np.float32))


def image(t_ns: int, rgb: np.ndarray, frame_id: str = "camera"):
    """sensor_msgs/Image, rgb8, from an (H, W, 3) uint8 array."""
    h, w = rgb.shape[:2]
    return T["sensor_msgs/msg/Image"](
        header=header(t_ns, frame_id), height=h, width=w, encoding="rgb8", is_bigendian=0,
        step=3 * w, data=np.ascontiguousarray(rgb, dtype=np.uint8).reshape(-1))


def image_to_array(msg) -> np.ndarray:
    """An rgb8 Image message as an (H, W, 3) uint8 array (raises ValueError otherwise)."""
    if msg.encoding != "rgb8":
        raise ValueError(f"expected an rgb8 image, got {msg.encoding!r}")
    data = np.asarray(msg.data, dtype=np.uint8)
    if data.size != msg.height * msg.width * 3 or msg.step != 3 * msg.width:
        raise ValueError(f"image data of {data.size} bytes does not fit "
                         f"{msg.width}x{msg.height} rgb8 (step {msg.step})")
    return data.reshape(msg.height, msg.width, 3)


def camera_info(t_ns: int, width: int, height: int, distortion_model: str, d, k, r, p,
                frame_id: str = "camera"):
    """sensor_msgs/CameraInfo (K, D in OpenCV's convention; P = [K | 0])."""
    RoI = T["sensor_msgs/msg/RegionOfInterest"]
    f64 = lambda a: np.asarray(a, dtype=np.float64)  # noqa: E731
    return T["sensor_msgs/msg/CameraInfo"](
        header=header(t_ns, frame_id), height=int(height), width=int(width),
        distortion_model=distortion_model, d=f64(d), k=f64(k), r=f64(r), p=f64(p),
        binning_x=0, binning_y=0,
        roi=RoI(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))


def msg_stamp_ns(msg) -> int | None:
    """Sim-time stamp of a message in ns (header stamp, the clock of a Clock, or the first
    transform's of a TFMessage: ``sim/poses`` stamps them all with the tick)."""
    h = getattr(msg, "header", None)
    if h is not None:
        return stamp_ns(h.stamp)
    transforms = getattr(msg, "transforms", None)
    if transforms:
        return stamp_ns(transforms[0].header.stamp)
    c = getattr(msg, "clock", None)
    return stamp_ns(c) if c is not None else None


def summarize(msg, max_items: int = 6):
    """A readable nested dict of a message with large arrays summarised."""
    if isinstance(msg, np.ndarray):
        if msg.size <= max_items:
            return msg.tolist()
        return f"<{msg.dtype}[{msg.size}] min={np.nanmin(msg):.4g} max={np.nanmax(msg):.4g}>" \
            if msg.dtype.kind == "f" else f"<{msg.dtype}[{msg.size}]>"
    if isinstance(msg, list):
        if len(msg) > max_items:
            return [summarize(m) for m in msg[:max_items]] + [f"... {len(msg)} items"]
        return [summarize(m) for m in msg]
    if hasattr(msg, "__dataclass_fields__"):
        return {k: summarize(getattr(msg, k)) for k in msg.__dataclass_fields__ if k != "__msgtype__"}
    return msg
