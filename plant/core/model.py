"""The core's model: what does not change during a run, built once from the world files.

W worlds with the same robots (one world for the plant; a batched environment's copies),
each robot's drive parameters (its limits and motion noise: :mod:`plant.core.drive`), its sensors (which topics, their periods in control ticks,
the lidar and camera configurations, the noise laws as arrays) and the byte layouts of its
per-tick messages (:class:`bus.packed.Rows`: the frame ids are fixed, so each message is a
template with its values' places known).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from bus import packed
from bus.keys import WORLD_FRAME, frame

from ..camera import camera_info
from ..lidar import LidarConfig
from ..noise import NoiseConfig
from ..sensors import JOINTS, period_ticks
from ..world import WorldSpec
from .drive import limits_of, motion_std

#: the per-tick topics every robot publishes, in the plant's order
EVERY_TICK = ("joint_states", "gps", "ground_truth")
#: the noise streams of a robot's per-tick values, and the topic of each
NOISE_STREAMS = ("encoders", "gps", "lidar")


def noise_law(cfg: NoiseConfig) -> tuple[float, float, float, float]:
    """A stream's noise law as the kernels read it: (std, mean, bias, resolution)."""
    return (cfg.std, cfg.mean, cfg.bias, cfg.resolution)


class Model:
    """W copies of one world's robots and sensors (``specs``: one :class:`WorldSpec` per
    world, the same robots in the same order). Read-only after construction."""

    def __init__(self, specs: Sequence[WorldSpec]) -> None:
        if not specs:
            raise ValueError("a model needs at least one world")
        first = specs[0]
        names = tuple(r.name for r in first.robots)
        for s in specs[1:]:
            if tuple(r.name for r in s.robots) != names or s.tick_ns != first.tick_ns:
                raise ValueError("a model's worlds must be copies of one world (the same "
                                 "robots, the same control tick)")
        self.worlds = len(specs)
        self.robots = names
        self.index = {n: i for i, n in enumerate(names)}
        self.tick_ns = first.tick_ns
        self.tick_s = first.control_tick_s
        self.kinematic = first.mode == "kinematic"
        robots = first.robots
        self.wheel_radius_m = np.array([r.drive.wheel_radius_m for r in robots], float)
        self.wheel_separation_m = np.array([r.drive.wheel_separation_m for r in robots], float)
        #: each robot's drive limits (R, 8) and motion noise std (R,) (plant.core.drive)
        self.drive_limits = limits_of(robots, self.tick_s)
        self.motion_std = motion_std(robots)
        sens = [r.sensors for r in robots]
        self.lidars: tuple[LidarConfig | None, ...] = tuple(s.lidar for s in sens)
        self.cameras = tuple(s.camera for s in sens)
        #: each robot's topics in publishing order (as plant.sensors.RobotSensors has them)
        #: and each topic's period in ticks, 0 where a robot has no such sensor
        self.topics: tuple[tuple[str, ...], ...] = tuple(
            EVERY_TICK + (("scan",) if s.lidar else ())
            + (("camera/image_raw", "camera/camera_info") if s.camera else ()) for s in sens)
        R = len(names)
        self.periods = {t: np.ones(R, np.int64) for t in EVERY_TICK}
        self.periods["scan"] = np.array(
            [period_ticks(s.lidar.rate_hz, self.tick_s) if s.lidar else 0 for s in sens], np.int64)
        cam = np.array([period_ticks(s.camera.rate_hz, self.tick_s) if s.camera else 0
                        for s in sens], np.int64)
        self.periods["camera/image_raw"] = cam
        self.periods["camera/camera_info"] = cam.copy()
        for p in self.periods.values():
            p.flags.writeable = False
        self._periods = sorted({int(p) for v in self.periods.values() for p in v if p > 0})
        self._due: dict[tuple, dict[str, np.ndarray]] = {}
        #: (robot index, name, topic, period) of every robot's topics in publishing order
        self.order = tuple((i, n, t, int(self.periods[t][i]))
                           for i, n in enumerate(names) for t in self.topics[i])
        #: noise laws (std, mean, bias, resolution) per robot and stream, (R, 4)
        laws = {"encoders": [noise_law(s.encoder_noise) for s in sens],
                "gps": [noise_law(s.gps_noise) for s in sens],
                "lidar": [noise_law(s.lidar_noise) if s.lidar else (0, 0, 0, 0) for s in sens]}
        self.noise = {k: np.array(v, float).reshape(R, 4) for k, v in laws.items()}
        #: which robots each stream changes (a noise model exists: not all zero)
        self.noisy = {k: ~((v[:, 0] == 0) & (v[:, 1] == 0) & (v[:, 2] == 0) & (v[:, 3] == 0))
                      for k, v in self.noise.items()}
        self.noisy["lidar"] &= np.array([c is not None for c in self.lidars], bool)
        self.any_noise = {k: bool(v.any()) for k, v in self.noisy.items()}
        #: robots carrying the same lidar, cast together: {config: robot indices}
        groups: dict[LidarConfig, list[int]] = {}
        for i, c in enumerate(self.lidars):
            if c is not None:
                groups.setdefault(c, []).append(i)
        self.lidar_groups = {c: np.array(ix, np.int64) for c, ix in groups.items()}
        #: each camera's CameraInfo fields (plant.camera.camera_info), None without one
        self.camera_info = tuple(camera_info(c) if c is not None else None
                                 for c in self.cameras)
        self.frames = {f: [frame(n, f) for n in names]
                       for f in ("base_link", "laser", "camera_optical")}
        self.joint_rows = packed.joint_state_rows([""] * R, JOINTS, 2, 2)
        self.gps_rows = packed.point_stamped_rows([WORLD_FRAME] * R)
        self.odom_rows = packed.odometry_rows([WORLD_FRAME] * R, self.frames["base_link"])
        self.scan_rows = {c: packed.laser_scan_rows(
            [self.frames["laser"][i] for i in ix], c.num_rays, c.angle_min, c.angle_max,
            c.angle_increment, 1.0 / c.rate_hz, c.min_range_m, c.max_range_m)
            for c, ix in self.lidar_groups.items()}

    def due(self, tick: int) -> tuple[dict[str, np.ndarray], dict[str, list[int]]]:
        """Which robots' topics are due at ``tick``: (topic -> (R,) bool, read-only; topic ->
        the robots' indices, for the topics due somewhere). Kept for each phase of the
        sensors' periods met (a tick's are those of an earlier tick with the same phases)."""
        key = tuple(tick % p for p in self._periods)
        got = self._due.get(key)
        if got is None:
            if len(self._due) >= 1024:
                self._due.clear()
            masks = {t: _frozen((p > 0) & (tick % np.maximum(p, 1) == 0))
                     for t, p in self.periods.items()}
            rows = {t: np.flatnonzero(m).tolist() for t, m in masks.items() if m.any()}
            got = self._due[key] = (masks, rows)
        return got


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a
