"""The tick's sensor values handed to the members composed into the plant's process.

A composed member reads the plant's sensors as a process member does, as messages, but it
need not decode them from the bytes the plant publishes: where the core keeps a topic's
values as the wire carries them, the message is made from those values, field for field
the object :func:`bus.codec.decode` gives of the bytes (the same Python types; float32
fields rounded to float32 as the CDR encoding rounds them; arrays read-only, as a decoded
message's views of its payload are). The bytes are still made for whoever else reads them
(bus subscribers, recorders), so what a member sees is the same wherever it runs.

Today that is the lidars' LaserScan: its ranges are the core's float32 rows of the tick
(:attr:`plant.core.data.Data.ranges`), its other fields the lidar's constants; and the
per-tick ``joint_states``, ``gps`` and ``ground_truth``: their values are the float64s the
core's sensing kernel wrote for the tick (noise drawn) into its message buffer
(:class:`plant.core.outgoing.Outgoing`), read at their places, the other fields those of
the robot's template (frame id, joint names). Topics without such values go to the member
as bytes, decoded as before.
"""
from __future__ import annotations

import struct
from typing import Callable

import numpy as np

from bus import codec, made

from .core.data import Data
from .core.model import Model

_F7 = struct.Struct("<7f")
_STAMP = struct.Struct("<iI")        # a message's header stamp, after the 4-byte encapsulation
_D3, _D6, _D7 = (struct.Struct(f"<{n}d") for n in (3, 6, 7))
_JOINTS_T = "sensor_msgs/msg/JointState"
_EMPTY32 = np.zeros(0, np.float32)     # a LaserScan's intensities (none), read-only: shared
_EMPTY32.flags.writeable = False
_GPS_T = "geometry_msgs/msg/PointStamped"
_TRUTH_T = "nav_msgs/msg/Odometry"
#: a message type's class, built positionally as the decoder builds it (bus/cdrfast.py)
_TIME = codec.T["builtin_interfaces/msg/Time"]
_HEADER = codec.T["std_msgs/msg/Header"]
_SCAN = codec.T["sensor_msgs/msg/LaserScan"]


def scan_head(cfg) -> tuple[float, ...]:
    """A lidar's LaserScan fields angle_min .. range_max as the wire carries them: float32,
    each read back as the Python float a decoder gives."""
    return _F7.unpack(_F7.pack(cfg.angle_min, cfg.angle_max, cfg.angle_increment, 0.0,
                               1.0 / cfg.rate_hz, cfg.min_range_m, cfg.max_range_m))


class Handover:
    """World ``w``'s messages of a tick made from the core's values (module docstring):
    :meth:`at` gives, for the tick just sensed, a function (robot, topic) -> the message,
    or None where the core keeps no values of that topic (the member decodes its bytes)."""

    def __init__(self, model: Model, data: Data, w: int = 0) -> None:
        self.model, self.data, self.w = model, data, w
        self._heads = {cfg: scan_head(cfg) for cfg in model.lidar_groups}
        self._index = model.index
        self._laser = model.frames["laser"]
        #: (the world's message buffer, each robot's joint_states (frame id, names, places of
        #: position and velocity, their length in bytes), gps (frame id, place) and
        #: ground_truth (frame ids, places of pose and twist)), made once the core has
        #: sensed: :meth:`_per_tick`
        self._rows: tuple | None = None

    @classmethod
    def of(cls, kept: "Handover | None", model: Model, data: Data) -> "Handover":
        """``kept`` if it is of world 0 of ``model`` and ``data``, else a new one."""
        if kept is not None and kept.model is model and kept.data is data:
            return kept
        return cls(model, data)

    def at(self, t_ns: int) -> Callable[[str, str], object]:
        """The messages of tick ``t_ns`` (sensed already: :func:`plant.core.step.sense`)."""
        tick, kept = self.data.ranges[self.w]
        if not kept or tick != t_ns // self.model.tick_ns:
            kept = ()
        for _, _, ranges in kept:
            ranges.flags.writeable = False        # (a member's must not change the tick's)
        rows: dict[int, tuple] = {}               # (filled when a scan is first asked for)
        index, laser = self._index, self._laser
        sec, nanosec = divmod(t_ns, 1_000_000_000)
        empty = _EMPTY32
        per_tick = self._per_tick(sec, nanosec)

        def message(robot: str, topic: str):
            if topic != "scan":
                return per_tick(index.get(robot), topic) if per_tick is not None else None
            i = index.get(robot)
            if not rows and kept:
                for cfg, robots, ranges in kept:
                    head = self._heads[cfg]
                    rows.update((j, (head, r)) for j, r in zip(robots.tolist(), ranges))
            got = rows.get(i)
            if got is None:
                return None
            head, ranges = got
            return _SCAN(_HEADER(_TIME(sec, nanosec), laser[i]), *head, ranges, empty)
        return message

    def scan_rows(self, t_ns: int) -> list[tuple]:
        """The lidars' scans of tick ``t_ns`` as arrays, if sensed at ``t_ns`` (else []): per
        lidar model, (its LaserScan's fields angle_min .. range_max as a decoder reads them,
        the robots' indices, their float32 ranges (rows, rays), read-only)."""
        tick, kept = self.data.ranges[self.w]
        if not kept or tick != t_ns // self.model.tick_ns:
            return []
        for _, _, ranges in kept:
            ranges.flags.writeable = False    # (a member's must not change the tick's)
        return [(self._heads[cfg], robots, ranges) for cfg, robots, ranges in kept]

    def _per_tick(self, sec: int, nanosec: int) -> Callable[[int | None, str], object] | None:
        """(robot index, topic) -> the tick's ``joint_states``, ``gps`` or ``ground_truth`` of
        that robot from the core's message buffer, None where the buffer does not hold it
        (not sensed for this stamp: the member decodes the bytes); None before the core has
        a buffer."""
        out = self.data.outgoing[self.w]
        if out is None:
            return None
        if self._rows is None or self._rows[0] is not out:
            self._rows = (out, *_templates(out))
        _, joints, gps, truth = self._rows
        buf, read, stamp = out.buffer, out.read, (sec, nanosec)
        unpack = _STAMP.unpack_from
        frombuffer, f8 = np.frombuffer, np.float64

        def message(i: int | None, topic: str):
            if topic == "joint_states":
                got = joints[i] if i is not None and read[i, 0] else None
                if got is None or unpack(buf, got[0]) != stamp:
                    return None
                _, frame, names, p, v, n = got
                return made.joint_state(sec, nanosec, frame, names,
                                        frombuffer(buf[p:p + n].tobytes(), f8),
                                        frombuffer(buf[v:v + n].tobytes(), f8))
            if topic == "gps":
                got = gps[i] if i is not None and read[i, 1] else None
                if got is None or unpack(buf, got[0]) != stamp:
                    return None
                return made.point_stamped(sec, nanosec, got[1], *_D3.unpack_from(buf, got[2]))
            if topic == "ground_truth":
                got = truth[i] if i is not None and read[i, 2] else None
                if got is None or unpack(buf, got[0]) != stamp:
                    return None
                _, frame, child, p, v = got
                return made.odometry_of(sec, nanosec, frame, child, _D7.unpack_from(buf, p),
                                        frombuffer(buf[p + 56:p + 344].tobytes(), f8),
                                        _D6.unpack_from(buf, v),
                                        frombuffer(buf[v + 48:v + 336].tobytes(), f8))
            return None
        return message


def _templates(out) -> tuple[list, list, list]:
    """Each robot's joint_states, gps and ground_truth in ``out``'s buffer: the fields that
    do not change (decoded from its template) and the places of its values and stamp."""
    layout = out.layout
    joints, gps, truth = [], [], []
    for i, at in enumerate(layout.places):
        a, b = layout.spans[3 * i]
        js = codec.decode(layout.buffer[a:b].tobytes(), _JOINTS_T)
        n = 8 * len(js.position)
        joints.append(None if len(js.velocity) * 8 != n or js.effort.size else
                      (at[0] + 4, js.header.frame_id, tuple(js.name), at[1], at[2], n))
        a, b = layout.spans[3 * i + 1]
        pt = codec.decode(layout.buffer[a:b].tobytes(), _GPS_T)
        gps.append((at[3] + 4, pt.header.frame_id, at[4]))
        a, b = layout.spans[3 * i + 2]
        od = codec.decode(layout.buffer[a:b].tobytes(), _TRUTH_T)
        truth.append((at[5] + 4, od.header.frame_id, od.child_frame_id, at[6], at[7]))
    return joints, gps, truth
