"""The tick's sensor values handed to the members composed into the plant's process.

A composed member reads the plant's sensors as a process member does, as messages, but it
need not decode them from the bytes the plant publishes: where the core keeps a topic's
values as the wire carries them, the message is made from those values, field for field
the object :func:`bus.codec.decode` gives of the bytes (the same Python types; float32
fields rounded to float32 as the CDR encoding rounds them; arrays read-only, as a decoded
message's views of its payload are). The bytes are still made for whoever else reads them
(bus subscribers, recorders), so what a member sees is the same wherever it runs.

Today that is the lidars' LaserScan: its ranges are the core's float32 rows of the tick
(:attr:`plant.core.data.Data.ranges`), its other fields the lidar's constants. Topics
without such values go to the member as bytes, decoded as before.
"""
from __future__ import annotations

import struct
from typing import Callable

import numpy as np

from bus import codec

from .core.data import Data
from .core.model import Model

_F7 = struct.Struct("<7f")
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

    @classmethod
    def of(cls, kept: "Handover | None", model: Model, data: Data) -> "Handover":
        """``kept`` if it is of world 0 of ``model`` and ``data``, else a new one."""
        if kept is not None and kept.model is model and kept.data is data:
            return kept
        return cls(model, data)

    def at(self, t_ns: int) -> Callable[[str, str], object]:
        """The messages of tick ``t_ns`` (sensed already: :func:`plant.core.step.sense`)."""
        tick, kept = self.data.ranges[self.w]
        rows: dict[int, tuple] = {}
        if kept and tick == t_ns // self.model.tick_ns:
            for cfg, robots, ranges in kept:
                ranges.flags.writeable = False    # (a member's must not change the tick's)
                head = self._heads[cfg]
                rows.update((i, (head, r)) for i, r in zip(robots.tolist(), ranges))
        index, laser = self._index, self._laser
        sec, nanosec = divmod(t_ns, 1_000_000_000)
        empty = np.zeros(0, np.float32)
        empty.flags.writeable = False

        def message(robot: str, topic: str):
            if topic != "scan":
                return None
            i = index.get(robot)
            got = rows.get(i)
            if got is None:
                return None
            head, ranges = got
            return _SCAN(_HEADER(_TIME(sec, nanosec), laser[i]), *head, ranges, empty)
        return message
