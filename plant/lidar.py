"""Planar scanning lidar modelled on the SICK LMS 291 (as Webots simulates it).

Geometry
--------
* The sensor frame is the robot frame convention (x forward, y left, z up); the scan
  plane is the sensor's x-y plane. The sensor sits on the robot at the mount pose
  (``mount_x_m, mount_y_m, mount_z_m, mount_yaw_rad``) relative to the robot base,
  so the scan tilts with the robot if the robot tilts.
* Ray ``i`` points at ``angle_min + i * angle_increment`` (counter-clockwise from
  the sensor's x axis), ``angle_min = -fov/2``, ``angle_increment = fov/(n-1)``: both
  ends of the field of view are included (the LMS 291's 180 rays over pi are
  pi/179 apart). This is the ROS ``sensor_msgs/LaserScan`` order: index 0 is the
  rightmost ray. (Webots' range image runs the other way, left to right: Webots
  ``ranges[i]`` is ours ``ranges[n-1-i]``.)

Values (Webots and ROS REP 117 for "no return")
-----------------------------------------------
* nothing within ``max_range_m`` along the ray  -> ``+inf``;
* the first surface is closer than ``min_range_m`` -> ``+inf`` (it still occludes
  whatever is behind it, as in Webots: "not detected but still occlude");
* the robot's own parts are skipped (``exclude_owner``).

:func:`scan` returns these exact ranges (float64). :func:`apply_noise` turns them
into reported values: Gaussian noise (a :class:`plant.noise.NoiseModel`, ray i's the
i-th normal of the lidar's stream at the tick, whatever the rays hit), then every
finite value is clipped to ``[min_range_m, max_range_m]`` (a true return stays a
return: noise never turns a hit into "no return" or vice versa), then quantised to
``resolution_m`` if > 0 (and clipped again). ``inf`` stays ``inf``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from plant import kernels
from plant.raycast import Scene, cast_sectors
from plant.shapes import Shape, pose_matrix

__all__ = ["LidarConfig", "scan", "scan_many", "scan_worlds", "WorldScenes",
           "scan_many_reference",
           "apply_noise", "measure", "ray_directions", "sensor_pose"]


#: bounds a lidar's configuration is held to: 10,000 rays (0.036 deg apart over a full
#: turn, finer than planar lidars' 0.1-0.25 deg steps), and a sensor's slowest rate (one
#: reading every 100 s); beyond them a world file ran the plant out of memory or overflowed
#: the period of its readings
MAX_RAYS = 10_000
MIN_RATE_HZ = 0.01


@dataclass(frozen=True)
class LidarConfig:
    """SICK LMS 291-like planar lidar. SI units (m, rad, Hz)."""

    num_rays: int = 180
    fov_rad: float = math.pi
    min_range_m: float = 0.01
    max_range_m: float = 80.0
    resolution_m: float = 0.0          # quantisation step of reported ranges; 0 = none
    rate_hz: float = 10.0
    mount_x_m: float = 0.15
    mount_y_m: float = 0.0
    mount_z_m: float = 0.25
    mount_yaw_rad: float = 0.0

    def __post_init__(self) -> None:
        if int(self.num_rays) != self.num_rays or self.num_rays < 1:
            raise ValueError(f"num_rays must be a positive integer, got {self.num_rays!r}")
        if self.num_rays > MAX_RAYS:
            raise ValueError(f"lidar num_rays {self.num_rays} is more than {MAX_RAYS}")
        checks = {
            "fov_rad": 0.0 <= self.fov_rad <= 2.0 * math.pi,
            "min_range_m": 0.0 <= self.min_range_m < self.max_range_m,
            "max_range_m": self.max_range_m > 0.0,
            "resolution_m": self.resolution_m >= 0.0,
            "rate_hz": self.rate_hz >= MIN_RATE_HZ,
        }
        for key, ok in checks.items():
            if not ok:
                raise ValueError(f"lidar {key} out of range: {getattr(self, key)!r}")
        for key in ("mount_x_m", "mount_y_m", "mount_z_m", "mount_yaw_rad"):
            if not math.isfinite(getattr(self, key)):
                raise ValueError(f"lidar {key} must be finite, got {getattr(self, key)!r}")

    @property
    def angle_min(self) -> float:
        return -0.5 * self.fov_rad if self.num_rays > 1 else 0.0

    @property
    def angle_max(self) -> float:
        return 0.5 * self.fov_rad if self.num_rays > 1 else 0.0

    @property
    def angle_increment(self) -> float:
        return self.fov_rad / (self.num_rays - 1) if self.num_rays > 1 else 0.0

    def angles(self) -> np.ndarray:
        """Ray angles in the sensor frame (rad, CCW from x), both fov ends included."""
        return _angles(self.num_rays, self.fov_rad).copy()

    def mount_pose(self) -> np.ndarray:
        """4x4 sensor->robot-base transform."""
        return _mount_pose(self).copy()


def _mount_pose(config: LidarConfig) -> np.ndarray:
    """The mount pose, computed once per mount (read-only: shared; keyed by its four
    numbers, whose hash is cheaper than the whole configuration's)."""
    return _mount_at(config.mount_x_m, config.mount_y_m, config.mount_z_m, config.mount_yaw_rad)


@lru_cache(maxsize=64)
def _mount_at(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    m = pose_matrix(x, y, z, yaw=yaw)
    m.flags.writeable = False
    return m


@lru_cache(maxsize=64)
def _angles(n: int, fov: float) -> np.ndarray:
    if n == 1:
        return np.zeros(1)
    return np.linspace(-0.5 * fov, 0.5 * fov, n)


@lru_cache(maxsize=64)
def _local_dirs(n: int, fov: float) -> np.ndarray:
    a = _angles(n, fov)
    return np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)


def ray_directions(config: LidarConfig) -> np.ndarray:
    """(n, 3) unit ray directions in the sensor frame."""
    return _local_dirs(config.num_rays, config.fov_rad).copy()


def sensor_pose(config: LidarConfig, robot_pose: np.ndarray) -> np.ndarray:
    """World pose (4x4) of the sensor for a robot-base world pose."""
    return np.asarray(robot_pose, dtype=float) @ _mount_pose(config)


def scan(config: LidarConfig, robot_pose: np.ndarray,
         shapes: "Sequence[Shape] | Scene", exclude_owner: str | None = None) -> np.ndarray:
    """Exact ranges (m, float64, shape (num_rays,)) for the robot at ``robot_pose``.

    ``inf`` where nothing lies within ``max_range_m`` or the first surface is nearer
    than ``min_range_m``. Pass the robot's name as ``exclude_owner`` so the sensor
    ignores its own robot.
    """
    return scan_many(config, [robot_pose], Scene.from_shapes(shapes), [exclude_owner])[0]


def scan_many(config: LidarConfig, robot_poses, scene: Scene,
              exclude_owners: Sequence[str | None], threads: int = 1) -> np.ndarray:
    """:func:`scan` for G robots carrying the same lidar: (G, num_rays), row g bit for bit
    what ``scan(config, robot_poses[g], scene, exclude_owners[g])`` gives.

    One call of the C kernel (plant/kernels/lidar.c) for every robot: each shape is
    tested on the rays of its bearing sector only, with the arithmetic of
    :func:`scan_many_reference` (the numpy code the tests compare it with), the same bits.
    ``threads`` > 1 splits the robots over up to that many threads (at least 8 robots
    each: plant/kernels/lidar.c), the same bits."""
    base = np.asarray(robot_poses, dtype=float).reshape(-1, 4, 4)
    ws = kernels.lidar_work(base.shape[0], config.num_rays, threads)
    _fill_fans(config, base, ws)
    ws.skip[:] = [scene.owner_id(o) if o else -1 for o in exclude_owners]
    return kernels.lidar_scan_work(scene.kernel_arrays(), len(scene), ws, config.angle_min,
                                   config.angle_increment, config.min_range_m,
                                   config.max_range_m)


def _fill_fans(config: LidarConfig, base: np.ndarray, ws: kernels.LidarWork) -> None:
    """:func:`_fans` of robots at ``base`` (G, 4, 4) into ``ws``' buffers (the same matmuls,
    the same bits)."""
    np.matmul(base, _mount_pose(config), out=ws.poses)
    np.matmul(_local_dirs(config.num_rays, config.fov_rad)[None],
              ws.poses[:, :3, :3].transpose(0, 2, 1), out=ws.dirs)


class Fans:
    """:func:`scan_many` of G robots in one ``scene`` (none of whose shapes they skip),
    call after call: the buffers, their addresses and the scene's taken once (this object
    keeps the scene alive). The same bits."""

    def __init__(self, config: LidarConfig, scene: Scene, g: int, threads: int = 1) -> None:
        self.config, self.scene = config, scene
        self.ws = kernels.LidarWork(g, config.num_rays, threads)
        self.ws.skip[:] = -1
        self._scene = (scene.kernel_arrays(), len(scene))
        self._range = (config.angle_min, config.angle_increment, config.min_range_m,
                       config.max_range_m)

    def scan(self, base: np.ndarray) -> np.ndarray:
        """(G, num_rays) exact ranges of the robots at ``base`` (G, 4, 4) float64."""
        _fill_fans(self.config, base, self.ws)
        return kernels.lidar_scan_work(*self._scene, self.ws, *self._range)


def scan_worlds(config: LidarConfig, scenes: Sequence[Scene], robot_poses,
                exclude_owners: Sequence[str | None], world_of: Sequence[int]) -> np.ndarray:
    """:func:`scan_many` for G robots in several worlds (a batched environment's N
    copies of a world): robot g stands in ``scenes[world_of[g]]``. (G, num_rays), row g
    bit for bit what ``scan_many`` of its world alone gives; one call of the kernel."""
    if not len(scenes):                    # (no world, so no robot to cast for)
        return np.zeros((0, config.num_rays))
    return WorldScenes(config, scenes, exclude_owners, world_of,
                       [(0, 0)] * len(scenes)).scan(robot_poses)


class WorldScenes:
    """:func:`scan_worlds` call after call for robots in W worlds whose shapes stay the same
    but for the poses of some (a batch's worlds: their robots' parts move): every world's
    scene laid out once in one set of arrays, world after world, the owner ids made distinct
    across worlds and each robot's skipped owner and shapes found once. :meth:`move` writes
    the moving shapes' poses in place, :meth:`scan` casts; the same bits as
    :func:`scan_worlds` of the worlds' scenes with their shapes there.

    ``scenes``: the W worlds' scenes (their still shapes where they stay); ``owners`` (G,):
    the robot each lidar skips (None: none), ``world_of`` (G,) its world; ``moving`` (W,):
    (first shape, count) of each world's moving shapes, in its scene's order."""

    def __init__(self, config: LidarConfig, scenes: Sequence[Scene],
                 owners: Sequence[str | None], world_of: Sequence[int],
                 moving: Sequence[tuple[int, int]]) -> None:
        world_of = np.asarray(world_of, dtype=np.int64).reshape(-1)
        if not scenes or len(moving) != len(scenes) or len(owners) != len(world_of):
            raise ValueError(f"{len(scenes)} scenes, {len(moving)} moving ranges, "
                             f"{len(owners)} owners for {len(world_of)} robots")
        if world_of.size and not 0 <= world_of.min() <= world_of.max() < len(scenes):
            raise ValueError(f"a robot's world is not one of the {len(scenes)} scenes")
        self.config = config
        sizes = [len(sc) for sc in scenes]
        #: each world's first shape in the arrays (and their end)
        self.starts = starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        shift = np.concatenate([[0], np.cumsum([len(sc._owner_ids) for sc in scenes])])
        self.centers, self.rotations, halves, quad, rr, radii = (
            np.ascontiguousarray(np.concatenate([getattr(sc, key) for sc in scenes]), dtype=float)
            for key in ("centers", "rotations", "halves", "quad", "rr", "radii"))
        self.owner_ids = np.concatenate([sc.owner_ids + shift[k] for k, sc in enumerate(scenes)]
                                        ).astype(np.int64)
        self.skip = np.array([scenes[k].owner_id(o) + shift[k]
                              if o and scenes[k].owner_id(o) >= 0 else -1
                              for k, o in zip(world_of.tolist(), owners)], dtype=np.int64)
        self.first = np.ascontiguousarray(starts[world_of])
        self.last = np.ascontiguousarray(starts[world_of + 1])
        rows = []
        for k, (first, count) in enumerate(moving):
            if not 0 <= first <= first + count <= sizes[k]:
                raise ValueError(f"{count} moving shapes from shape {first} do not fit world "
                                 f"{k}'s {sizes[k]} shapes")
            rows.append(starts[k] + first + np.arange(count, dtype=np.int64))
        #: the moving shapes' rows in the arrays, world after world (:meth:`move`'s order)
        self.rows = np.concatenate(rows)
        self._keep = (halves, quad, rr, radii)          # alive as long as this object
        self._arrays = tuple(a.ctypes.data for a in (self.centers, self.rotations) + self._keep
                             ) + (kernels.ptr(self.owner_ids),)
        self._range = (config.angle_min, config.angle_increment, config.min_range_m,
                       config.max_range_m)

    def __len__(self) -> int:
        return len(self.centers)

    def move(self, poses: np.ndarray) -> None:
        """The moving shapes at ``poses`` ((M, 4, 4), in :attr:`rows`' order)."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 4, 4)
        if len(poses) != len(self.rows):
            raise ValueError(f"{len(poses)} poses for {len(self.rows)} moving shapes")
        self.centers[self.rows] = poses[:, :3, 3]
        self.rotations[self.rows] = poses[:, :3, :3]

    def scan(self, robot_poses, robots: np.ndarray | None = None) -> np.ndarray:
        """(g, num_rays) exact ranges of robots ``robots`` (indices of the G; None: all of
        them) at ``robot_poses`` ((g, 4, 4) base -> world), each in its world as the last
        :meth:`move` left it."""
        poses, dirs = _fans(self.config, robot_poses)
        skip, first, last = self.skip, self.first, self.last
        if robots is not None:
            at = np.asarray(robots, dtype=np.intp).reshape(-1)
            skip, first, last = skip[at], first[at], last[at]
        if len(poses) != len(skip):
            raise ValueError(f"{len(poses)} robot poses for {len(skip)} robots")
        return kernels.lidar_scan(self._arrays, len(self.centers), poses, dirs, skip,
                                  *self._range, first, last)


def _fans(config: LidarConfig, robot_poses) -> tuple[np.ndarray, np.ndarray]:
    """(sensor poses (G, 4, 4), world ray directions (G, n, 3)) of G robots, in numpy
    (matmul, as the recordings were made: the kernel takes them as they are)."""
    poses = np.asarray(robot_poses, dtype=float).reshape(-1, 4, 4) @ _mount_pose(config)
    rot = poses[:, :3, :3]
    dirs = np.matmul(_local_dirs(config.num_rays, config.fov_rad)[None], rot.transpose(0, 2, 1))
    return poses, dirs


def scan_many_reference(config: LidarConfig, robot_poses, scene: Scene,
                        exclude_owners: Sequence[str | None]) -> np.ndarray:
    """:func:`scan_many` in numpy (:func:`~plant.raycast.cast_sectors`): the reference the
    kernel is tested against."""
    poses, dirs = _fans(config, robot_poses)
    fan, shape, lo, hi = _cull(config, poses, scene, exclude_owners)
    dist = cast_sectors(np.ascontiguousarray(poses[:, :3, 3]), dirs, scene, fan, shape, lo, hi,
                        config.max_range_m)
    dist[dist < config.min_range_m] = np.inf
    return dist


def _cull(config: LidarConfig, poses: np.ndarray, scene: Scene,
          exclude_owners: Sequence[str | None]):
    """(fan, shape, first ray, last ray) for each sensor and each shape whose bounding
    sphere meets its scan plane within range, with the rays of the angular sector that
    sphere covers: a conservative cull, so a cast finds exactly what casting every ray at
    every shape would."""
    g_n, s_n, n = poses.shape[0], len(scene), config.num_rays
    if s_n == 0:
        return (np.zeros(0, dtype=np.intp),) * 4
    owner_ids = np.array([scene.owner_id(o) if o else -1 for o in exclude_owners])
    keep = scene.owner_ids[None, :] != owner_ids[:, None]
    rot, pos = poses[:, :3, :3], poses[:, :3, 3]
    rel = np.matmul(scene.centers[None] - pos[:, None, :], rot)      # (G, S, 3) sensor frame
    r = scene.radii[None]
    h = np.abs(rel[..., 2])
    # meets the scan plane: |distance| <= the bounding box's extent along the normal
    # (the normal in each shape's frame: n_local[g, s, i] = sum_j R_s[j, i] z_g[j])
    # (np.tensordot(rot[:, :, 2], scene.rotations, axes=([1], [1])) without its wrapping)
    n_local = np.abs(np.dot(rot[:, :, 2], scene.rotations.transpose(1, 0, 2).reshape(3, -1))
                     ).reshape(g_n, s_n, 3)
    extent = (n_local[..., 0] * scene.halves[:, 0] + n_local[..., 1] * scene.halves[:, 1]
              + n_local[..., 2] * scene.halves[:, 2])
    keep &= h <= extent + 1e-12
    r_plane = np.sqrt(np.maximum(r * r - h * h, 0.0))
    rho = np.hypot(rel[..., 0], rel[..., 1])
    keep &= rho - r_plane <= config.max_range_m
    fan, shape = np.nonzero(keep)
    lo = np.zeros(fan.size, dtype=np.intp)
    hi = np.full(fan.size, n - 1, dtype=np.intp)
    if n > 1 and fan.size:
        rp, rh = r_plane[fan, shape], rho[fan, shape]
        with np.errstate(invalid="ignore", divide="ignore"):
            half = np.arcsin(np.minimum(rp / rh, 1.0))
        bearing = np.arctan2(rel[fan, shape, 1], rel[fan, shape, 0])
        a0, inc = config.angle_min, config.angle_increment
        # a sector crossing the +-pi seam (or a sensor inside the sphere): every ray
        sector = (rh > rp) & (np.abs(bearing) + half < math.pi)
        # rays whose angle lies in [bearing - half, bearing + half], with a slack of 1e-6
        # of a ray spacing, far above the rounding of these angles
        first = np.ceil((bearing - half - a0) / inc - 1e-6).astype(np.intp)
        last = np.floor((bearing + half - a0) / inc + 1e-6).astype(np.intp)
        lo = np.where(sector, np.maximum(first, 0), 0)
        hi = np.where(sector, np.minimum(last, n - 1), n - 1)
        seen = lo <= hi                                 # the sector meets the field of view
        fan, shape, lo, hi = fan[seen], shape[seen], lo[seen], hi[seen]
    return fan, shape, lo, hi


def apply_noise(config: LidarConfig, ranges: np.ndarray, noise=None, tick=0) -> np.ndarray:
    """Reported ranges from exact ones: noise -> clip finite to [min, max] -> quantise.

    ``noise``: a :class:`plant.noise.NoiseModel` (or None for none), drawn at ``tick``;
    a model of several keys takes ``ranges`` (K, n), a scan a row, and ``tick`` one int or
    one per row. Returns a new float64 array; ``inf`` stays ``inf``.
    """
    r = np.array(ranges, dtype=float)
    if noise is not None:
        r = np.asarray(noise.apply(r, tick), dtype=float)
    finite = np.isfinite(r)
    lo, hi = config.min_range_m, config.max_range_m
    r[finite] = np.clip(r[finite], lo, hi)
    if config.resolution_m > 0.0:
        q = config.resolution_m
        r[finite] = np.clip(np.round(r[finite] / q) * q, lo, hi)
    return r


def measure(config: LidarConfig, robot_pose: np.ndarray, shapes: "Sequence[Shape] | Scene",
            noise=None, exclude_owner: str | None = None, tick: int = 0) -> np.ndarray:
    """``apply_noise(config, scan(...), noise, tick)``: what the sensor reports."""
    return apply_noise(config, scan(config, robot_pose, shapes, exclude_owner), noise, tick)
