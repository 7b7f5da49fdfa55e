"""The tick's camera messages handed to the members composed into the plant's process.

:mod:`plant.handover` hands a composed member the tick's LaserScans as values; this adds the
cameras' ``camera/image_raw`` and ``camera/camera_info``. The Image is made of the picture
the camera kernel drew this tick (:attr:`plant.core.data.Data.images`), the CameraInfo of
the camera's constant fields: field for field the object :func:`bus.codec.decode` gives of
the bytes the plant publishes (the same Python types, the pixels' bytes, the matrices'
float64 values, arrays read-only as a decoded message's views of its payload are). A
follower composed into the plant thus skips decoding its camera's two messages every frame
(~25 us of a 160x120 frame's); the bytes are still made for whoever else reads them.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from bus import codec

from .core.data import Data
from .core.model import Model
from .handover import Handover

_TIME = codec.T["builtin_interfaces/msg/Time"]
_HEADER = codec.T["std_msgs/msg/Header"]
_IMAGE = codec.T["sensor_msgs/msg/Image"]
_INFO = codec.T["sensor_msgs/msg/CameraInfo"]
_ROI = codec.T["sensor_msgs/msg/RegionOfInterest"]


def _frozen(values) -> np.ndarray:
    a = np.array(values, dtype=np.float64).reshape(-1)
    a.flags.writeable = False
    return a


def info_fields(fields: dict) -> tuple:
    """A camera's CameraInfo fields after the header, as decoding gives them
    (:func:`bus.codec.camera_info`'s ``fields``: :func:`plant.camera.camera_info`)."""
    return (int(fields["height"]), int(fields["width"]), str(fields["distortion_model"]),
            *(_frozen(fields[k]) for k in ("d", "k", "r", "p")), 0, 0, _ROI(0, 0, 0, 0, False))


class CameraHandover(Handover):
    """:class:`plant.handover.Handover` with the cameras' messages (module docstring)."""

    def __init__(self, model: Model, data: Data, w: int = 0) -> None:
        super().__init__(model, data, w)
        self._info = {i: info_fields(f) for i, f in enumerate(model.camera_info)
                      if f is not None}
        self._optical = model.frames["camera_optical"]

    def at(self, t_ns: int) -> Callable[[str, str], object]:
        """The messages of tick ``t_ns`` (sensed already: :func:`plant.core.step.sense`)."""
        scans = super().at(t_ns)
        tick, pictures = self.data.images[self.w]
        if tick != t_ns // self.model.tick_ns:
            pictures = {}
        index, optical, infos = self._index, self._optical, self._info
        sec, nanosec = divmod(t_ns, 1_000_000_000)

        def message(robot: str, topic: str):
            if topic == "camera/image_raw":
                rgb = pictures.get(index.get(robot))
                if rgb is None:
                    return None
                pixels = rgb.reshape(-1)
                pixels.flags.writeable = False    # (a member's must not change the tick's)
                h, w = rgb.shape[:2]
                return _IMAGE(_HEADER(_TIME(sec, nanosec), optical[index[robot]]), h, w,
                              "rgb8", 0, 3 * w, pixels)
            if topic == "camera/camera_info":
                i = index.get(robot)             # (asked for a due one: only its stamp varies)
                if i not in infos:
                    return None
                return _INFO(_HEADER(_TIME(sec, nanosec), optical[i]), *infos[i])
            return scans(robot, topic)
        return message
