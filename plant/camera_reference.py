"""The camera's numpy renderer: the reference the C kernel (plant/kernels/camera.c, called
by :func:`plant.camera.render_full`) is tested against, and what the kernel replaced.

Float32 per-shape kernels over the pixels of each shape's projected bounding box (see
:mod:`plant.camera` for the conventions); :func:`render_full_reference` has
:func:`plant.camera.render_full`'s signature and returns the same buffers.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

try:                                   # only for a fast RGBA->RGB copy
    import cv2
except ImportError:                    # pragma: no cover
    cv2 = None

from plant.camera import (_LEVELS, _T_BODY_OPTICAL, DEFAULT_BACKGROUND, LIGHT_DIR, CameraConfig,
                          _flat_grid_for, _grid_for, _lut)
from plant.raycast import Scene, quadratic_roots, shape_params
from plant.shapes import Shape

__all__ = ["render_full_reference"]


# ----------------------------------------------------------------------------------
# Rendering
# ----------------------------------------------------------------------------------

_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
                         dtype=float)
_EDGES = np.array([(i, j) for i in range(8) for j in range(i + 1, 8)
                   if np.sum(_CORNER_SIGNS[i] != _CORNER_SIGNS[j]) == 1])


def _projected_rects(half: np.ndarray, t_opt_shape: np.ndarray, near: float, far: float):
    """Normalised-image rectangles covering each shape's bounding box clipped to
    z >= near: (S, 4) [x0, x1, y0, y1] and a (S,) bool "possibly visible" mask
    (False when the box lies wholly in front of ``near`` or beyond ``far``)."""
    rot_t = t_opt_shape[:, :3, :3].transpose(0, 2, 1)
    corners = (_CORNER_SIGNS[None, :, :] * half[:, None, :]) @ rot_t
    corners += t_opt_shape[:, None, :3, 3]                                # (S, 8, 3)
    z = corners[..., 2]
    a, b = corners[:, _EDGES[:, 0]], corners[:, _EDGES[:, 1]]            # (S, 12, 3)
    za, zb = a[..., 2], b[..., 2]
    cross = (za - near) * (zb - near) < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        sfrac = np.where(cross, (near - za) / (zb - za), 0.0)
    clip = a + sfrac[..., None] * (b - a)
    pts = np.concatenate([corners, clip], axis=1)                         # (S, 20, 3)
    ok = np.concatenate([z >= near, cross], axis=1)
    zz = np.where(ok, np.maximum(pts[..., 2], near), 1.0)
    x = pts[..., 0] / zz
    y = pts[..., 1] / zz
    rect = np.stack([np.where(ok, x, np.inf).min(1), np.where(ok, x, -np.inf).max(1),
                     np.where(ok, y, np.inf).min(1), np.where(ok, y, -np.inf).max(1)], axis=1)
    visible = ok.any(axis=1) & (z.min(axis=1) <= far)
    return rect, visible


# ----------------------------------------------------------------------------------
# Camera kernels: one shape, the shared ray origin ``o`` (float64 (3,), in the shape's
# frame), the rays' directions ``d`` ((3, n) float32, shape frame). Return (t_enter, ok,
# lam): ``ok`` marks entering hits with near <= t < cur (the z-buffer), ``lam`` the
# Lambert term n . L (``light`` = L in the shape frame), valid where ok; lam is None if
# nothing is hit. Few array passes (the three slabs of a box go through together, the
# face comes from the slab that set t_enter) and float32 throughout: per-shape numpy call
# overhead, not arithmetic, is what a small frame costs.
# ----------------------------------------------------------------------------------

def _slab32(o, d, h):
    inv = np.divide(1.0, d)
    t1 = inv * (-h - o)
    t2 = inv * (h - o)
    return np.fmin(t1, t2), np.fmax(t1, t2, out=t2)


def _face_term(d, l_comp):
    """Lambert term of the slab face entered by rays d: normal -sign(d)."""
    return np.where(d > 0, np.float32(-l_comp), np.float32(l_comp))


def _cam_box(prm, o, d, light, near, cur):
    h = np.array(prm, dtype=np.float32)[:, None]
    o32 = o.astype(np.float32)[:, None]
    inv = np.divide(1.0, d)
    t1 = (-h - o32) * inv
    t2 = (h - o32) * inv
    lo = np.fmin(t1, t2)
    hi = np.fmax(t1, t2, out=t2)
    tn = lo.max(axis=0)
    ok = tn <= hi.min(axis=0)
    ok &= tn >= near
    ok &= tn < cur
    if not ok.any():
        return tn, ok, None
    l32 = light.astype(np.float32)[:, None]
    faces = np.where(d > 0, -l32, l32)      # Lambert term of each slab's entry face
    # the face of the first slab (x, y, z) whose entry set t_enter
    lam = np.where(tn == lo[0], faces[0], np.where(tn == lo[1], faces[1], faces[2]))
    return tn, ok, lam


def _cam_sphere(prm, o, d, light, near, cur):
    (r,) = prm
    a = d * d
    a = a.sum(axis=0)
    b = o.astype(np.float32) @ d
    c = float(o @ o) - r * r
    t0, _ = quadratic_roots(a, b, c)
    ok = t0 >= near                          # nan (no root) compares False
    ok &= t0 < cur
    if not ok.any():
        return t0, ok, None
    # n = (o + t d) / r:  n . L = (o . L) / r + t (d . L) / r
    dl = (light / r).astype(np.float32) @ d
    dl *= t0
    dl += float(o @ light) / r
    return t0, ok, dl


def _cam_cylinder(prm, o, d, light, near, cur):
    r, hh = prm
    ox, oy, oz = (float(v) for v in o)
    dx, dy, dz = d
    a = dx * dx
    a += dy * dy
    b = dx * ox
    b += dy * oy
    c = ox * ox + oy * oy - r * r
    s0, s1 = quadratic_roots(a, b, c)
    if c < 0.0:                              # origin inside the infinite tube: rays
        par = a == 0.0                       # along the axis stay inside it
        s0 = np.where(par, np.float32(-np.inf), s0)
        s1 = np.where(par, np.float32(np.inf), s1)
    zlo, zhi = _slab32(oz, dz, hh)
    side = s0 >= zlo
    tn = np.where(side, s0, zlo)             # s0 nan (tube missed): not side, tn = zlo,
    ok = tn <= np.minimum(s1, zhi)           # but then s1 is nan too: not ok
    ok &= tn >= near
    ok &= tn < cur
    if not ok.any():
        return tn, ok, None
    lx, ly, lz = (float(v) for v in light)
    px = dx * tn
    px += ox
    px *= lx / r
    py = dy * tn
    py += oy
    py *= ly / r
    px += py
    lam = np.where(side, px, _face_term(dz, lz))
    return tn, ok, lam


_CAM_KERNELS = {"box": _cam_box, "sphere": _cam_sphere, "cylinder": _cam_cylinder}


def _shade(shape_list, sid: np.ndarray, lam: np.ndarray, bg: np.ndarray) -> np.ndarray:
    """rgb8 from shape ids and Lambert terms via a (shape, level) -> RGBA lookup table
    (the Lambert term is quantised to 1/255: at most half a grey level off)."""
    h, w = sid.shape
    n = len(shape_list)
    lut = _lut(tuple(tuple(s.color) for s in shape_list), tuple(float(v) for v in bg))
    q = np.clip(lam, 0.0, 1.0)
    q *= _LEVELS - 1
    q += 0.5
    idx = q.astype(np.intp)
    row = sid.copy()
    row[sid < 0] = n
    row *= _LEVELS
    idx += row
    rgba = np.take(lut, idx).view(np.uint8).reshape(h, w, 4)
    if cv2 is not None:
        return cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB)
    return np.ascontiguousarray(rgba[..., :3])     # pragma: no cover - numpy-only fallback



def _clipped_rects(halves, t_opt_shape, near: float, far: float, grid):
    """Each shape's projected rectangle clipped to the image grid's bounds, and whether
    anything of it is left to draw."""
    rects, visible = _projected_rects(halves, t_opt_shape, near, far)
    bx0, bx1, by0, by1 = grid.bounds
    rects[:, 0] = np.maximum(rects[:, 0], bx0)
    rects[:, 1] = np.minimum(rects[:, 1], bx1)
    rects[:, 2] = np.maximum(rects[:, 2], by0)
    rects[:, 3] = np.minimum(rects[:, 3], by1)
    visible &= (rects[:, 0] <= rects[:, 1]) & (rects[:, 2] <= rects[:, 3])
    return rects, visible


def render_full_reference(config: CameraConfig, camera_pose: np.ndarray,
                shapes: "Sequence[Shape] | Scene", exclude_owner: str | None = None,
                background=DEFAULT_BACKGROUND, *, force_flat: bool = False):
    """Render and also return the buffers: ``(rgb uint8 (H,W,3), depth float32 (H,W)
    m along the optical axis with inf where nothing is hit, shape_index (H,W) int
    indexing ``shapes``, -1 = none)``. Ray maths runs in float32 (sub-micrometre at
    room scale); the lidar path (:mod:`plant.raycast`) is float64.

    ``force_flat`` uses the (distortion) per-pixel-index path even without distortion
    (testing aid; the output is identical).
    """
    scene = Scene.from_shapes(shapes)
    shape_list = scene.shapes
    grid = _grid_for(config) if not force_flat else _flat_grid_for(config)
    h, w = config.height, config.width
    near, far = float(config.near_m), float(config.far_m)
    bg = np.asarray(background, dtype=float).reshape(3)

    t_world_opt = np.asarray(camera_pose, dtype=float) @ _T_BODY_OPTICAL
    r_wo, o_w = t_world_opt[:3, :3], t_world_opt[:3, 3]

    depth = np.full((h, w), far, dtype=np.float32)   # z-buffer: optical-axis depth
    sid = np.full((h, w), -1, dtype=np.intp)
    shade = np.zeros((h, w), dtype=np.float32)
    todo = np.nonzero(scene.include_mask(exclude_owner))[0]
    if todo.size:
        rots, cens = scene.rotations[todo], scene.centers[todo]
        # shape -> optical: R_wo^T R_s, R_wo^T (c_s - o_w)
        t_opt_shape = np.zeros((todo.size, 4, 4))
        t_opt_shape[:, :3, :3] = r_wo.T @ rots
        t_opt_shape[:, :3, 3] = (cens - o_w) @ r_wo
        t_opt_shape[:, 3, 3] = 1.0
        rects, visible = _clipped_rects(scene.halves[todo], t_opt_shape, near, far, grid)
        flat = grid.distorted
        depth_f, sid_f, shade_f = depth.reshape(-1), sid.reshape(-1), shade.reshape(-1)
        for j in np.nonzero(visible)[0]:
            i = todo[j]
            shape = shape_list[i]
            x0, x1, y0, y1 = rects[j]
            if flat:
                sel = grid.select_flat(x0, x1, y0, y1)
                if sel.size == 0:
                    continue
                rays = grid.rays3_flat[:, sel]
                cur = depth_f[sel]
            else:
                sel = grid.select_block(x0, x1, y0, y1)
                if sel is None:
                    continue
                rays = grid.rays3[:, sel[0], sel[1]].reshape(3, -1)
                block = depth[sel]                  # a view
                cur = block.reshape(-1)             # a copy (the block is not contiguous)
            r_s = rots[j]
            d = (r_s.T @ r_wo).astype(np.float32) @ rays        # optical -> shape local
            o = r_s.T @ (o_w - cens[j])
            with np.errstate(all="ignore"):
                tn, hit, lam = _CAM_KERNELS[shape.kind](shape_params(shape), o, d,
                                                        r_s.T @ LIGHT_DIR, near, cur)
            if lam is None:
                continue
            if flat:
                idx = sel[hit]
                depth_f[idx] = tn[hit]
                sid_f[idx] = i
                shade_f[idx] = lam[hit]
            else:
                shp = block.shape
                hit = hit.reshape(shp)
                np.copyto(block, tn.reshape(shp), where=hit)
                np.copyto(sid[sel], i, where=hit)
                np.copyto(shade[sel], lam.reshape(shp), where=hit)

    img = _shade(shape_list, sid, shade, bg)
    depth[sid < 0] = np.inf
    return img, depth, sid

