"""Pinhole RGB camera rendered by ray casting (a C kernel, plant/kernels/camera.c; OpenCV only
for distortion).

Frames
------
* The camera *body* frame follows the robot convention: x forward (viewing
  direction), y left, z up. ``camera_pose`` arguments are body-frame poses
  (4x4, camera->world); the mount pose on the robot is in the same convention.
* Internally rays live in the *optical* frame (OpenCV / ROS ``*_optical_frame``):
  z forward, x right, y down. ``x_body = z_opt``, ``y_body = -x_opt``,
  ``z_body = -y_opt`` (:data:`R_BODY_OPTICAL` maps optical to body coordinates).
  A 3-D point ``P_opt`` given to ``cv2.projectPoints(P_opt, rvec=0, tvec=0, K, D)``
  lands on the pixel where :func:`render` draws it.

Intrinsics (:func:`intrinsics`)
-------------------------------
``fx = fy = (width/2) / tan(hfov/2)``, ``cx = (width-1)/2``, ``cy = (height-1)/2``:
pixel centres are at integer coordinates (OpenCV convention), pixel ``(u, v)`` covers
``[u-0.5, u+0.5]``, so ``hfov`` spans the image from its left edge to its right edge
(Webots' definition); square pixels, vertical fov ``2 atan((height/2)/fy)``.
``D = (k1, k2, p1, p2, k3)`` is OpenCV's plumb-bob model. With distortion, the ray of
output pixel ``(u, v)`` is the undistorted normalised point that ``cv2.projectPoints``
maps to ``(u, v)`` (``cv2.undistortPoints`` polished by Newton steps to ~1e-12),
cached per configuration. Pixels with no preimage (strong distortion beyond its fold)
show the background.

Rendering
---------
Rays start at the camera; a hit counts only if the ray *enters* the solid at a depth
in ``[near_m, far_m)`` (as in :mod:`plant.raycast`, back faces are ignored: a camera
inside its own robot's body does not see the body; ``exclude_owner`` skips a robot's
parts altogether). Each shape's bounding box is clipped to the near plane and
projected to a rectangle of normalised image coordinates; only the rays of pixels
inside that rectangle are intersected with it (z-buffer on depth), in double. Colour =
``shape.color * (AMBIENT + DIFFUSE * max(0, n . LIGHT_DIR))`` (n . L quantised to
1/255); pixels where nothing is hit get ``background`` (RGB 0..1). Output: uint8
(H, W, 3) rgb8. Pass a :class:`plant.raycast.Scene` built once per tick to share the
stacking work with the lidar.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from plant import kernels
from plant.lens import undistort
from plant.lidar import MIN_RATE_HZ
from plant.raycast import Scene
from plant.shapes import Shape, pose_matrix

__all__ = [
    "CameraConfig",
    "intrinsics",
    "camera_info",
    "camera_pose",
    "look_at",
    "render",
    "render_full",
    "frame",
    "third_person",
    "R_BODY_OPTICAL",
    "LIGHT_DIR",
    "AMBIENT",
    "DIFFUSE",
    "DEFAULT_BACKGROUND",
]

#: optical -> body rotation (columns: optical x, y, z axes expressed in the body frame)
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0],
                           [-1.0, 0.0, 0.0],
                           [0.0, -1.0, 0.0]])
_T_BODY_OPTICAL = np.eye(4)
_T_BODY_OPTICAL[:3, :3] = R_BODY_OPTICAL

#: world-frame unit vector towards the light (mostly overhead, a little towards -x, +y)
LIGHT_DIR = np.array([-0.4, 0.3, 1.0]) / np.linalg.norm([-0.4, 0.3, 1.0])
_LIGHT = np.ascontiguousarray(LIGHT_DIR, dtype=float)
AMBIENT = 0.4
DIFFUSE = 0.6
DEFAULT_BACKGROUND = (0.70, 0.82, 0.95)

_TILE = 8


#: the largest image side (a 4K sensor's is 3840): beyond it a world file would run the
#: plant out of memory
MAX_SIDE_PX = 4096


@dataclass(frozen=True)
class CameraConfig:
    """Pinhole camera. SI units (m, rad, Hz); distortion in OpenCV's convention."""

    width: int = 160
    height: int = 120
    hfov_rad: float = 1.0              # ~57.3 deg, edge to edge
    rate_hz: float = 30.0
    near_m: float = 0.01
    far_m: float = 100.0
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    mount_x_m: float = 0.18
    mount_y_m: float = 0.0
    mount_z_m: float = 0.30
    mount_roll_rad: float = 0.0
    mount_pitch_rad: float = 0.0
    mount_yaw_rad: float = 0.0

    def __post_init__(self) -> None:
        for key in ("width", "height"):
            v = getattr(self, key)
            if int(v) != v or v < 1:
                raise ValueError(f"camera {key} must be a positive integer, got {v!r}")
            if v > MAX_SIDE_PX:
                raise ValueError(f"camera {key} {v} is more than {MAX_SIDE_PX} pixels")
        checks = {
            "hfov_rad": 0.0 < self.hfov_rad < math.pi,
            "rate_hz": self.rate_hz >= MIN_RATE_HZ,
            "near_m": 0.0 < self.near_m < self.far_m,
            "far_m": self.far_m > 0.0,
        }
        for key, ok in checks.items():
            if not ok:
                raise ValueError(f"camera {key} out of range: {getattr(self, key)!r}")
        for key in ("k1", "k2", "p1", "p2", "k3", "mount_x_m", "mount_y_m", "mount_z_m",
                    "mount_roll_rad", "mount_pitch_rad", "mount_yaw_rad"):
            if not math.isfinite(getattr(self, key)):
                raise ValueError(f"camera {key} must be finite, got {getattr(self, key)!r}")

    @property
    def distortion(self) -> tuple[float, float, float, float, float]:
        return (self.k1, self.k2, self.p1, self.p2, self.k3)

    def mount_pose(self) -> np.ndarray:
        """4x4 camera-body -> robot-base transform."""
        return pose_matrix(self.mount_x_m, self.mount_y_m, self.mount_z_m,
                           self.mount_roll_rad, self.mount_pitch_rad, self.mount_yaw_rad)


def intrinsics(config: CameraConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(K 3x3, D (5,))`` for OpenCV: fx = fy = (w/2)/tan(hfov/2), c = ((w-1)/2, (h-1)/2)."""
    f = 0.5 * config.width / math.tan(0.5 * config.hfov_rad)
    k = np.array([[f, 0.0, 0.5 * (config.width - 1)],
                  [0.0, f, 0.5 * (config.height - 1)],
                  [0.0, 0.0, 1.0]])
    return k, np.array(config.distortion, dtype=float)


def camera_info(config: CameraConfig) -> dict:
    """Fields of a ROS ``sensor_msgs/CameraInfo`` (plumb_bob; P = [K | 0])."""
    k, d = intrinsics(config)
    p = np.zeros((3, 4))
    p[:, :3] = k
    return {
        "width": config.width, "height": config.height,
        "distortion_model": "plumb_bob", "d": d.tolist(),
        "k": k.ravel().tolist(), "r": np.eye(3).ravel().tolist(), "p": p.ravel().tolist(),
    }


def camera_pose(config: CameraConfig, robot_pose: np.ndarray) -> np.ndarray:
    """World pose (4x4, body convention) of the camera for a robot-base world pose."""
    return np.asarray(robot_pose, dtype=float) @ config.mount_pose()


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera body pose (x forward, y left, z up) at ``eye`` looking at ``target``."""
    eye = np.asarray(eye, dtype=float)
    fwd = np.asarray(target, dtype=float) - eye
    nf = np.linalg.norm(fwd)
    if nf == 0:
        raise ValueError("look_at: eye and target coincide")
    fwd /= nf
    up = np.asarray(up, dtype=float)
    left = np.cross(up, fwd)
    if np.linalg.norm(left) < 1e-9:              # looking along `up`: pick another up
        left = np.cross(np.array([1.0, 0.0, 0.0]) if abs(fwd[0]) < 0.9
                        else np.array([0.0, 1.0, 0.0]), fwd)
    left /= np.linalg.norm(left)
    upv = np.cross(fwd, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = fwd, left, upv, eye
    return m


# ----------------------------------------------------------------------------------
# Ray grid (cached per image geometry)
# ----------------------------------------------------------------------------------

class _RayGrid:
    """Per-pixel optical-frame rays (x_n, y_n, 1) and culling structures."""

    def __init__(self, width: int, height: int, hfov: float, dist: tuple):
        cfg = CameraConfig(width=width, height=height, hfov_rad=hfov,
                           k1=dist[0], k2=dist[1], p1=dist[2], p2=dist[3], k3=dist[4])
        self.k, self.d = intrinsics(cfg)
        self.width, self.height = width, height
        f, cx, cy = self.k[0, 0], self.k[0, 2], self.k[1, 2]
        self.f, self.cx, self.cy = f, cx, cy
        u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
        xd, yd = (u - cx) / f, (v - cy) / f
        self.distorted = any(c != 0.0 for c in dist)
        if self.distorted:
            xn, yn = undistort(xd.ravel(), yd.ravel(), dist, self.k)
            xn, yn = xn.reshape(height, width), yn.reshape(height, width)
        else:
            xn, yn = xd, yd
        self.valid = np.isfinite(xn) & np.isfinite(yn)
        self.xn, self.yn = xn, yn
        # (x_n, y_n, 1) per pixel, float32: a shape's ray directions are one 3x3 product
        self.rays3 = np.stack([xn, yn, np.ones_like(xn)]).astype(np.float32)   # (3, H, W)
        self.rays3_flat = self.rays3.reshape(3, -1)
        dirs = np.stack([xn, yn, np.ones_like(xn)], axis=-1)
        dirs[~self.valid] = np.nan
        self.dirs = dirs                                        # (H, W, 3)
        with np.errstate(invalid="ignore"):
            self.bounds = (np.nanmin(xn), np.nanmax(xn), np.nanmin(yn), np.nanmax(yn))
        if self.distorted:
            self._build_tiles()
        self.kernel_bounds = np.array(self.bounds, dtype=float)
        self._xy = None
        for arr in (self.xn, self.yn, self.dirs, self.valid, self.rays3, self.rays3_flat,
                    self.kernel_bounds):
            arr.flags.writeable = False         # shared through the cache

    def kernel_xy(self) -> np.ndarray:
        """(2, H, W) float64: every pixel's ray (xn, yn), NaN where it has none (the C
        kernel's distorted rays)."""
        if self._xy is None:
            xy = np.stack([self.xn, self.yn]).astype(float)
            xy[:, ~self.valid] = np.nan
            xy.flags.writeable = False
            self._xy = xy
        return self._xy

    def _build_tiles(self) -> None:
        h, w = self.height, self.width
        tv, tu = np.meshgrid(np.arange(h) // _TILE, np.arange(w) // _TILE, indexing="ij")
        ntu = (w + _TILE - 1) // _TILE
        tid = (tv * ntu + tu).ravel()
        tid = np.where(self.valid.ravel(), tid, -1)
        order = np.argsort(tid, kind="stable")
        order = order[tid[order] >= 0]
        self.perm = order
        ntiles = ntu * ((h + _TILE - 1) // _TILE)
        counts = np.bincount(tid[order], minlength=ntiles)
        self.starts = np.concatenate([[0], np.cumsum(counts)])
        xs, ys = self.xn.ravel()[order], self.yn.ravel()[order]
        nz = counts > 0
        self.tile_ids = np.nonzero(nz)[0]
        s = self.starts[self.tile_ids]
        self.t_xmin = np.minimum.reduceat(xs, s)
        self.t_xmax = np.maximum.reduceat(xs, s)
        self.t_ymin = np.minimum.reduceat(ys, s)
        self.t_ymax = np.maximum.reduceat(ys, s)
        self.xn_flat = self.xn.ravel()
        self.yn_flat = self.yn.ravel()

    def select_flat(self, x0, x1, y0, y1) -> np.ndarray:
        """Flat pixel indices whose ray lies in the normalised rectangle."""
        m = (self.t_xmax >= x0) & (self.t_xmin <= x1) & (self.t_ymax >= y0) & (self.t_ymin <= y1)
        tiles = self.tile_ids[m]
        if tiles.size == 0:
            return np.empty(0, dtype=np.intp)
        st = self.starts[tiles]
        lens = self.starts[tiles + 1] - st
        total = int(lens.sum())
        base = np.repeat(st - (np.cumsum(lens) - lens), lens)
        idx = self.perm[base + np.arange(total)]
        xs, ys = self.xn_flat[idx], self.yn_flat[idx]
        keep = (xs >= x0) & (xs <= x1) & (ys >= y0) & (ys <= y1)
        return idx[keep]

    def select_block(self, x0, x1, y0, y1):
        """(row slice, col slice) of the pixels whose ray lies in the rectangle, or None."""
        f, cx, cy = self.f, self.cx, self.cy
        u0 = max(0, math.ceil(f * x0 + cx - 1e-9))
        u1 = min(self.width - 1, math.floor(f * x1 + cx + 1e-9))
        v0 = max(0, math.ceil(f * y0 + cy - 1e-9))
        v1 = min(self.height - 1, math.floor(f * y1 + cy + 1e-9))
        if u0 > u1 or v0 > v1:
            return None
        return (slice(v0, v1 + 1), slice(u0, u1 + 1))


@lru_cache(maxsize=16)
def _ray_grid(width: int, height: int, hfov: float, dist: tuple) -> _RayGrid:
    return _RayGrid(width, height, hfov, dist)


def _grid_for(config: CameraConfig) -> _RayGrid:
    return _ray_grid(int(config.width), int(config.height), float(config.hfov_rad),
                     tuple(float(c) for c in config.distortion))


_LEVELS = 256


@lru_cache(maxsize=32)
def _lut(colors: tuple, bg: tuple) -> np.ndarray:
    """Flat uint32 (RGBA) table: entry shape * LEVELS + level; row len(colors) = background."""
    n = len(colors)
    cols = np.clip(np.array(colors, dtype=float).reshape(n, 3), 0.0, 1.0)
    fac = AMBIENT + DIFFUSE * (np.arange(_LEVELS) / (_LEVELS - 1))
    lut = np.empty((n + 1, _LEVELS, 4), dtype=np.uint8)
    lut[:n, :, :3] = np.rint(cols[:, None, :] * fac[None, :, None] * 255.0)
    lut[n, :, :3] = np.rint(np.clip(bg, 0.0, 1.0) * 255.0)
    lut[..., 3] = 255
    return lut.view(np.uint32).reshape(-1)



def render_full(config: CameraConfig, camera_pose: np.ndarray,
                shapes: "Sequence[Shape] | Scene", exclude_owner: str | None = None,
                background=DEFAULT_BACKGROUND, *, force_flat: bool = False):
    """Render and also return the buffers: ``(rgb uint8 (H,W,3), depth float32 (H,W)
    m along the optical axis with inf where nothing is hit, shape_index (H,W) int
    indexing ``shapes``, -1 = none)``. One call of the C kernel (plant/kernels/camera.c),
    in double; :func:`plant.camera_reference.render_full_reference` is the numpy
    renderer it is tested against.

    ``force_flat`` gives the kernel every pixel's ray, as with distortion, even without
    it (testing aid; the output is identical).
    """
    h, w = config.height, config.width
    bufs = (np.empty((h, w, 3), dtype=np.uint8), np.empty((h, w), dtype=np.float32),
            np.empty((h, w), dtype=np.intp), np.empty(w * h + w + h))
    _render_into(config, camera_pose, shapes, exclude_owner, background, force_flat, bufs)
    return bufs[:3]


def render(config: CameraConfig, camera_pose: np.ndarray, shapes: "Sequence[Shape] | Scene",
           exclude_owner: str | None = None, background=DEFAULT_BACKGROUND) -> np.ndarray:
    """rgb8 image (uint8, (height, width, 3)) seen from ``camera_pose`` (4x4 world pose
    of the camera body: x forward, y left, z up). ``exclude_owner``: skip that robot's
    parts (the robot carrying the camera). ``background``: RGB 0..1 where nothing is hit.
    (:func:`render_full`'s picture, its depth and shape buffers reused frame after frame.)"""
    h, w = config.height, config.width
    rgb = np.empty((h, w, 3), dtype=np.uint8)
    scratch = kernels.camera_work(w, h)
    _render_into(config, camera_pose, shapes, exclude_owner, background, False,
                 (rgb, *scratch))
    return rgb


def frame(config: CameraConfig, robot_pose: np.ndarray, scene: "Sequence[Shape] | Scene",
          exclude_owner: str | None = None, noise=None, tick: int = 0) -> np.ndarray:
    """The camera's rgb8 picture, noisy, as a sensor publishes it frame after frame: the
    bytes of ``noise.apply(render(config, camera_pose(config, robot_pose), scene,
    exclude_owner), tick)`` (``noise``: a :class:`plant.noise.NoiseModel`, or None), in one
    kernel call that renders and draws the noise, with the arguments that stay the same
    from frame to frame (the ray grid, the colour table, the shapes drawn, the buffers)
    taken once per camera, scene layout and thread."""
    drawers = getattr(_local, "drawers", None)
    if drawers is None:
        drawers = _local.drawers = {}
    d = drawers.get((id(config), exclude_owner))
    if d is None:                       # (a drawer holds its config: the id stays its own)
        if len(drawers) > 16:
            drawers.clear()
        d = drawers[(id(config), exclude_owner)] = _Drawer(config, exclude_owner)
    draw = None if noise is None else noise.image_draw(tick)
    rgb = d.draw(robot_pose, Scene.from_shapes(scene), draw)
    if noise is not None and draw is None:
        rgb = noise.apply(rgb, tick)
    return rgb


_local = threading.local()


class _Drawer:
    """One camera's kernel call with its fixed arguments prepared (see :func:`frame`)."""

    def __init__(self, config: CameraConfig, exclude_owner: str | None) -> None:
        self.config, self.exclude = config, exclude_owner
        w, h = config.width, config.height
        self.shape = (h, w, 3)
        self.mount = config.mount_pose()
        grid = _grid_for(config)
        self.bufs = (np.empty((h, w), dtype=np.float32), np.empty((h, w), dtype=np.intp),
                     np.empty(w * h + w + h))
        self.pose, self.opt, self.cam = np.empty((4, 4)), np.empty((4, 4)), np.empty(12)
        xy = grid.kernel_xy() if grid.distorted else None
        self._grid = (grid, xy)                 # (kept alive: the call holds their addresses)
        self.view = (kernels.ptr(self.cam), kernels.ptr(_LIGHT), w, h, grid.f, grid.cx, grid.cy,
                     None if xy is None else kernels.ptr(xy), kernels.ptr(grid.kernel_bounds),
                     float(config.near_m), float(config.far_m))
        self.work = tuple(kernels.ptr(b) for b in self.bufs)
        self.layout = None      # (owners, colors, todo, lut, their addresses) of the scene

    def _scene(self, scene: Scene) -> tuple:
        lay = self.layout
        if lay is None or lay[0] is not scene.owners or lay[1] is not scene.colors:
            todo = np.nonzero(scene.include_mask(self.exclude))[0].astype(np.int64)
            bg = tuple(float(v) for v in np.asarray(DEFAULT_BACKGROUND, dtype=float))
            lut = _lut(scene.colors, bg)
            lay = self.layout = (scene.owners, scene.colors, todo, lut,
                                 (kernels.ptr(todo), todo.size), kernels.ptr(lut))
        return lay

    def draw(self, robot_pose: np.ndarray, scene: Scene, noise: tuple | None) -> np.ndarray:
        lay = self._scene(scene)
        # camera_pose's and _render_into's products, into buffers kept for them
        np.matmul(np.asarray(robot_pose, dtype=float), self.mount, out=self.pose)
        np.matmul(self.pose, _T_BODY_OPTICAL, out=self.opt)
        cam = self.cam
        cam[:9] = self.opt[:3, :3].ravel()
        cam[9:] = self.opt[:3, 3]
        rgb = np.empty(self.shape, dtype=np.uint8)
        seed, thr, vals = (0, None, None) if noise is None else (noise[0], *noise[1])
        kernels.library().plant_camera_render(
            scene.centers.ctypes.data, scene.rotations.ctypes.data, *scene.const_ptrs()[:2],
            len(scene), *lay[4], *self.view, lay[5], rgb.ctypes.data, *self.work, seed,
            0 if thr is None else thr.size, None if thr is None else thr.ctypes.data,
            None if vals is None else vals.ctypes.data)
        return rgb


def _render_into(config, camera_pose, shapes, exclude_owner, background, force_flat, bufs):
    scene = Scene.from_shapes(shapes)
    grid = _grid_for(config) if not force_flat else _flat_grid_for(config)
    bg = tuple(float(v) for v in np.asarray(background, dtype=float).reshape(3))
    todo = np.nonzero(scene.include_mask(exclude_owner))[0].astype(np.int64)
    lut = _lut(scene.colors, bg)
    t_world_opt = np.asarray(camera_pose, dtype=float) @ _T_BODY_OPTICAL
    cam = np.concatenate([t_world_opt[:3, :3].ravel(), t_world_opt[:3, 3]])
    kernels.camera_render(scene, todo, cam, _LIGHT, config.width, config.height, grid.f, grid.cx,
                          grid.cy, grid.kernel_xy() if grid.distorted else None,
                          grid.kernel_bounds, float(config.near_m), float(config.far_m), lut,
                          *bufs)


def third_person(eye_xyz, target_xyz, shapes: "Sequence[Shape] | Scene", width: int = 640,
                 height: int = 480, hfov: float = 1.0, background=DEFAULT_BACKGROUND,
                 up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Picture of the scene from any eye point looking at ``target_xyz`` (rgb8)."""
    cfg = CameraConfig(width=width, height=height, hfov_rad=hfov, far_m=1e4)
    return render(cfg, look_at(eye_xyz, target_xyz, up), shapes, None, background)


@lru_cache(maxsize=4)
def _flat_grid(width: int, height: int, hfov: float) -> _RayGrid:
    g = _RayGrid(width, height, hfov, (0.0,) * 5)
    g.distorted = True
    g._build_tiles()
    return g


def _flat_grid_for(config: CameraConfig) -> _RayGrid:
    if any(c != 0.0 for c in config.distortion):
        return _grid_for(config)
    return _flat_grid(int(config.width), int(config.height), float(config.hfov_rad))
