"""Ray casting and the planar lidar against analytic distances."""
from __future__ import annotations

import math

import numpy as np
import pytest

from plant.lidar import LidarConfig, apply_noise, measure, scan, scan_many, sensor_pose
from plant.noise import NoiseModel, stream_key, webots_lidar
from plant.raycast import Scene, cast_distances, cast_rays
from plant.shapes import Shape, pose_matrix

ROBOT = "robot1"
SCAN_Z = 0.25  # lidar height for a robot standing at z = 0 with the default mount


# ----------------------------------------------------------------------------------
# Test world: a 8 x 6 m room (inner faces x = +-4, y = +-3) with a 3 m opening in the
# y = +3 wall, a yawed box, a cylinder, a sphere, a second robot, our robot's parts.
# ----------------------------------------------------------------------------------

def _room() -> list[Shape]:
    t, hgt = 0.2, 1.0
    s = [Shape("box", (20.0, 20.0, 0.1), pose_matrix(0, 0, -0.05), name="floor")]
    ew = (t, 6.0 + 2 * t, hgt)
    s.append(Shape("box", ew, pose_matrix(4 + t / 2, 0, hgt / 2), name="wall_e"))
    s.append(Shape("box", ew, pose_matrix(-4 - t / 2, 0, hgt / 2), name="wall_w"))
    s.append(Shape("box", (8.0, t, hgt), pose_matrix(0, -3 - t / 2, hgt / 2), name="wall_s"))
    # north wall with an opening from x = -1 to x = 2
    s.append(Shape("box", (3.0, t, hgt), pose_matrix(-2.5, 3 + t / 2, hgt / 2), name="wall_n1"))
    s.append(Shape("box", (2.0, t, hgt), pose_matrix(3.0, 3 + t / 2, hgt / 2), name="wall_n2"))
    s.append(Shape("box", (0.6, 0.4, 0.5), pose_matrix(2.0, -1.2, 0.25, yaw=0.4),
                   (0.2, 0.2, 0.9), name="box"))
    s.append(Shape("cylinder", (0.25, 0.8), pose_matrix(2.5, 1.0, 0.4), (0.9, 0.1, 0.1),
                   name="cyl"))
    s.append(Shape("sphere", (0.35,), pose_matrix(-1.5, -1.0, 0.3), (0.1, 0.9, 0.1), name="ball"))
    # another robot: seen by ours
    s.append(Shape("box", (0.4, 0.3, 0.4), pose_matrix(-2.0, 1.5, 0.2, yaw=-0.7), name="body",
                   owner="robot2"))
    return s


def _own_parts(robot_pose: np.ndarray) -> list[Shape]:
    """Our robot: a body around the lidar's foot, a lidar housing around its origin and a
    mast right in front of it, all in the scan plane unless excluded."""
    parts = [
        Shape("box", (0.5, 0.4, 0.3), pose_matrix(0.0, 0.0, 0.15), name="body"),
        Shape("cylinder", (0.04, 0.1), pose_matrix(0.15, 0.0, 0.25), name="lidar_housing"),
        Shape("cylinder", (0.02, 0.6), pose_matrix(0.3, 0.05, 0.3), name="mast"),
        Shape("sphere", (0.05,), pose_matrix(0.15, -0.12, 0.25), name="knob"),
    ]
    for p in parts:
        p.pose = robot_pose @ p.pose
        p.owner = ROBOT
    return parts


# ---------------------------- independent 2-D reference ---------------------------

def _ray_segment(o, d, a, b):
    """2-D ray (o + t d) vs segment a-b; t or inf."""
    e = b - a
    den = d[0] * (-e[1]) - d[1] * (-e[0])
    if abs(den) < 1e-15:
        return math.inf
    w = a - o
    t = (w[0] * (-e[1]) - w[1] * (-e[0])) / den
    s = (d[0] * w[1] - d[1] * w[0]) / den
    return t if (t >= 0 and 0 <= s <= 1) else math.inf


def _ray_circle(o, d, c, r):
    w = o - c
    b = w @ d
    cc = w @ w - r * r
    disc = b * b - cc
    if disc < 0 or cc < 0:       # miss, or origin inside
        return math.inf
    t = -b - math.sqrt(disc)
    return t if t >= 0 else math.inf


def _expected_ranges(origin3, yaw, angles, shapes, max_range, min_range, skip_owner):
    o = np.asarray(origin3[:2], float)
    z = origin3[2]
    out = []
    for ang in angles:
        d = np.array([math.cos(yaw + ang), math.sin(yaw + ang)])
        best = math.inf
        for s in shapes:
            if s.owner == skip_owner:
                continue
            c = s.pose[:3, 3]
            if s.kind == "box":
                lx, ly, lz = s.size
                if not (c[2] - lz / 2 <= z <= c[2] + lz / 2):
                    continue
                syaw = math.atan2(s.pose[1, 0], s.pose[0, 0])
                ux = np.array([math.cos(syaw), math.sin(syaw)]) * lx / 2
                uy = np.array([-math.sin(syaw), math.cos(syaw)]) * ly / 2
                corners = [c[:2] + ux + uy, c[:2] - ux + uy, c[:2] - ux - uy, c[:2] + ux - uy]
                for i in range(4):
                    best = min(best, _ray_segment(o, d, corners[i], corners[(i + 1) % 4]))
            elif s.kind == "cylinder":
                r, h = s.size
                if c[2] - h / 2 <= z <= c[2] + h / 2:
                    best = min(best, _ray_circle(o, d, c[:2], r))
            else:
                (r,) = s.size
                dz = z - c[2]
                if abs(dz) < r:
                    best = min(best, _ray_circle(o, d, c[:2], math.sqrt(r * r - dz * dz)))
        if best > max_range or best < min_range:
            best = math.inf
        out.append(best)
    return np.array(out)


# -------------------------------------- tests --------------------------------------

def test_default_config_is_lms291():
    cfg = LidarConfig()
    a = cfg.angles()
    assert cfg.num_rays == 180 and len(a) == 180
    assert a[0] == pytest.approx(-math.pi / 2) and a[-1] == pytest.approx(math.pi / 2)
    assert cfg.angle_min == pytest.approx(-math.pi / 2)
    assert cfg.angle_increment == pytest.approx(math.pi / 179)
    assert np.allclose(np.diff(a), math.pi / 179)
    assert cfg.max_range_m == 80.0


@pytest.mark.parametrize("robot_xyyaw", [(0.3, -0.2, 0.3), (-0.5, 0.4, 2.2), (1.0, 0.0, -1.3)])
def test_scan_matches_analytic_distances(robot_xyyaw):
    x, y, yaw = robot_xyyaw
    robot = pose_matrix(x, y, 0.0, yaw=yaw)
    world = _room() + _own_parts(robot)
    cfg = LidarConfig()
    ranges = scan(cfg, robot, world, exclude_owner=ROBOT)
    origin = sensor_pose(cfg, robot)[:3, 3]
    assert origin[2] == pytest.approx(SCAN_Z)
    expected = _expected_ranges(origin, yaw + cfg.mount_yaw_rad, cfg.angles(), world,
                                cfg.max_range_m, cfg.min_range_m, ROBOT)
    assert np.array_equal(np.isinf(ranges), np.isinf(expected))
    fin = np.isfinite(expected)
    assert fin.sum() > 100
    assert np.max(np.abs(ranges[fin] - expected[fin])) < 1e-6


def test_culling_does_not_change_the_scan():
    # scan() culls shapes off the scan plane / out of the fan before casting; with the
    # robot tilted and turned, the result equals casting every ray at every shape
    rng = np.random.default_rng(11)
    world = _room()
    cfg = LidarConfig(fov_rad=4.0, num_rays=90)
    for _ in range(10):
        robot = pose_matrix(*rng.uniform(-2, 2, 2), rng.uniform(0, 0.3),
                            *rng.uniform(-0.3, 0.3, 2), rng.uniform(-math.pi, math.pi))
        pose = sensor_pose(cfg, robot)
        a = np.linspace(-2.0, 2.0, 90)
        dirs = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1) @ pose[:3, :3].T
        want, _, _ = cast_rays(pose[:3, 3], dirs, world, max_range=cfg.max_range_m)
        want[want < cfg.min_range_m] = np.inf
        assert np.array_equal(scan(cfg, robot, world), want)


@pytest.mark.parametrize("fov", [1.5 * math.pi, 2.0 * math.pi])
def test_many_lidars_at_once_scan_what_each_alone_and_every_ray_at_every_shape_do(fov):
    """A swarm's scans in one pass (scan_many, each shape tried only on the rays of its
    bearing sector): row for row the bits of scan() alone and of casting every ray at
    every shape, robots seeing each other, tilted, near walls, with a full-circle fan
    (its sector seam) too."""
    rng = np.random.default_rng(5)
    cfg = LidarConfig(fov_rad=fov, num_rays=72, max_range_m=6.0, mount_z_m=0.2)
    names = [f"r{i}" for i in range(7)]
    poses = [pose_matrix(*rng.uniform(-3.5, 3.5, 1), *rng.uniform(-2.5, 2.5, 1),
                         rng.uniform(0, 0.05), *rng.uniform(-0.1, 0.1, 2),
                         rng.uniform(-math.pi, math.pi)) for _ in names]
    poses[1] = pose_matrix(3.85, 0.0, 0.0, yaw=0.2)            # its lidar against a wall
    world = [s for s in _room() if s.owner != "robot2"]
    for name, pose in zip(names, poses):
        for part in (Shape("box", (0.4, 0.3, 0.3), pose_matrix(0, 0, 0.15)),
                     Shape("sphere", (0.1,), pose_matrix(0.05, 0.16, 0.1)),
                     Shape("cylinder", (0.05, 0.5), pose_matrix(-0.15, 0, 0.25))):
            world.append(Shape(part.kind, part.size, pose @ part.pose, name=name, owner=name))
    scene = Scene(world)
    got = scan_many(cfg, poses, scene, names)
    a = np.linspace(-fov / 2, fov / 2, cfg.num_rays)
    for g, (name, pose) in enumerate(zip(names, poses)):
        assert np.array_equal(got[g], scan(cfg, pose, scene, exclude_owner=name))
        sp = sensor_pose(cfg, pose)
        dirs = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1) @ sp[:3, :3].T
        want, _, _ = cast_rays(sp[:3, 3], dirs, world, max_range=cfg.max_range_m,
                               exclude_owner=name)
        want[want < cfg.min_range_m] = np.inf
        assert np.array_equal(got[g], want)
    assert np.isfinite(got).mean() > 0.5
    assert np.all(np.isinf(scan_many(cfg, poses, Scene([]), names)))


def test_rays_through_the_opening_hit_nothing():
    robot = pose_matrix(0.3, -0.2, 0.0, yaw=0.3)
    ranges = scan(LidarConfig(), robot, _room(), exclude_owner=ROBOT)
    assert np.isinf(ranges).sum() >= 5
    assert np.all(ranges[np.isfinite(ranges)] > 0)


def test_own_robot_is_not_seen():
    robot = pose_matrix(0.3, -0.2, 0.0, yaw=0.3)
    cfg = LidarConfig()
    bare = scan(cfg, robot, _room(), exclude_owner=ROBOT)
    with_parts = scan(cfg, robot, _room() + _own_parts(robot), exclude_owner=ROBOT)
    assert np.array_equal(bare, with_parts)
    # not excluded: the mast and the knob are seen (the housing and body contain the
    # origin, so their back faces are ignored anyway)
    seen = scan(cfg, robot, _room() + _own_parts(robot))
    assert np.sum(seen < 0.3) >= 3
    assert np.all(seen[np.isfinite(seen)] > 0.0)


def test_other_robot_is_seen():
    robot = pose_matrix(0.3, -0.2, 0.0, yaw=math.pi / 2 + 0.6)
    world = _room()
    cfg = LidarConfig()
    with_r2 = scan(cfg, robot, world, exclude_owner=ROBOT)
    without = scan(cfg, robot, [s for s in world if s.owner != "robot2"], exclude_owner=ROBOT)
    assert np.any(with_r2 < without)


def test_max_and_min_range_give_inf_and_near_objects_occlude():
    robot = np.eye(4)
    cfg = LidarConfig(max_range_m=3.0, min_range_m=0.2)
    ranges = scan(cfg, robot, _room(), exclude_owner=ROBOT)
    assert np.all(np.isinf(ranges) | (ranges <= 3.0))
    # a post 0.1 m ahead of the sensor: below min range -> inf, and the wall behind it
    # is not reported either
    post = Shape("cylinder", (0.03, 1.0), pose_matrix(cfg.mount_x_m + 0.1, 0, 0.5), name="post")
    r = scan(LidarConfig(min_range_m=0.2), robot, _room() + [post])
    mid = 90  # rays 89 and 90 straddle the x axis (+-0.5 increment)
    assert np.isinf(r[mid]) and np.isinf(r[mid - 1])
    r_free = scan(LidarConfig(min_range_m=0.2), robot, _room())
    assert np.isfinite(r_free[mid])


def test_mount_yaw_and_ray_order():
    # ray 0 is the rightmost (-y), the last the leftmost (+y): ROS LaserScan order
    wall_left = Shape("box", (10, 0.1, 1), pose_matrix(0, 2.0, 0.5))
    cfg = LidarConfig(mount_x_m=0.0, mount_z_m=0.25)
    r = scan(cfg, np.eye(4), [wall_left])
    assert r[-1] == pytest.approx(2.0 - 0.05) and np.isinf(r[0])
    cfg_yaw = LidarConfig(mount_x_m=0.0, mount_z_m=0.25, mount_yaw_rad=math.pi / 2)
    r2 = scan(cfg_yaw, np.eye(4), [wall_left])
    assert r2[89] == pytest.approx((2.0 - 0.05) / math.cos(cfg.angle_increment / 2))


def test_apply_noise_keeps_inf_and_clips():
    cfg = LidarConfig(max_range_m=10.0, min_range_m=0.1)
    true = np.array([np.inf, 0.1, 5.0, 10.0, np.inf] * 2000)
    model = NoiseModel(webots_lidar(0.05, cfg.max_range_m), stream_key(1, "robot1", "lidar"))
    out = apply_noise(cfg, true, model)
    assert np.array_equal(np.isinf(out), np.isinf(true))
    fin = np.isfinite(out)
    assert out[fin].min() >= 0.1 and out[fin].max() <= 10.0
    assert np.any(out[fin] == 10.0) and np.any(out[fin] == 0.1)
    q = apply_noise(LidarConfig(resolution_m=0.01), np.array([1.23456, np.inf]))
    assert q[0] == pytest.approx(1.23) and np.isinf(q[1])
    # the whole pipeline
    robot = pose_matrix(0.3, -0.2, 0.0, yaw=0.3)
    m = measure(LidarConfig(), robot, _room(), None, exclude_owner=ROBOT)
    assert np.array_equal(m, scan(LidarConfig(), robot, _room(), exclude_owner=ROBOT))


# ------------------------------ raycast unit tests ---------------------------------

def _inside(shape: Shape, p: np.ndarray) -> np.ndarray:
    """Point(s) (..., 3) inside the closed solid (vectorised)."""
    inv = np.linalg.inv(shape.pose)
    q = np.asarray(p) @ inv[:3, :3].T + inv[:3, 3]
    if shape.kind == "box":
        return np.all(np.abs(q) <= np.asarray(shape.size) / 2, axis=-1)
    if shape.kind == "cylinder":
        r, h = shape.size
        return (q[..., 0] ** 2 + q[..., 1] ** 2 <= r * r) & (np.abs(q[..., 2]) <= h / 2)
    return np.einsum("...i,...i->...", q, q) <= shape.size[0] ** 2


@pytest.mark.parametrize("kind,size", [("box", (0.8, 0.5, 0.3)), ("cylinder", (0.3, 0.9)),
                                       ("sphere", (0.4,))])
def test_random_rays_enter_exactly_at_the_surface(kind, size):
    rng = np.random.default_rng(7)
    for trial in range(5):
        pose = pose_matrix(*rng.uniform(-1, 1, 3), *rng.uniform(-math.pi, math.pi, 3))
        shape = Shape(kind, size, pose)
        n = 400
        origins = pose[:3, 3] + rng.normal(size=(n, 3)) * 2.0
        origins[:20] = pose[:3, 3] + rng.normal(size=(20, 3)) * 0.05   # inside
        targets = pose[:3, 3] + rng.normal(size=(n, 3)) * 0.4
        dirs = targets - origins
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        t, idx, nrm = cast_rays(origins, dirs, [shape])
        assert np.all((idx == 0) == np.isfinite(t))
        inside0 = _inside(shape, origins)
        hit = np.isfinite(t)
        assert not np.any(hit & inside0)                 # starts inside: back faces ignored
        assert hit.sum() > 50 and inside0.sum() > 0
        eps = 1e-7
        th = t[hit][:, None]
        o, d, nh = origins[hit], dirs[hit], nrm[hit]
        assert np.all(_inside(shape, o + (th + eps) * d))
        assert not np.any(_inside(shape, o + (th - eps) * d))
        assert np.allclose(np.linalg.norm(nh, axis=1), 1.0)
        assert np.all(np.einsum("ij,ij->i", nh, d) < 0)  # outward normal faces the ray
        # the normal is the surface normal: stepping along it leaves the shape
        assert not np.any(_inside(shape, o + th * d + 1e-6 * nh))
        # misses from outside: no sample along the ray is inside
        miss = ~hit & ~inside0
        ts = np.linspace(0, 6, 1201)[None, :, None]
        pts = origins[miss][:, None, :] + ts * dirs[miss][:, None, :]
        assert not np.any(_inside(shape, pts))


def test_known_hits_and_normals():
    cyl = Shape("cylinder", (0.5, 2.0), pose_matrix(3, 0, 1, roll=math.pi / 2))  # axis along -y
    box = Shape("box", (1, 1, 1), pose_matrix(0, 5, 0.5, yaw=math.pi / 4))
    sph = Shape("sphere", (1.0,), pose_matrix(0, -4, 0))
    o = np.array([[0, 0, 1], [3, 3, 1], [0, 0, 0.5], [0, 0, 0], [0, 0, 0]], float)
    d = np.array([[1, 0, 0], [0, -1, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    t, idx, n = cast_rays(o, d, [cyl, box, sph])
    assert t[0] == pytest.approx(2.5) and idx[0] == 0 and np.allclose(n[0], [-1, 0, 0])
    assert t[1] == pytest.approx(2.0) and idx[1] == 0 and np.allclose(n[1], [0, 1, 0])  # cap
    assert t[2] == pytest.approx(5 - math.sqrt(0.5)) and idx[2] == 1
    assert np.allclose(n[2], [-math.sqrt(0.5), -math.sqrt(0.5), 0])
    assert t[3] == pytest.approx(3.0) and idx[3] == 2 and np.allclose(n[3], [0, 1, 0])
    assert np.isinf(t[4]) and idx[4] == -1 and np.all(n[4] == 0)


def test_grazing_and_axis_parallel_rays():
    box = Shape("box", (2, 2, 2), pose_matrix(5, 0, 0))
    # along the face plane y = 1: a miss, no nan
    t, idx, _ = cast_rays([[0, 1, 0], [0, 0.999, 0], [0, 1.001, 0]], [[1, 0, 0]] * 3, [box])
    assert np.isinf(t[0]) and t[1] == pytest.approx(4.0) and np.isinf(t[2])
    cyl = Shape("cylinder", (1, 2), pose_matrix(0, 0, 5))
    t, idx, n = cast_rays([[0.5, 0, 0], [1.5, 0, 0]], [[0, 0, 1]] * 2, [cyl])
    assert t[0] == pytest.approx(4.0) and np.allclose(n[0], [0, 0, -1]) and np.isinf(t[1])


def test_masks_and_max_range():
    a = Shape("sphere", (0.5,), pose_matrix(2, 0, 0), owner="r1")
    b = Shape("sphere", (0.5,), pose_matrix(4, 0, 0), owner="r2")
    o, d = np.zeros((1, 3)), np.array([[1.0, 0, 0]])
    assert cast_rays(o, d, [a, b])[1][0] == 0
    assert cast_rays(o, d, [a, b], exclude_owner="r1")[1][0] == 1
    assert cast_rays(o, d, [a, b], include=[1])[1][0] == 1
    assert cast_rays(o, d, [a, b], include=np.array([False, False]))[1][0] == -1
    assert np.isinf(cast_rays(o, d, [a, b], max_range=1.0)[0][0])
    scene = Scene([a, b])
    assert cast_rays(o, d, scene, exclude_owner="r1")[0][0] == pytest.approx(3.5)
    t, i, n = cast_rays(np.zeros((0, 3)), np.zeros((0, 3)), [a])
    assert t.shape == (0,) and n.shape == (0, 3)
    t, i, n = cast_rays(o, d, [])
    assert np.isinf(t[0]) and i[0] == -1


def test_distance_only_caster_equals_the_general_one():
    # the lidar's cast_distances: the same distances as cast_rays for rays from one origin,
    # with origins inside shapes, rays along a cylinder's axis, grazing rays and max range
    rng = np.random.default_rng(5)
    kinds = [("box", (0.8, 0.5, 0.3)), ("cylinder", (0.3, 0.9)), ("sphere", (0.4,))]
    for trial in range(20):
        shapes = [Shape(k, size, pose_matrix(*rng.uniform(-2, 2, 3),
                                             *rng.uniform(-math.pi, math.pi, 3)))
                  for k, size in (kinds[i] for i in rng.integers(0, 3, 8))]
        shapes.append(Shape("cylinder", (0.5, 1.0), pose_matrix(0, 0, 3)))  # axis along z
        shapes.append(Shape("box", (1, 1, 1), pose_matrix(0, 0, -3)))
        origin = shapes[int(rng.integers(0, 8))].pose[:3, 3] if trial % 4 == 0 \
            else rng.uniform(-1, 1, 3)
        dirs = rng.normal(size=(300, 3))
        dirs[:3] = [[0, 0, 1], [0, 0, -1], [1, 0, 0]]
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        for max_range in (np.inf, 2.0):
            want = cast_rays(origin, dirs, shapes, max_range=max_range)[0]
            got = cast_distances(origin, dirs, shapes, max_range=max_range)
            assert np.array_equal(np.isinf(got), np.isinf(want))
            assert np.allclose(got, want, rtol=0, atol=1e-12)
    # one origin on a face plane, rays along it: a miss, as in cast_rays
    box = Shape("box", (2, 2, 2), pose_matrix(5, 0, 0))
    assert np.isinf(cast_distances([0, 1, 0], [[1, 0, 0]], [box])[0])
    assert cast_distances([0, 0.999, 0], [[1, 0, 0]], [box])[0] == pytest.approx(4.0)
    assert cast_distances([0, 0, 0], np.zeros((0, 3)), [box]).shape == (0,)
    assert np.isinf(cast_distances([0, 0, 0], [[1, 0, 0]], [box], include=[]))[0]
