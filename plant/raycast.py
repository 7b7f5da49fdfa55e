"""Vectorised ray casting against primitive :class:`~plant.shapes.Shape` solids.

Pure numpy, exact analytic intersections, computed in each shape's local frame:

* box: slab test against the oriented box (``size`` = full extents);
* cylinder: finite, capped (``size`` = radius, height; axis = local z, centred);
* sphere: ``size`` = radius.

Every primitive is written as one form, its local bounding box (three slabs)
intersected with a diagonal quadric ``qx x^2 + qy y^2 + qz z^2 <= rr``: a box has
q = 0 (no quadric), a cylinder q = (1, 1, 0), rr = r^2, a sphere q = (1, 1, 1). So all
shapes go through a single broadcast (shapes x rays) with no per-kind or per-shape
Python loop; that is what keeps a 180-ray scan well under a millisecond.

Conventions
-----------
* A ray is ``origin + t * direction``. Directions need not be unit length: ``t`` is
  the ray parameter, which equals the distance in metres when directions are unit
  vectors (as :func:`cast_rays` expects).
* Only *entering* (front-face) hits count: a ray whose origin lies inside a shape
  (or which starts past ``min_range`` inside it) does not see that shape at all -- its
  back faces are ignored. A sensor buried in its own robot body therefore does not
  see the body; use ``exclude_owner`` / ``include`` to skip a robot's parts anyway
  (cheaper, and also right for parts that do *not* contain the sensor).
* A ray grazing a face exactly (parallel to it, in its plane) is a miss.
* Normals are world-frame, unit, outward, of the surface that was hit.
* Misses: distance ``inf``, shape index ``-1``, normal ``(0, 0, 0)``.
"""
from __future__ import annotations

from functools import cached_property
from typing import Sequence

import numpy as np

from plant.shapes import Shape

__all__ = [
    "Scene",
    "ShapeList",
    "cast_rays",
    "cast_distances",
    "cast_elements",
    "cast_sectors",
    "quadratic_roots",
    "shape_params",
    "local_half_extents",
]


def quadratic_roots(a, b_half, c):
    """Roots of ``a t^2 + 2 b_half t + c = 0`` (a > 0), ordered; nan where none.

    Numerically stable form (no cancellation in either root). Call inside
    ``np.errstate(all="ignore")`` if some a may be 0 or the discriminant negative."""
    sq = np.sqrt(b_half * b_half - a * c)            # nan where no real root
    q = -(b_half + np.copysign(sq, b_half))
    r1 = q / a
    r2 = c / q
    return np.minimum(r1, r2), np.maximum(r1, r2)    # nan propagates: a miss


def shape_params(shape: Shape) -> tuple[float, ...]:
    """Size parameters: box half extents; cylinder (radius, half height); sphere (r,)."""
    if shape.kind == "box":
        return tuple(0.5 * float(v) for v in shape.size)
    if shape.kind == "cylinder":
        return (float(shape.size[0]), 0.5 * float(shape.size[1]))
    return (float(shape.size[0]),)


def local_half_extents(shape: Shape) -> np.ndarray:
    """Half extents of the shape's local bounding box."""
    if shape.kind == "box":
        return 0.5 * np.asarray(shape.size, dtype=float)
    if shape.kind == "cylinder":
        r, h = shape.size
        return np.array([r, r, 0.5 * h], dtype=float)
    r = float(shape.size[0])
    return np.array([r, r, r])


def _half_tuple(shape: Shape) -> tuple[float, float, float]:
    size = shape.size
    if shape.kind == "box":
        return (0.5 * size[0], 0.5 * size[1], 0.5 * size[2])
    if shape.kind == "cylinder":
        return (size[0], size[0], 0.5 * size[1])
    return (size[0], size[0], size[0])


_QUADRIC = {"box": (0.0, 0.0, 0.0), "cylinder": (1.0, 1.0, 0.0), "sphere": (1.0, 1.0, 1.0)}


class ShapeList(list):
    """A list of shapes that knows its world's :class:`Scene` as built once (``template``,
    the same shapes in the same order) and where its moving shapes are now: the shapes
    from ``first_moving`` on stand at ``moving_poses`` ((D, 4, 4), their poses)."""

    def __init__(self, shapes, template: "Scene", first_moving: int, moving_poses: np.ndarray):
        super().__init__(shapes)
        self.template = template
        self.first_moving = first_moving
        self.moving_poses = moving_poses


class Scene:
    """Shapes stacked into arrays for batched casting (build once per tick and share
    between sensors; ``cast_rays`` also accepts a plain list and builds one).

    Every primitive is centred on its pose origin. Arrays, (S, ...) each:
    ``centers``, ``rotations`` (shape->world), ``halves`` (local bounding-box half
    extents), ``radii`` (bounding spheres), ``quad`` / ``rr`` (the quadric), ``owners``.

    A :class:`ShapeList` (what :meth:`plant.sim.Simulation.shapes` returns) carries the
    world's scene as it was built once (its ``template``): then only the poses of its
    moving shapes are stacked anew, the rest is shared, the same values; :meth:`placed` does
    so from the poses' (D, 4, 4) array alone (a tick's scene: :meth:`plant.sim.Simulation.scene`).
    """

    def __init__(self, shapes: Sequence[Shape]):
        self._shapes = list(shapes)
        tpl = getattr(shapes, "template", None)
        if tpl is not None and len(tpl) == len(self._shapes):
            self._place(tpl, shapes.first_moving, shapes.moving_poses)
            return
        n = len(self._shapes)
        self.owners = np.array([s.owner for s in self._shapes], dtype=object)
        self._owner_ids: dict[str, int] = {}
        self.owner_ids = np.array([self._owner_ids.setdefault(s.owner, len(self._owner_ids))
                                   for s in self._shapes], dtype=np.int64).reshape(n)
        poses = np.array([s.pose for s in self._shapes], dtype=float).reshape(n, 4, 4)
        self.centers = np.ascontiguousarray(poses[:, :3, 3])
        self.rotations = np.ascontiguousarray(poses[:, :3, :3])
        self.halves = np.array([_half_tuple(s) for s in self._shapes], dtype=float).reshape(n, 3)
        self.radii = np.sqrt((self.halves * self.halves).sum(axis=1))
        self.quad = np.array([_QUADRIC[s.kind] for s in self._shapes], dtype=float).reshape(n, 3)
        # box: 0 <= 1 always holds (the quadric never bounds it); else radius^2
        self.rr = np.where(self.quad[:, 0] > 0, self.halves[:, 0] ** 2, 1.0)
        self._const_ptrs = None
        #: the shapes' colours, as a key (the camera's colour table is cached on it)
        self.colors = tuple(tuple(float(c) for c in s.color) for s in self._shapes)

    @classmethod
    def placed(cls, template: "Scene", first: int, poses: np.ndarray) -> "Scene":
        """``template`` with its shapes ``first`` .. ``first + D - 1`` at ``poses`` ((D, 4, 4)),
        the others where they are in it, no :class:`Shape` made (:attr:`shapes` makes them
        if asked). All but the centres and rotations is the template's, shared."""
        scene = cls.__new__(cls)
        scene._shapes = None
        scene._place(template, first, poses)
        return scene

    def _place(self, tpl: "Scene", first: int, poses: np.ndarray) -> None:
        d = len(poses)
        if not 0 <= first <= first + d <= len(tpl.centers):
            raise ValueError(f"{d} poses from shape {first} do not fit {len(tpl.centers)} shapes")
        self._lazy = (tpl, first, d)
        self.owners, self._owner_ids, self.owner_ids = tpl.owners, tpl._owner_ids, tpl.owner_ids
        self.halves, self.radii, self.quad, self.rr = tpl.halves, tpl.radii, tpl.quad, tpl.rr
        self._const_ptrs = tpl.const_ptrs()
        self.colors = tpl.colors
        self.centers = tpl.centers.copy()
        self.centers[first:first + d] = poses[:, :3, 3]
        self.rotations = tpl.rotations.copy()
        self.rotations[first:first + d] = poses[:, :3, :3]

    @property
    def shapes(self) -> list[Shape]:
        """The scene's shapes as objects (a :meth:`placed` scene's made on the first call)."""
        if self._shapes is None:
            tpl, first, d = self._lazy
            poses = np.zeros((d, 4, 4))
            poses[:, :3, :3], poses[:, 3, 3] = self.rotations[first:first + d], 1.0
            poses[:, :3, 3] = self.centers[first:first + d]
            self._shapes = tpl.shapes[:first] + [
                Shape.placed(s.kind, s.size, pose, s.color, s.name, s.owner)
                for s, pose in zip(tpl.shapes[first:first + d], poses)] + tpl.shapes[first + d:]
        return self._shapes

    def __getstate__(self) -> dict:
        """Pickled without the arrays' addresses (they mean nothing in another process)."""
        state = self.__dict__.copy()
        state["_const_ptrs"] = None
        return state

    def const_ptrs(self) -> tuple[int, int, int, int, int]:
        """Addresses of halves, quad, rr, radii, owner_ids (for the C kernels)."""
        if self._const_ptrs is None:
            self._const_ptrs = tuple(a.ctypes.data for a in (self.halves, self.quad, self.rr,
                                                              self.radii, self.owner_ids))
        return self._const_ptrs

    def kernel_arrays(self) -> tuple[int, ...]:
        """Addresses of (centers, rotations, halves, quad, rr, radii, owner_ids), the
        scene as plant/kernels/lidar.c reads it (the arrays live as long as the scene)."""
        h, q, rr, radii, owners = self.const_ptrs()
        return (self.centers.ctypes.data, self.rotations.ctypes.data, h, q, rr, radii, owners)

    # the same as contiguous columns, for cast_elements' gathers: rot_cols[j][k] = R[j, k]
    @cached_property
    def rot_cols(self):
        return [[np.ascontiguousarray(self.rotations[:, j, k]) for k in range(3)]
                for j in range(3)]

    @cached_property
    def center_cols(self):
        return [np.ascontiguousarray(self.centers[:, j]) for j in range(3)]

    @cached_property
    def half_cols(self):
        return [np.ascontiguousarray(self.halves[:, k]) for k in range(3)]

    @classmethod
    def from_shapes(cls, shapes: "Sequence[Shape] | Scene") -> "Scene":
        return shapes if isinstance(shapes, Scene) else cls(shapes)

    def __len__(self) -> int:
        return len(self.centers)

    def owner_id(self, owner: str) -> int:
        """The number ``owner_ids`` holds for the shapes of ``owner`` (-2 if it has none)."""
        return self._owner_ids.get(owner, -2)

    def include_mask(self, exclude_owner: str | None = None, include=None) -> np.ndarray:
        """Boolean mask over shapes: ``include`` (bool mask or index list; None = all)
        minus every shape whose ``owner == exclude_owner`` (when not None/empty)."""
        n = len(self)
        if include is None:
            mask = np.ones(n, dtype=bool)
        else:
            inc = np.asarray(include)
            if inc.dtype == bool:
                if inc.shape != (n,):
                    raise ValueError(f"include mask has shape {inc.shape}, expected ({n},)")
                mask = inc.copy()
            else:
                mask = np.zeros(n, dtype=bool)
                mask[inc.astype(np.intp)] = True
        if exclude_owner:
            mask &= self.owners != exclude_owner
        return mask


def _slab(o, d, h):
    """Interval of t with |o + t d| <= h. d == 0: (-inf, inf) inside, empty outside."""
    inv = 1.0 / d                       # +-inf on zero components (sign of zero kept)
    t1 = (-h - o) * inv
    t2 = (h - o) * inv
    # fmin/fmax drop the nan of 0*inf (ray parallel to and exactly on a face plane):
    # the interval collapses to +-inf, i.e. a grazing ray misses.
    return np.fmin(t1, t2), np.fmax(t1, t2)


def _clip_to_quadrics(quad, rr, d_local, o_local, tn, tf) -> np.ndarray:
    """Narrow the slabs' entry ``tn`` and exit ``tf`` (S, N) by each round shape's quadric
    a t^2 + 2 b t + c <= 0 (in place; only the rows of round shapes: boxes have none);
    the quadric's entry per shape and ray (-inf where it has none)."""
    dx, dy, dz = d_local
    ox, oy, oz = o_local
    q0 = np.full(tn.shape, -np.inf)
    rnd = np.nonzero(quad[:, 0] > 0)[0]
    if rnd.size:
        qx, qy, qz = quad[rnd, 0:1], quad[rnd, 1:2], quad[rnd, 2:3]
        rdx, rdy, rdz = dx[rnd], dy[rnd], dz[rnd]
        rox, roy, roz = ox[rnd], oy[rnd], oz[rnd]
        a = qx * rdx * rdx + qy * rdy * rdy + qz * rdz * rdz
        b = qx * rox * rdx + qy * roy * rdy + qz * roz * rdz
        c = qx * rox * rox + qy * roy * roy + qz * roz * roz - rr[rnd, None]
        r0, r1 = quadratic_roots(a, b, c)
        flat = a == 0.0                   # rays along a cylinder's axis
        if flat.any():
            inside = np.broadcast_to(c < 0.0, flat.shape)
            r0 = np.where(flat, np.where(inside, -np.inf, np.nan), r0)
            r1 = np.where(flat, np.where(inside, np.inf, np.nan), r1)
        tn[rnd] = np.maximum(tn[rnd], r0)  # nan propagates: a miss
        tf[rnd] = np.minimum(tf[rnd], r1)
        q0[rnd] = r0
    return q0


def _entry_normals(ks, rows, tr, d_local, o_local, entries, quad, rot) -> np.ndarray:
    """World-frame unit normals (R, 3) where the rays ``rows`` enter their nearest shapes
    ``ks`` at ``tr``: the quadric's if it set the entry, else the slab's that did."""
    dx, dy, dz = d_local
    ox, oy, oz = o_local
    lo_x, lo_y, q0 = entries
    orow = rows if ox.shape[1] > 1 else 0
    ddx, ddy, ddz = dx[ks, rows], dy[ks, rows], dz[ks, rows]
    px = ox[ks, orow] + tr * ddx
    py = oy[ks, orow] + tr * ddy
    pz = oz[ks, orow] + tr * ddz
    on_q = tr == q0[ks, rows]
    selx = ~on_q & (tr == lo_x[ks, rows])
    sely = ~on_q & ~selx & (tr == lo_y[ks, rows])
    selz = ~on_q & ~selx & ~sely
    qk = quad[ks]
    nx = np.where(on_q, qk[:, 0] * px, np.where(selx, -np.sign(ddx), 0.0))
    ny = np.where(on_q, qk[:, 1] * py, np.where(sely, -np.sign(ddy), 0.0))
    nz = np.where(on_q, qk[:, 2] * pz, np.where(selz, -np.sign(ddz), 0.0))
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    rk = rot[ks]                                                          # (R, 3, 3)
    return (rk[:, :, 0] * (nx / norm)[:, None] + rk[:, :, 1] * (ny / norm)[:, None]
            + rk[:, :, 2] * (nz / norm)[:, None])


def cast_rays(origins, directions, shapes: "Sequence[Shape] | Scene",
              max_range: float = np.inf, *, min_range: float = 0.0,
              exclude_owner: str | None = None, include=None):
    """Cast N rays against the shapes; nearest entering hit per ray.

    origins: (N, 3), or (3,) / (1, 3) for one origin shared by all rays (faster);
    directions: (N, 3), world frame, unit for ``distances`` to be metres. Hits with
    ``t < min_range`` (the ray starts there: a shape straddling that point is entered
    "from inside" and ignored) or ``t > max_range`` are misses.
    ``exclude_owner``: skip shapes of that owner (a robot's sensors pass the robot's
    name). ``include``: bool mask (len(shapes)) or index list of shapes to consider
    (combined with ``exclude_owner``).

    Returns ``(distances (N,), shape_index (N,) int, normals (N, 3))``: ``inf``,
    ``-1``, zeros where nothing is hit; shape_index indexes the given list.
    """
    scene = Scene.from_shapes(shapes)
    d = np.atleast_2d(np.asarray(directions, dtype=float))
    o = np.atleast_2d(np.asarray(origins, dtype=float))
    if o.shape[0] != 1 and o.shape[0] != d.shape[0]:
        if d.shape[0] != 1:
            raise ValueError(f"origins {o.shape} and directions {d.shape} do not match")
        d = np.broadcast_to(d, o.shape)
    n_rays = d.shape[0]
    best_t = np.full(n_rays, np.inf)
    best_i = np.full(n_rays, -1, dtype=np.intp)
    best_n = np.zeros((n_rays, 3))
    if n_rays == 0 or len(scene) == 0:
        return best_t, best_i, best_n
    idx = np.nonzero(scene.include_mask(exclude_owner, include))[0]
    if idx.size == 0:
        return best_t, best_i, best_n
    rot, pos, half = scene.rotations[idx], scene.centers[idx], scene.halves[idx]
    quad, rr = scene.quad[idx], scene.rr[idx]
    s = idx.size
    with np.errstate(all="ignore"):
        # local frame: p_local = R^T (p - c), component k = sum_j p_j R[j, k], summed in
        # the order cast_elements uses (so the lidar's casts match these bit for bit)
        dx, dy, dz = (d[None, :, 0] * rot[:, 0, k, None] + d[None, :, 1] * rot[:, 1, k, None]
                      + d[None, :, 2] * rot[:, 2, k, None] for k in range(3))  # (S, N)
        rel = o[None, :, :] - pos[:, None, :]                                 # (S, No, 3)
        ox, oy, oz = (rel[:, :, 0] * rot[:, 0, k, None] + rel[:, :, 1] * rot[:, 1, k, None]
                      + rel[:, :, 2] * rot[:, 2, k, None] for k in range(3))  # (S, No)
        lo_x, tf = _slab(ox, dx, half[:, 0:1])
        lo_y, hi = _slab(oy, dy, half[:, 1:2])
        np.minimum(tf, hi, out=tf)
        lo_z, hi = _slab(oz, dz, half[:, 2:3])
        np.minimum(tf, hi, out=tf)
        tn = np.maximum(np.maximum(lo_x, lo_y), lo_z)
        q0 = _clip_to_quadrics(quad, rr, (dx, dy, dz), (ox, oy, oz), tn, tf)
        hit = (tn <= tf) & (tn >= min_range) & (tn <= max_range)
        tn[~hit] = np.inf
        t = tn
        k = np.argmin(t, axis=0)                                              # (N,)
        cols = np.arange(n_rays)
        tk = t[k, cols]
        rows = np.nonzero(np.isfinite(tk))[0]
        if rows.size == 0:
            return best_t, best_i, best_n
        ks = k[rows]
        tr = tk[rows]
        nw = _entry_normals(ks, rows, tr, (dx, dy, dz), (ox, oy, oz), (lo_x, lo_y, q0),
                            quad, rot)
    best_t[rows] = tr
    best_i[rows] = idx[ks]
    best_n[rows] = nw
    return best_t, best_i, best_n


def cast_distances(origin, directions, shapes: "Sequence[Shape] | Scene",
                   max_range: float = np.inf, *, exclude_owner: str | None = None,
                   include=None) -> np.ndarray:
    """Distances only, for rays sharing one origin: ``cast_rays(...)[0]`` (same hits, same
    conventions, ``min_range`` 0, the same bits) without the shape indices and normals:
    every ray against every included shape through :func:`cast_elements`."""
    scene = Scene.from_shapes(shapes)
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    o = np.asarray(origin, dtype=float).reshape(1, 3)
    if d.shape[0] == 0 or len(scene) == 0:
        return np.full(d.shape[0], np.inf)
    kept = np.nonzero(scene.include_mask(exclude_owner, include))[0]
    n = d.shape[0]
    shape, ray = np.repeat(kept, n), np.tile(np.arange(n), kept.size)
    return cast_elements(o, d[None], scene, np.zeros_like(shape), shape, ray, max_range)[0]


def cast_elements(origins: np.ndarray, directions: np.ndarray, scene: Scene, fan: np.ndarray,
                  shape: np.ndarray, ray: np.ndarray, max_range: float = np.inf) -> np.ndarray:
    """Nearest hit per ray of G fans, testing only the listed (fan, shape, ray) elements.

    Fan g has n rays from ``origins[g]`` (G, 3) along ``directions[g]`` (G, n, 3); element
    e tests ray ``ray[e]`` of fan ``fan[e]`` against shape ``shape[e]``. Returns (G, n)
    distances, ``inf`` where no listed element hits; conventions of
    :func:`cast_distances`. A caller that lists only the rays a shape can meet (a lidar
    knows each shape's bearing) does a fraction of the work of every ray against every
    shape, and each element's result depends on nothing else: a fan gives the same bits
    alone or in a batch."""
    g_n, n = directions.shape[0], directions.shape[1]
    out = np.full(g_n * n, np.inf)
    if fan.size == 0:
        return out.reshape(g_n, n)
    # gathers of contiguous per-component columns: elementwise work on contiguous arrays
    rot = [[scene.rot_cols[j][k][shape] for k in range(3)] for j in range(3)]   # R[j][k] (E,)
    ray_at = fan * n + ray
    d = [np.ascontiguousarray(directions[:, :, j]).reshape(-1)[ray_at] for j in range(3)]
    o = [origins[fan, j] - scene.center_cols[j][shape] for j in range(3)]
    with np.errstate(all="ignore"):
        # local frame, p_local = R^T p: component k = sum_j p_j R[j, k] (as cast_rays sums)
        dl = [d[0] * rot[0][k] + d[1] * rot[1][k] + d[2] * rot[2][k] for k in range(3)]
        ol = [o[0] * rot[0][k] + o[1] * rot[1][k] + o[2] * rot[2][k] for k in range(3)]
        tn = tf = None
        for k in range(3):
            h = scene.half_cols[k][shape]
            inv = np.divide(1.0, dl[k])
            t1 = (-h - ol[k]) * inv
            t2 = (h - ol[k]) * inv
            lo, hi = np.fmin(t1, t2), np.fmax(t1, t2)
            tn = lo if tn is None else np.maximum(tn, lo)
            tf = hi if tf is None else np.minimum(tf, hi)
        rnd = np.nonzero(scene.quad[shape, 0] > 0)[0]
        if rnd.size:
            q = [scene.quad[shape[rnd], k] for k in range(3)]
            dr = [v[rnd] for v in dl]
            orr = [v[rnd] for v in ol]
            a = q[0] * dr[0] * dr[0] + q[1] * dr[1] * dr[1] + q[2] * dr[2] * dr[2]
            b = q[0] * dr[0] * orr[0] + q[1] * dr[1] * orr[1] + q[2] * dr[2] * orr[2]
            c = (q[0] * orr[0] * orr[0] + q[1] * orr[1] * orr[1] + q[2] * orr[2] * orr[2]
                 - scene.rr[shape[rnd]])
            _clip_round(tn, tf, rnd, a, b, c)
        hit = (tn <= tf) & (tn >= 0.0) & (tn <= max_range)
    np.minimum.at(out, ray_at[hit], tn[hit])
    return out.reshape(g_n, n)


def _clip_round(tn: np.ndarray, tf: np.ndarray, rnd: np.ndarray, a: np.ndarray,
                b: np.ndarray, c: np.ndarray) -> None:
    """Narrow the entry/exit distances ``tn``/``tf`` of the elements ``rnd`` (rays against
    round shapes) to the quadric ``a t^2 + 2 b t + c <= 0``, in place."""
    r0, r1 = quadratic_roots(a, b, c)
    flat = a == 0.0                   # rays along a cylinder's axis
    if flat.any():
        r0 = np.where(flat, np.where(c < 0.0, -np.inf, np.nan), r0)
        r1 = np.where(flat, np.where(c < 0.0, np.inf, np.nan), r1)
    tn[rnd] = np.maximum(tn[rnd], r0)  # nan propagates: a miss
    tf[rnd] = np.minimum(tf[rnd], r1)


def cast_sectors(origins: np.ndarray, directions: np.ndarray, scene: Scene, fan: np.ndarray,
                 shape: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 max_range: float = np.inf) -> np.ndarray:
    """:func:`cast_elements` of the elements (fan[p], shape[p], ray) for ray in lo[p]..hi[p]
    of each pair p: the same bits, with what depends only on the pair (the origin in the
    shape's frame, its half extents, its rotation) computed once per pair, not per ray."""
    g_n, n = directions.shape[0], directions.shape[1]
    out = np.full(g_n * n, np.inf)
    if fan.size == 0:
        return out.reshape(g_n, n)
    count = hi - lo + 1
    total = int(count.sum())
    pair = np.repeat(np.arange(fan.size), count)
    ray_at = np.repeat(fan * n + lo - (np.cumsum(count) - count), count) + np.arange(total)
    rot = scene.rotations[shape]                                               # (P, 3, 3)
    o = origins[fan] - scene.centers[shape]                                    # (P, 3)
    dflat = directions.reshape(-1, 3)
    d = [np.ascontiguousarray(dflat[ray_at, j]) for j in range(3)]
    with np.errstate(all="ignore"):
        # local frame, p_local = R^T p: component k = sum_j p_j R[j, k] (as cast_rays sums)
        rk = [[np.ascontiguousarray(rot[:, j, k])[pair] for k in range(3)] for j in range(3)]
        dl = [d[0] * rk[0][k] + d[1] * rk[1][k] + d[2] * rk[2][k] for k in range(3)]
        olp = o[:, 0:1] * rot[:, 0] + o[:, 1:2] * rot[:, 1] + o[:, 2:3] * rot[:, 2]  # (P, 3)
        half = scene.halves[shape]
        tn = tf = None
        for k in range(3):
            ol, h = olp[:, k], half[:, k]
            inv = np.divide(1.0, dl[k])
            t1 = (-h - ol)[pair] * inv
            t2 = (h - ol)[pair] * inv
            lo_k, hi_k = np.fmin(t1, t2), np.fmax(t1, t2, out=t2)
            tn = lo_k if tn is None else np.maximum(tn, lo_k, out=tn)
            tf = hi_k if tf is None else np.minimum(tf, hi_k, out=tf)
        round_pairs = scene.quad[shape, 0] > 0
        if round_pairs.any():
            rnd = np.nonzero(round_pairs[pair])[0]
            q = scene.quad[shape][pair[rnd]]
            dr = [v[rnd] for v in dl]
            orr = [olp[pair[rnd], k] for k in range(3)]
            a = q[:, 0] * dr[0] * dr[0] + q[:, 1] * dr[1] * dr[1] + q[:, 2] * dr[2] * dr[2]
            b = q[:, 0] * dr[0] * orr[0] + q[:, 1] * dr[1] * orr[1] + q[:, 2] * dr[2] * orr[2]
            c = (q[:, 0] * orr[0] * orr[0] + q[:, 1] * orr[1] * orr[1]
                 + q[:, 2] * orr[2] * orr[2] - scene.rr[shape][pair[rnd]])
            _clip_round(tn, tf, rnd, a, b, c)
        hit = (tn <= tf) & (tn >= 0.0) & (tn <= max_range)
    np.minimum.at(out, ray_at[hit], tn[hit])
    return out.reshape(g_n, n)
