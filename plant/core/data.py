"""The core's data: what a tick changes, as arrays shaped (worlds, robots, ...).

The true state of every robot after a tick (pose as a transform, yaw, body velocities,
wheel angles and speeds, the base orientation as a quaternion), filled by
:func:`plant.core.step.observe` from each world's stepper (a kinematic world's arrays, or
DART's, which stays the owner of a dynamic world: :class:`plant.sim.Simulation`), and each
robot's noise streams (a key and a law each: a reading's noise is a function of the key and
the tick, :mod:`plant.noise`).
"""
from __future__ import annotations

import numpy as np

from .drive import state_arrays
from .model import Model

#: the per-tick noise streams, and the attribute of a robot's sensors holding its model
_STREAMS = {"encoders": "enc_noise", "gps": "gps_noise", "lidar": "lidar_noise"}


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
        self.steps = np.zeros(W, np.int64)          # physics steps each world has made
        self.t_ns = np.zeros(W, np.int64)           # each world's time, ns (steps x step)
        #: each world's robots' sensors (:class:`plant.sensors.RobotSensors`, the camera's
        #: noise model among them), set by :meth:`set_streams`
        self.streams: list[dict | None] = [None] * W
        #: each per-tick noise stream's key per robot (:func:`plant.noise.stream_key` of the
        #: world's seed, uint64 (W, R); its law is the model's), so a tick's draws of every
        #: robot are one call
        self.keys = {k: np.zeros((W, R), np.uint64) for k in _STREAMS}
        self._names = model.robots
        #: the front half's state (:func:`plant.core.drive.state_arrays`: the limiters' v, w
        #: and wheels, the commands' kind and values, the targets, the motion noise's keys),
        #: and each world's view of its rows (:func:`plant.core.drive.world_drive`)
        self.drive = state_arrays(W, R)
        self.drives: list = [None] * W
        #: each robot's dead reckoning from its encoders (:func:`odometry_arrays`), where a
        #: host runs it for the robot's controller (a batched environment's observers)
        self.odometry = odometry_arrays(W, R)
        #: each world's message buffer and kernel calls (:mod:`plant.core.outgoing`), made
        #: when first sensed, and their layout (the same for every world)
        self.outgoing: list = [None] * W
        self.layout = None
        #: ``sim/poses``' encoder (:class:`plant.core.outgoing.Poses`), made when first asked
        self.poses = None
        #: each world's lidar ranges of its last sensed tick as the wire carries them: (tick,
        #: [(lidar config, robot indices, float32 (rows, rays))]) (plant.handover)
        self.ranges: list[tuple] = [(-1, [])] * W
        #: each world's camera pictures of its last sensed tick, noisy, as the Image
        #: messages carry them: (tick, {robot index: uint8 (H, W, 3)}) (plant.camera_handover)
        self.images: list[tuple] = [(-1, {})] * W

    def set_streams(self, w: int, sensors: dict) -> None:
        """World ``w``'s robots' sensors (freshly built: their noise keys follow the seed)."""
        self.streams[w] = sensors
        for k, attr in _STREAMS.items():
            self.keys[k][w] = [0 if (m := getattr(sensors[n], attr)) is None else m.key
                               for n in self._names]

    def flat(self, group: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``group``'s (W, R, ...) arrays (:attr:`drive`, :attr:`odometry`, :attr:`keys`) as
        views of a row per robot, world after world (W * R, ...): what a kernel that walks
        every robot of every world reads."""
        return {k: a.reshape((-1,) + a.shape[2:]) for k, a in group.items()}

    @property
    def xyz(self) -> np.ndarray:
        """(W, R, 3) base_link positions, m (a view of :attr:`tf`)."""
        return self.tf[..., :3, 3]


def odometry_arrays(worlds: int, robots: int) -> dict[str, np.ndarray]:
    """The dead reckoning's state of ``worlds`` worlds of ``robots`` robots
    (:class:`controllers.odometry.Odometry`'s, robot by robot; plant/kernels/drive.c's
    plant_odometry steps them all), at rest."""
    W, R = worlds, robots
    return {"pose": np.zeros((W, R, 3)),       # x m, y m, theta rad (its start's frame)
            "vel": np.zeros((W, R, 2)),        # v m/s, w rad/s of the last update
            "last": np.zeros((W, R, 2)),       # the encoders' angles it last read, rad
            "last_t": np.zeros((W, R)),        # and their time, s
            "r": np.zeros((W, R)),             # the wheel radius it assumes, m
            "d": np.zeros((W, R))}             # the wheel separation it assumes, m
