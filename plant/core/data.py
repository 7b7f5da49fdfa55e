"""The core's data: what a tick changes, as arrays shaped (worlds, robots, ...).

The true state of every robot after a tick (pose as a transform, yaw, body velocities,
wheel angles and speeds, the base orientation as a quaternion), filled by
:func:`plant.core.step.observe` from each world's stepper (a kinematic world's arrays, or
DART's, which stays the owner of a dynamic world: :class:`plant.sim.Simulation`), and each
robot's noise streams.
"""
from __future__ import annotations

import numpy as np

from .model import Model


class Data:
    def __init__(self, model: Model) -> None:
        W, R = model.worlds, len(model.robots)
        #: base_link -> world, (W, R, 4, 4)
        self.tf = np.zeros((W, R, 4, 4))
        self.tf[..., [0, 1, 2, 3], [0, 1, 2, 3]] = 1.0
        self.yaw = np.zeros((W, R))                 # rad
        self.quaternion = np.zeros((W, R, 4))       # x, y, z, w
        self.quaternion[..., 3] = 1.0
        self.v = np.zeros((W, R))                   # forward speed in base_link, m/s
        self.w = np.zeros((W, R))                   # yaw rate in base_link, rad/s
        self.enc_pos = np.zeros((W, R, 2))          # wheel angles (left, right), rad
        self.enc_vel = np.zeros((W, R, 2))          # wheel speeds, rad/s
        self.tick = np.zeros(W, np.int64)           # the control tick each world is at
        #: each world's robots' noise streams ({robot: plant.sensors.RobotSensors}, whose
        #: noise models draw them: :meth:`set_streams`)
        self.streams: list[dict | None] = [None] * W
        #: per world and stream ("encoders", "gps", "lidar", "camera"): {robot index: its
        #: noise model} of the robots whose values that stream changes
        self.noisy: list[dict[str, dict[int, object]]] = [{} for _ in range(W)]
        self._names = model.robots

    def set_streams(self, w: int, sensors: dict) -> None:
        """World ``w``'s robots' noise streams (its freshly built sensors)."""
        self.streams[w] = sensors
        by = {"encoders": "enc_noise", "gps": "gps_noise", "lidar": "lidar_noise",
              "camera": "camera_noise"}
        self.noisy[w] = {k: {i: m for i, n in enumerate(self._names)
                             if (m := getattr(sensors[n], attr)) is not None}
                         for k, attr in by.items()}

    @property
    def xyz(self) -> np.ndarray:
        """(W, R, 3) base_link positions, m (a view of :attr:`tf`)."""
        return self.tf[..., :3, 3]
