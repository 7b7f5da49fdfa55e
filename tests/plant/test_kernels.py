"""The plant's C kernels (plant/kernels/): the lidar sweep gives the numpy reference's
ranges to the bit and the analytic ranges of a known room on every ray; the camera kernel
draws every pixel of a known scene where the geometry says; the image noise kernel gives
its numpy reference's bytes; a missing library says how to build it."""
from __future__ import annotations

import math

import numpy as np
import pytest

from plant import kernels
from plant.camera import CameraConfig, render_full
from plant.camera_reference import render_full_reference
from plant.lidar import LidarConfig, scan, scan_many, scan_many_reference, scan_worlds
from plant.noise import (NoiseConfig, NoiseModel, alias_table, frame_seed, image_noise_reference,
                         stream_key)
from plant.raycast import Scene
from plant.shapes import Shape, pose_matrix
from plant.sim import Simulation
from plant.world import load_world


def _poses(rng, base: np.ndarray, n: int, tilt: float = 0.0) -> list[np.ndarray]:
    out = []
    for _ in range(n):
        m = pose_matrix(rng.uniform(-2.5, 2.5), rng.uniform(-2.0, 2.0), rng.uniform(-0.1, 0.6),
                        roll=rng.uniform(-tilt, tilt), pitch=rng.uniform(-tilt, tilt),
                        yaw=rng.uniform(-math.pi, math.pi))
        out.append(m @ base)
    return out


@pytest.mark.parametrize("world,robot", [("living_room", "robot1"),
                                         ("living_room_follow", "follower")])
def test_lidar_kernel_gives_the_numpy_reference_to_the_bit(world, robot):
    spec = load_world(world)
    sim = Simulation(spec)
    scene = Scene(sim.shapes())
    cfg = spec.robot(robot).sensors.lidar or LidarConfig()
    rng = np.random.default_rng(7)
    for trial in range(40):
        poses = _poses(rng, np.eye(4), 6, tilt=0.4 if trial % 2 else 0.0)
        owners = [robot, None, "nobody", "", robot, "leader"]
        got = scan_many(cfg, poses, scene, owners)
        want = scan_many_reference(cfg, poses, scene, owners)
        assert got.tobytes() == want.tobytes(), trial
        assert np.isfinite(got).any()
    # a 360-degree lidar with a short range and a min range: the seam and both limits
    cfg = LidarConfig(num_rays=361, fov_rad=2 * math.pi, min_range_m=0.5, max_range_m=2.0)
    poses = _poses(rng, np.eye(4), 8)
    got = scan_many(cfg, poses, scene, [robot] * 8)
    assert got.tobytes() == scan_many_reference(cfg, poses, scene, [robot] * 8).tobytes()
    assert np.isinf(got).any() and np.isfinite(got).any()


def test_lidar_kernel_split_over_threads_gives_the_same_bits():
    """A batch's lidars cast on several threads (each a contiguous part of the fans, at
    least 8 each; parts of unequal size) are the same bits as on one, and the reference's."""
    spec = load_world("living_room")
    scene = Scene(Simulation(spec).shapes())
    cfg = spec.robot("robot1").sensors.lidar or LidarConfig()
    rng = np.random.default_rng(3)
    poses = _poses(rng, np.eye(4), 37, tilt=0.2)
    owners = ["robot1", None] * 18 + [None]
    want = scan_many_reference(cfg, poses, scene, owners)
    assert np.isfinite(want).any()
    for threads in (1, 2, 3, 4, 5, 64):
        got = scan_many(cfg, poses, scene, owners, threads)
        assert got.tobytes() == want.tobytes(), threads


def test_lidar_sweeps_of_several_worlds_in_one_call_are_each_worlds_own():
    """A batched environment's worlds: robots in different copies of a world (moved
    differently) cast in one call, each row the bits of its own world's scan."""
    spec = load_world("living_room_follow")
    sims = [Simulation(spec) for _ in range(3)]
    for k, sim in enumerate(sims):
        for _ in range(5 * k):
            sim.command_twist("leader", 0.4, 0.6 * k)
            sim.step_tick()
    scenes = [Scene(sim.shapes()) for sim in sims]
    cfg = spec.robot("follower").sensors.lidar or LidarConfig()
    rng = np.random.default_rng(3)
    world_of = [0, 1, 2, 2, 1, 0, 2]
    poses = _poses(rng, np.eye(4), len(world_of))
    owners = ["follower", "leader", None, "follower", "", "leader", "leader"]
    got = scan_worlds(cfg, scenes, poses, owners, world_of)
    for g, k in enumerate(world_of):
        want = scan_many(cfg, [poses[g]], scenes[k], [owners[g]])[0]
        assert got[g].tobytes() == want.tobytes(), g
    assert np.isfinite(got).all(axis=1).any()


def test_lidar_kernel_every_ray_of_a_square_room():
    """A sensor at (x0, y0) in a 4 m x 3 m room of walls, yawed: every ray's range is the
    distance to the first wall along it, as geometry gives it."""
    lx, ly, t = 4.0, 3.0, 0.1
    walls = [Shape("box", (t, ly + 2 * t, 1.0), pose_matrix(sx * (lx + t) / 2, 0, 0.5))
             for sx in (-1, 1)]
    walls += [Shape("box", (lx, t, 1.0), pose_matrix(0, sy * (ly + t) / 2, 0.5)) for sy in (-1, 1)]
    cfg = LidarConfig(num_rays=180, mount_x_m=0.0, mount_z_m=0.0)
    x0, y0, yaw = 0.7, -0.4, 0.3
    ranges = scan(cfg, pose_matrix(x0, y0, 0.3, yaw=yaw), Scene(walls))
    a = yaw + cfg.angles()
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (lx / 2 - x0) / c, (-lx / 2 - x0) / c)
        ty = np.where(s > 0, (ly / 2 - y0) / s, (-ly / 2 - y0) / s)
    want = np.minimum(np.where(np.isfinite(tx) & (tx > 0), tx, np.inf),
                      np.where(np.isfinite(ty) & (ty > 0), ty, np.inf))
    assert np.all(np.isfinite(ranges))
    assert np.max(np.abs(ranges - want)) < 1e-12


def test_scene_of_a_shape_list_is_the_scene_of_its_shapes():
    """Simulation.shapes() carries the world's scene stacked once; a Scene of it (only the
    moving shapes restacked) holds what a Scene of the plain list holds, after a move."""
    spec = load_world("living_room_follow")
    sim = Simulation(spec)
    for _ in range(20):
        sim.command_twist("leader", 0.3, 0.5)
        sim.step_tick()
    shapes = sim.shapes()
    fast, plain = Scene(shapes), Scene(list(shapes))
    for key in ("centers", "rotations", "halves", "radii", "quad", "rr", "owner_ids"):
        assert np.array_equal(getattr(fast, key), getattr(plain, key)), key
    assert not np.array_equal(fast.centers, Scene(sim._scene_template.shapes).centers)


def _camera_scene():
    wall = Shape("box", (0.2, 20.0, 20.0), pose_matrix(5.1, 0, 0), (0.8, 0.2, 0.2))
    ball = Shape("sphere", (0.5,), pose_matrix(3.0, 0.4, -0.2), (0.1, 0.9, 0.1))
    can = Shape("cylinder", (0.3, 1.0), pose_matrix(2.5, -0.8, 0.3, roll=0.4), (0.2, 0.2, 0.9))
    return [wall, ball, can]


def test_camera_kernel_every_pixel_of_a_known_scene():
    """A wall 5 m ahead filling the view and a sphere before it: every pixel's ray, cast
    in double by hand, says which solid it sees and how deep; the kernel agrees on every
    pixel but the few whose ray grazes the sphere."""
    cfg = CameraConfig(width=160, height=120, hfov_rad=1.2)
    shapes = _camera_scene()[:2]
    _, depth, sid = render_full(cfg, np.eye(4), shapes)
    f = 0.5 * cfg.width / math.tan(0.5 * cfg.hfov_rad)
    u, v = np.meshgrid(np.arange(cfg.width), np.arange(cfg.height))
    # optical (x right, y down, z forward) -> body (x forward, y left, z up)
    d = np.stack([np.ones_like(u, dtype=float), -(u - 79.5) / f, -(v - 59.5) / f], -1)
    oc = np.array([3.0, 0.4, -0.2])
    b = -(d @ oc)
    a = (d * d).sum(-1)
    disc = b * b - a * (oc @ oc - 0.25)
    t_ball = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
    on_ball = disc > 0
    want_sid = np.where(on_ball, 1, 0)
    want_depth = np.where(on_ball, t_ball, 5.0)        # the ray's x is 1: t is the depth
    clear = np.abs(disc) > 1e-3 * a                     # not grazing the sphere
    assert np.array_equal(sid[clear], want_sid[clear])
    assert np.max(np.abs(depth[clear] - want_depth[clear])) < 1e-5
    assert (sid == 1).sum() > 200 and clear.mean() > 0.99


def test_camera_kernel_agrees_with_the_numpy_renderer():
    cfg = CameraConfig(width=200, height=150)
    shapes = _camera_scene()
    for pose in (np.eye(4), pose_matrix(0.5, 0.3, 0.2, roll=0.1, pitch=-0.05, yaw=0.2)):
        img, depth, sid = render_full(cfg, pose, shapes)
        ref_img, ref_depth, ref_sid = render_full_reference(cfg, pose, shapes)
        same = sid == ref_sid
        assert same.mean() > 0.999                       # float32 vs double: silhouettes
        fin = same & np.isfinite(ref_depth)
        rel = np.abs(depth[fin] - ref_depth[fin]) / ref_depth[fin]
        # float32 near-tangent rays on the cylinder are ill-conditioned (as in test_camera)
        assert np.mean(rel < 1e-5) > 0.99 and rel.max() < 1e-3
        grey = np.abs(img.astype(int) - ref_img.astype(int)).max(-1)
        assert np.mean(grey[same] <= 1) == 1.0


@pytest.mark.parametrize("cfg", [NoiseConfig(std=20.0), NoiseConfig(std=7.3, bias=3.5, mean=-1.25),
                                 NoiseConfig(std=300.0), NoiseConfig(std=0.2)])
@pytest.mark.parametrize("shape", [(60, 80, 3), (7, 5, 3)])     # an odd number of channels
def test_image_noise_kernel_gives_the_numpy_reference_bytes(cfg, shape):
    img = np.random.default_rng(3).integers(0, 256, size=shape, dtype=np.uint8)
    key = stream_key(1, "robot1", "camera")
    model = NoiseModel(cfg, key)
    for tick in (0, 1, 2, 10 ** 12):
        got = model.apply(img, tick)
        want = image_noise_reference(img, frame_seed(key, tick), cfg.std, cfg.bias + cfg.mean)
        assert np.array_equal(got, want)


@pytest.mark.parametrize("cfg", [NoiseConfig(std=10.0), NoiseConfig(std=7.3, bias=3.5, mean=-1.25),
                                 NoiseConfig(std=300.0)])
def test_image_noise_eight_at_a_time_gives_the_two_at_a_time_bytes(cfg):
    """Where the processor has AVX2 the image noise is drawn eight elements at a time: the
    bytes of two at a time and of the numpy reference, for every length (the last elements
    two, then one, at a time) and for grey levels that clip at 0 and 255."""
    if not kernels.noise_wide():
        pytest.skip("the processor has no AVX2: the noise is drawn two elements at a time only")
    rng = np.random.default_rng(5)
    key = stream_key(2, "follower", "camera")
    table = alias_table(float(cfg.std), float(cfg.bias + cfg.mean))
    try:
        for n in (*range(1, 40), 57600, 57603):
            img = rng.integers(0, 256, n, dtype=np.uint8)
            img[:: 7] = 0
            img[3:: 7] = 255
            seed = frame_seed(key, int(rng.integers(0, 10 ** 9)))
            wide, narrow = np.empty_like(img), np.empty_like(img)
            kernels.image_noise(img, seed, table, wide)
            kernels.noise_wide(0)
            kernels.image_noise(img, seed, table, narrow)
            kernels.noise_wide(-1)
            assert wide.tobytes() == narrow.tobytes(), n
            assert wide.tobytes() == image_noise_reference(
                img, seed, cfg.std, cfg.bias + cfg.mean).tobytes(), n
    finally:
        kernels.noise_wide(-1)


def test_a_missing_library_says_how_to_build_it(tmp_path):
    with pytest.raises(kernels.KernelsMissing, match="make setup"):
        kernels.load(tmp_path / "libplant_kernels.so")


def test_kinematic_kernel_gives_the_numpy_reference_to_the_bit():
    """plant/kernels/kinematic.c against plant.kinematic.reference_step: four copies of a
    two-robot room in one batch, robots dropped anywhere (against furniture, walls and
    each other), random wheel speeds; both paths of the footprint test (blocked by the room,
    by the other robot) and free moves all taken, every array equal to the bit."""
    from types import SimpleNamespace

    from plant import kinematic
    spec = load_world("living_room_follow", ["world.mode=kinematic"])
    batch = kinematic.join([kinematic.Kinematics(spec) for _ in range(4)])
    n = len(batch.pose)
    rng = np.random.default_rng(11)
    fields = ("pose", "wheels", "speeds", "vel", "radius", "separation", "world")
    seen = {"free": 0, "room": 0, "robot": 0}
    for trial in range(300):
        batch.pose[:] = np.column_stack([rng.uniform(-3.2, 3.2, n), rng.uniform(-2.7, 2.7, n),
                                         rng.uniform(-math.pi, math.pi, n)])
        if trial % 3 == 0:                      # each world's pair footprint to footprint
            batch.pose[1::2, :2] = batch.pose[0::2, :2] + rng.uniform(-0.5, 0.5, (n // 2, 2))
        targets = rng.uniform(-12.0, 12.0, (n, 2)) * (rng.random((n, 1)) < 0.9)
        ref = SimpleNamespace(**{f: getattr(batch, f).copy() for f in fields},
                              tick_s=batch.tick_s, foot=batch.foot)
        kinematic.reference_step(ref, targets)
        before = batch.pose.copy()
        batch.step(targets)
        for f in fields:
            assert getattr(batch, f).tobytes() == getattr(ref, f).tobytes(), (trial, f)
        alone = SimpleNamespace(**{f: getattr(ref, f).copy() for f in fields},
                                tick_s=ref.tick_s, foot=ref.foot)   # each robot on its own
        alone.pose, alone.world = before.copy(), np.arange(n)
        kinematic.reference_step(alone, targets)
        moving = (targets != 0).any(axis=1)
        stopped = moving & (batch.pose == before).all(axis=1)
        by_room = moving & (alone.pose == before).all(axis=1)
        seen["free"] += int((moving & ~stopped).sum())
        seen["room"] += int(by_room.sum())
        seen["robot"] += int((stopped & ~by_room).sum())
    assert min(seen.values()) > 20, seen


def test_kinematic_kernel_in_a_crowd_gives_the_numpy_reference_to_the_bit(tmp_path):
    """The robot-robot test over crowds: three copies of a 40-robot swarm room in one batch,
    the robots dropped in tight clusters (equal x centres, robots on top of each other, a
    NaN or infinite pose now and then), random wheel speeds: every array equals
    plant.kinematic.reference_step's, which tests every pair, to the bit."""
    from types import SimpleNamespace

    from plant import kinematic
    from plant.swarm_world import write_swarm_world
    spec = load_world(write_swarm_world(str(tmp_path / "w.toml"), 40, seed=1, mode="kinematic"))
    batch = kinematic.join([kinematic.Kinematics(spec) for _ in range(3)])
    n = len(batch.pose)
    side = spec.floor_size_m[0] / 2
    rng = np.random.default_rng(5)
    fields = ("pose", "wheels", "speeds", "vel", "radius", "separation", "world")
    by_robot = 0
    for trial in range(120):
        spots = rng.uniform(-side, side, (6, 2))
        xy = spots[rng.integers(0, 6, n)] + rng.normal(0.0, 0.15 + 0.1 * (trial % 4), (n, 2))
        if trial % 5 == 0:
            xy[rng.integers(0, n, 10), 0] = xy[0, 0]             # equal x, any y
            xy[1] = xy[2]                                        # one on top of another
        batch.pose[:] = np.column_stack([xy, rng.uniform(-math.pi, math.pi, n)])
        if trial % 7 == 0:
            batch.pose[rng.integers(0, n), rng.integers(0, 3)] = [np.nan, np.inf][trial % 2]
        targets = rng.uniform(-12.0, 12.0, (n, 2))
        ref = SimpleNamespace(**{f: getattr(batch, f).copy() for f in fields},
                              tick_s=batch.tick_s, foot=batch.foot)
        alone = SimpleNamespace(**{f: getattr(batch, f).copy() for f in fields},
                                tick_s=batch.tick_s, foot=batch.foot)
        alone.world = np.arange(n)                               # no other robots
        with np.errstate(invalid="ignore"):                      # (the NaN and inf poses)
            kinematic.reference_step(ref, targets)
            kinematic.reference_step(alone, targets)
        batch.step(targets)
        for f in fields:
            assert getattr(batch, f).tobytes() == getattr(ref, f).tobytes(), (trial, f)
        by_robot += int((np.isfinite(ref.pose).all(axis=1)
                         & (ref.pose != alone.pose).any(axis=1)).sum())
    assert by_robot > 500, by_robot


@pytest.mark.parametrize("world", ["living_room", "living_room_follow", "empty"])
def test_footprint_clearances_kernel_gives_the_numpy_reference_to_the_bit(world):
    """plant/kernels/kinematic.c's clearances (Footprints.clearances: the environments'
    contacts and free points) against Footprints.reference_clearances: points all
    over the room and beyond its walls, box centres and corners, circle centres, and NaNs
    (numpy's minimum keeps them); every value equal to the bit."""
    from plant.footprint import Footprints
    foot = Footprints(load_world(world))
    rng = np.random.default_rng(5)
    hx, hy = foot.box_half.T
    corners = foot.box_c + np.column_stack([hx * foot.box_cos - hy * foot.box_sin,
                                            hx * foot.box_sin + hy * foot.box_cos])
    pts = [rng.uniform(-1.2, 1.2, (4000, 2)) * foot.half, foot.box_c, foot.circ_c, corners,
           np.array([[np.nan, 0.0], [0.0, np.nan], [0.0, 0.0]])]
    pts = np.concatenate([p.reshape(-1, 2) for p in pts])
    got, want = foot.clearances(pts), foot.reference_clearances(pts)
    assert got.tobytes() == want.tobytes()
    assert np.isnan(got[-3]) and np.isnan(got[-2]) and np.isfinite(got[-1])
    assert (got <= 0).any() and (got > 0.5).any()        # beyond a wall and far from all


def _centres_at_the_edge(rng, foot, n: int, others: np.ndarray) -> np.ndarray:
    """n footprint centres each about one footprint radius (give or take nothing to a few
    mm) from a wall, a box, a circle or another robot's centre of ``others`` (two radii)."""
    from plant.footprint import FOOTPRINT_RADIUS_M as R
    gap = R + rng.choice([0.0, 1e-12, -1e-12, 1e-9, -1e-9, 1e-6, -1e-6, 3e-3, -3e-3], n)
    axis = rng.random(n) < 0.3                  # along an axis: a bound as tight as it gets
    a = np.where(axis, rng.integers(0, 4, n) * (math.pi / 2), rng.uniform(-math.pi, math.pi, n))
    u = np.column_stack([np.cos(a), np.sin(a)])
    out = np.empty((n, 2))
    for i in range(n):
        kind = rng.integers(0, 4)
        if kind == 0 and len(foot.circ_c):
            c = rng.integers(len(foot.circ_c))
            out[i] = foot.circ_c[c] + (foot.circ_r[c] + gap[i]) * u[i]
        elif kind == 1 and len(foot.box_c):
            b = rng.integers(len(foot.box_c))
            h = foot.box_half[b]
            p = np.clip(rng.uniform(-1.5, 1.5, 2) * h, -h, h)     # on a side or a corner
            p = p + gap[i] * u[i] if axis[i] else np.sign(u[i]) * h + gap[i] * np.abs(u[i])
            c, s = foot.box_cos[b], foot.box_sin[b]
            out[i] = foot.box_c[b] + [c * p[0] - s * p[1], s * p[0] + c * p[1]]
        elif kind == 2:
            out[i] = [rng.choice([-1, 1]) * (foot.half[0] - gap[i]),
                      rng.uniform(-foot.half[1], foot.half[1])]
        else:
            out[i] = others[rng.integers(len(others))] + (gap[i] + R) * u[i]
    return out


def _circles_on_grid_lines(rng, foot, centres: np.ndarray) -> None:
    """Moves circles (in place) so that their reach plus a footprint radius ends, give or take
    a hair, on a line of a 32 x 32 grid over the floor (the cells the kernel's grid has in a
    room this size), and puts ``centres`` just inside or outside that reach, across the line
    from the circle or not: a circle must be listed in every cell such a centre can be in."""
    from plant.footprint import FOOTPRINT_RADIUS_M as R
    m = len(centres)
    pick = rng.choice(len(foot.circ_c), m, replace=False)
    axis, sign = rng.integers(0, 2, m), rng.choice([-1.0, 1.0], m)
    for i, c in enumerate(pick):
        a, half, r = axis[i], foot.half[axis[i]], foot.circ_r[c]
        line = -half + rng.integers(2, 31) * (2 * half / 32)
        foot.circ_c[c, a] = line - sign[i] * (r + R) + rng.choice([0.0, 1e-9, -1e-9, 5e-4, -5e-4])
        foot.circ_c[c, 1 - a] = rng.uniform(-half + 1, half - 1)
        centres[i] = foot.circ_c[c]
        centres[i, a] += sign[i] * (r + R + rng.choice([-1e-12, -1e-9, -1e-6, 1e-9, -4e-4]))


@pytest.mark.parametrize("world", ["swarm96", "crowd288", "many_circles", "living_room_batch",
                                   "empty_batch", "nan_statics"])
def test_kinematic_kernel_at_the_footprints_edge_gives_the_reference_to_the_bit(world, tmp_path):
    """The kernel only computes a clearance exactly where it can be below the footprint's
    radius (bounds, a grid of the shapes near each cell of the floor for crowds, the old
    centre's clearance only when the new one is below): robots put within a hair of the
    radius from walls, boxes, circles and each other (exactly on it, 1e-12 m, 1e-9 m, 1e-6
    m, 3 mm in or out), barely moving or driving, NaN and infinite poses and centres now and
    then (a finite one driven to infinity), in the 96-robot swarm world (its grid; circles
    moved onto its cells' edges), three copies of it (288 robots: scratch beyond the
    stack's), it with 2000 more circles (a grid beyond the stack's), copies of the two-robot
    living room, an empty room and a room whose statics hold a NaN (nothing left out):
    plant.kinematic.reference_step, which tries every shape, gives the same arrays to the
    bit, and both sides of the edge are taken."""
    from types import SimpleNamespace

    from plant import kinematic
    from plant.footprint import CHASSIS_CENTRE_X_M
    from plant.swarm_world import write_swarm_world
    if world in ("swarm96", "crowd288", "many_circles"):
        spec = load_world(write_swarm_world(str(tmp_path / "w.toml"), 96, seed=0, mode="kinematic"))
        k = kinematic.Kinematics(spec)
        if world == "crowd288":                     # more robots than the stack scratch holds
            k = kinematic.join([k] + [kinematic.Kinematics(spec) for _ in range(2)])
        if world == "many_circles":                 # more grid entries than the stack holds
            foot, extra = k.foot, np.random.default_rng(3).uniform(-16.0, 16.0, (2000, 2))
            foot.circ_c = np.concatenate([foot.circ_c, extra])
            foot.circ_r = np.concatenate([foot.circ_r, np.full(2000, 0.05)])
            foot._kernel_args = None
    else:
        spec = load_world("empty" if world == "empty_batch" else "living_room_follow",
                          ["world.mode=kinematic"])
        k = kinematic.join([kinematic.Kinematics(spec) for _ in range(8)])
    if world == "nan_statics":
        k.foot.circ_r[0] = np.nan                   # (its kernel_args are the same arrays)
    n = len(k.pose)
    rng = np.random.default_rng(57)
    fields = ("pose", "wheels", "speeds", "vel", "radius", "separation", "world")
    blocked = moved = 0
    for trial in range(20 if world in ("crowd288", "many_circles") else 60):
        centres = _centres_at_the_edge(rng, k.foot, n, k.pose[:, :2])
        if world != "living_room_batch" and world != "empty_batch" and world != "nan_statics":
            _circles_on_grid_lines(rng, k.foot, centres[:24])
        yaw = rng.uniform(-math.pi, math.pi, n)
        k.pose[:] = np.column_stack([centres[:, 0] - CHASSIS_CENTRE_X_M * np.cos(yaw),
                                     centres[:, 1] - CHASSIS_CENTRE_X_M * np.sin(yaw), yaw])
        if trial % 4 == 0:
            bad = rng.integers(0, n, 3)
            k.pose[bad, rng.integers(0, 2, 3)] = [np.nan, np.inf, -np.inf]
            k.pose[bad[2], :2] = [np.inf, -np.inf]         # inf - inf: NaN clearances
        speed = 10.0 ** rng.uniform(-9, 1, (n, 1))          # a nm to centimetres a tick
        targets = rng.uniform(-1.0, 1.0, (n, 2)) * speed
        if trial % 4 == 1:          # from a finite centre to (inf, -inf): NaN by a box at yaw 0
            j = rng.integers(0, n)
            k.pose[j, 2], targets[j] = rng.uniform(-1.5, -0.1), 1e308
        ref = SimpleNamespace(**{f: getattr(k, f).copy() for f in fields},
                              tick_s=k.tick_s, foot=k.foot)
        before = k.pose.copy()
        with np.errstate(invalid="ignore", over="ignore"):
            kinematic.reference_step(ref, targets)
        kinematic.step_arrays(k, targets)
        for f in fields:
            assert getattr(k, f).tobytes() == getattr(ref, f).tobytes(), (trial, f)
        fine = np.isfinite(before).all(axis=1)
        still = (k.pose == before).all(axis=1)
        blocked += int((fine & still).sum())
        moved += int((fine & ~still).sum())
    least = n // 2 if world == "nan_statics" else n    # (there only robots block robots)
    assert blocked > least and moved > 3 * n, (blocked, moved)
