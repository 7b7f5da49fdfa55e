"""The ray-cast pinhole camera against the pinhole model and OpenCV's projectPoints."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from plant.camera import (R_BODY_OPTICAL, CameraConfig, camera_info, camera_pose, intrinsics,
                          look_at, render, render_full, third_person)
from plant.lidar import LidarConfig, scan
from plant.shapes import Shape, pose_matrix

CAM_WORLD = pose_matrix(1.0, -0.5, 0.4, roll=0.05, pitch=-0.1, yaw=0.6)  # any pose works


# ------------------------------------ scenes ----------------------------------------

def robot_shapes(name: str, pose: np.ndarray, ball: bool = False) -> list[Shape]:
    """A small diff-drive robot (body, wheels, caster, lidar, camera, optional ball mast)."""
    parts = [
        Shape("box", (0.36, 0.26, 0.16), pose_matrix(0, 0, 0.2), (0.85, 0.85, 0.85), "body"),
        Shape("cylinder", (0.12, 0.04), pose_matrix(0, 0.15, 0.12, roll=math.pi / 2),
              (0.1, 0.1, 0.1), "wheel_l"),
        Shape("cylinder", (0.12, 0.04), pose_matrix(0, -0.15, 0.12, roll=math.pi / 2),
              (0.1, 0.1, 0.1), "wheel_r"),
        Shape("sphere", (0.04,), pose_matrix(-0.14, 0, 0.04), (0.3, 0.3, 0.3), "caster"),
        Shape("cylinder", (0.04, 0.05), pose_matrix(0.15, 0, 0.25), (0.2, 0.2, 0.8), "lidar"),
        Shape("box", (0.04, 0.06, 0.04), pose_matrix(0.16, 0, 0.31), (0.1, 0.1, 0.1), "camera"),
    ]
    if ball:
        parts += [
            Shape("cylinder", (0.01, 0.3), pose_matrix(-0.1, 0, 0.43), (0.5, 0.5, 0.5), "mast"),
            Shape("sphere", (0.08,), pose_matrix(-0.1, 0, 0.64), (0.0, 1.0, 0.0), "green_ball"),
        ]
    for p in parts:
        p.pose = pose @ p.pose
        p.owner = name
        p.name = f"{name}/{p.name}"
    return parts


def living_room() -> list[Shape]:
    """A 6 x 5 m living room with furniture and two robots (~45 shapes)."""
    s: list[Shape] = []

    def add(kind, size, pose, color, name):
        s.append(Shape(kind, size, pose, color, name))

    add("box", (20, 20, 0.1), pose_matrix(0, 0, -0.05), (0.55, 0.45, 0.35), "floor")
    wc, h, t = (0.92, 0.9, 0.82), 2.5, 0.1
    add("box", (t, 5 + 2 * t, h), pose_matrix(3 + t / 2, 0, h / 2), wc, "wall_e")
    add("box", (t, 5 + 2 * t, h), pose_matrix(-3 - t / 2, 0, h / 2), wc, "wall_w")
    add("box", (6, t, h), pose_matrix(0, 2.5 + t / 2, h / 2), wc, "wall_n")
    add("box", (6, t, h), pose_matrix(0, -2.5 - t / 2, h / 2), wc, "wall_s")
    add("box", (2.4, 1.6, 0.01), pose_matrix(0.2, 0.3, 0.005), (0.6, 0.1, 0.15), "rug")
    sofa = (0.25, 0.3, 0.6)
    add("box", (0.9, 2.0, 0.4), pose_matrix(-2.4, 0.3, 0.2), sofa, "sofa_seat")
    add("box", (0.2, 2.0, 0.5), pose_matrix(-2.85, 0.3, 0.65), sofa, "sofa_back")
    add("box", (0.9, 0.2, 0.25), pose_matrix(-2.4, 1.4, 0.525), sofa, "sofa_arm_l")
    add("box", (0.9, 0.2, 0.25), pose_matrix(-2.4, -0.8, 0.525), sofa, "sofa_arm_r")
    wood = (0.55, 0.35, 0.2)
    add("box", (0.6, 1.1, 0.04), pose_matrix(-1.3, 0.3, 0.42), wood, "table_top")
    for i, (dx, dy) in enumerate([(-0.25, -0.5), (-0.25, 0.5), (0.25, -0.5), (0.25, 0.5)]):
        add("cylinder", (0.025, 0.4), pose_matrix(-1.3 + dx, 0.3 + dy, 0.2), wood, f"table_leg{i}")
    add("box", (0.4, 1.6, 0.5), pose_matrix(2.75, 0.0, 0.25), (0.2, 0.2, 0.2), "tv_stand")
    add("box", (0.08, 1.2, 0.7), pose_matrix(2.8, 0.0, 0.9), (0.05, 0.05, 0.08), "tv")
    add("box", (0.35, 1.2, 1.9), pose_matrix(0.8, 2.3, 0.95), (0.45, 0.3, 0.2), "bookshelf")
    add("box", (0.3, 0.3, 0.25), pose_matrix(0.4, 2.25, 2.02), (0.9, 0.8, 0.1), "box_on_shelf")
    add("box", (0.8, 0.8, 0.4), pose_matrix(1.8, -1.8, 0.2, yaw=0.6), (0.6, 0.5, 0.3), "armchair")
    add("box", (0.2, 0.8, 0.5), pose_matrix(1.55, -2.05, 0.6, yaw=0.6), (0.6, 0.5, 0.3),
        "armchair_back")
    add("cylinder", (0.15, 0.04), pose_matrix(-2.5, -2.1, 0.02), (0.15, 0.15, 0.15), "lamp_base")
    add("cylinder", (0.015, 1.5), pose_matrix(-2.5, -2.1, 0.77), (0.7, 0.7, 0.7), "lamp_pole")
    add("sphere", (0.2,), pose_matrix(-2.5, -2.1, 1.6), (1.0, 0.95, 0.7), "lamp_shade")
    add("cylinder", (0.18, 0.35), pose_matrix(2.6, 2.1, 0.175), (0.7, 0.35, 0.2), "plant_pot")
    add("sphere", (0.35,), pose_matrix(2.6, 2.1, 0.65), (0.1, 0.5, 0.15), "plant")
    add("sphere", (0.11,), pose_matrix(0.5, -1.0, 0.11), (0.9, 0.1, 0.1), "red_ball")
    add("sphere", (0.11,), pose_matrix(-0.4, 1.6, 0.11), (0.1, 0.2, 0.9), "blue_ball")
    add("cylinder", (0.25, 0.75), pose_matrix(-0.5, -1.7, 0.375), (0.9, 0.9, 0.9), "side_table")
    add("box", (0.45, 0.45, 0.05), pose_matrix(1.0, 1.0, 0.45), (0.4, 0.25, 0.15), "stool_top")
    add("cylinder", (0.04, 0.43), pose_matrix(1.0, 1.0, 0.215), (0.3, 0.3, 0.3), "stool_leg")
    s += robot_shapes("leader", pose_matrix(0.6, 0.1, 0, yaw=0.2), ball=True)
    s += robot_shapes("follower", pose_matrix(-0.4, -0.3, 0, yaw=0.3))
    return s


# ------------------------------- pinhole reference ----------------------------------

def sphere_ellipse(center_opt: np.ndarray, radius: float, k: np.ndarray):
    """Exact image of a sphere under a pinhole camera: (centre (u, v), sqrt(a*b) px).

    The silhouette is the cone of rays x with (x.C)^2 = (|C|^2 - R^2)|x|^2, i.e. the
    conic Q = C C^T - (|C|^2 - R^2) I in normalised coordinates; in pixels A = K^-T Q K^-1.
    """
    c = np.asarray(center_opt, float)
    q = np.outer(c, c) - (c @ c - radius ** 2) * np.eye(3)
    ki = np.linalg.inv(k)
    a = ki.T @ q @ ki
    a2, b, cc = a[:2, :2], a[:2, 2], a[2, 2]
    centre = -np.linalg.solve(a2, b)
    cprime = cc - b @ np.linalg.solve(a2, b)
    # inside: x^T a2 x + c' > 0 with a2 negative definite here -> flip signs
    area = math.pi * abs(cprime) / math.sqrt(np.linalg.det(a2))
    return centre, math.sqrt(area / math.pi)


def blob(sid: np.ndarray, index: int):
    v, u = np.nonzero(sid == index)
    return np.array([u.mean(), v.mean()]), math.sqrt(len(u) / math.pi), (u, v)


def body_dir(az: float, el: float) -> np.ndarray:
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def place_in_camera(cam_world: np.ndarray, p_body: np.ndarray) -> np.ndarray:
    return cam_world[:3, :3] @ p_body + cam_world[:3, 3]


# --------------------------------------- tests --------------------------------------

def test_intrinsics_convention():
    cfg = CameraConfig()
    k, d = intrinsics(cfg)
    f = 80 / math.tan(0.5)
    assert np.allclose(k, [[f, 0, 79.5], [0, f, 59.5], [0, 0, 1]])
    assert d.shape == (5,) and np.all(d == 0)
    info = camera_info(CameraConfig(k1=-0.3))
    assert info["distortion_model"] == "plumb_bob" and info["d"][0] == -0.3
    assert len(info["k"]) == 9 and len(info["p"]) == 12


@pytest.mark.parametrize("dist", [0.5, 1.0, 2.0, 3.0])
@pytest.mark.parametrize("az,el", [(0.0, 0.0), (0.25, 0.12), (-0.25, -0.1), (0.1, -0.15)])
def test_sphere_where_the_pinhole_model_says(dist, az, el):
    cfg = CameraConfig(width=640, height=480, hfov_rad=1.0)
    k, _ = intrinsics(cfg)
    radius = 0.08
    centre_w = place_in_camera(CAM_WORLD, dist * body_dir(az, el))
    shapes = [Shape("sphere", (radius,), pose_matrix(*centre_w), (0, 1, 0))]
    _, _, sid = render_full(cfg, CAM_WORLD, shapes)
    got_c, got_r, (u, v) = blob(sid, 0)
    assert u.min() > 0 and v.min() > 0 and u.max() < 639 and v.max() < 479  # fully in view
    c_opt = R_BODY_OPTICAL.T @ (dist * body_dir(az, el))
    want_c, want_r = sphere_ellipse(c_opt, radius, k)
    assert np.linalg.norm(got_c - want_c) < 1.0
    assert abs(got_r - want_r) / want_r < 0.05
    # and the sphere's centre projects (cv2) where the simple pinhole puts it
    proj, _ = cv2.projectPoints(c_opt.reshape(1, 3), np.zeros(3), np.zeros(3), k, np.zeros(5))
    assert np.allclose(proj.ravel(), k[:2, :2] @ (c_opt[:2] / c_opt[2]) + k[:2, 2])


def test_sphere_at_default_resolution():
    cfg = CameraConfig()
    k, _ = intrinsics(cfg)
    for az, el, dist in [(0.0, 0.0, 1.0), (0.25, 0.1, 1.5), (-0.3, -0.15, 0.8)]:
        centre_w = place_in_camera(CAM_WORLD, dist * body_dir(az, el))
        _, _, sid = render_full(cfg, CAM_WORLD, [Shape("sphere", (0.1,), pose_matrix(*centre_w))])
        got_c, got_r, _ = blob(sid, 0)
        want_c, want_r = sphere_ellipse(R_BODY_OPTICAL.T @ (dist * body_dir(az, el)), 0.1, k)
        assert np.linalg.norm(got_c - want_c) < 1.0
        assert abs(got_r - want_r) / want_r < 0.05


def test_ray_grid_inverts_opencv_distortion():
    from plant.camera import _grid_for
    cfg = CameraConfig(width=320, height=240, k1=-0.3, k2=0.1, p1=0.001, p2=-0.0005, k3=0.01)
    k, d = intrinsics(cfg)
    g = _grid_for(cfg)
    assert g.valid.all()
    pts = g.dirs.reshape(-1, 3)
    proj, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), k, d)
    u, v = np.meshgrid(np.arange(320), np.arange(240))
    err = np.hypot(proj[:, 0, 0] - u.ravel(), proj[:, 0, 1] - v.ravel())
    assert err.max() < 1e-6


@pytest.mark.parametrize("size", [(160, 120), (640, 480)])
def test_distorted_render_agrees_with_projectpoints(size):
    w, h = size
    cfg = CameraConfig(width=w, height=h, k1=-0.3, k2=0.1, p1=0.001)
    k, d = intrinsics(cfg)
    rng = np.random.default_rng(3)
    centres_body, shapes = [], []
    for az in np.linspace(-0.5, 0.5, 5):               # out to the image corners
        for el in np.linspace(-0.36, 0.36, 4):
            dist = rng.uniform(1.0, 2.5)
            cb = dist * body_dir(az, el)
            centres_body.append(cb)
            r = 0.02 * dist * (2.0 if w < 320 else 1.0)  # a few px (160x120) / ~12 px
            shapes.append(Shape("sphere", (r,), pose_matrix(*place_in_camera(CAM_WORLD, cb))))
    _, _, sid = render_full(cfg, CAM_WORLD, shapes)
    pts = np.array([R_BODY_OPTICAL.T @ c for c in centres_body])
    proj, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), k, d)
    proj = proj.reshape(-1, 2)
    checked = 0
    for i, p in enumerate(proj):
        r_px = k[0, 0] * shapes[i].size[0] / np.linalg.norm(centres_body[i]) * 1.5 + 2
        if not (r_px <= p[0] <= w - 1 - r_px and r_px <= p[1] <= h - 1 - r_px):
            continue                                      # partly outside the image
        got, _, _ = blob(sid, i)
        assert np.linalg.norm(got - p) < 1.0, (i, got, p)
        checked += 1
    assert checked >= (12 if w >= 320 else 6)
    # distortion visibly moves things: without it the corner spheres land elsewhere
    plain, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), k, np.zeros(5))
    assert np.max(np.linalg.norm(plain.reshape(-1, 2) - proj, axis=1)) > 3.0


@pytest.mark.parametrize("eye,target", [((-2.5, -2.0, 2.2), (0.3, 0.0, 0.3)),
                                        ((2.5, 2.0, 0.3), (-1.0, -0.5, 0.5)),
                                        ((0.0, 0.0, 4.0), (0.1, 0.0, 0.0))])
def test_camera_kernels_agree_with_the_general_caster(eye, target):
    # the camera's float32 per-shape kernels vs plant.raycast (float64, all shapes)
    from plant.camera import _T_BODY_OPTICAL, _grid_for
    from plant.raycast import cast_rays
    cfg = CameraConfig(width=200, height=150, k1=-0.2, k2=0.05)
    world = living_room()
    pose = look_at(eye, target)
    _, depth, sid = render_full(cfg, pose, world)
    t_wo = pose @ _T_BODY_OPTICAL
    rays = _grid_for(cfg).dirs.reshape(-1, 3) @ t_wo[:3, :3].T   # optical z = 1: t = depth
    t, idx, _ = cast_rays(t_wo[:3, 3], rays, world, max_range=cfg.far_m, min_range=cfg.near_m)
    same = idx == sid.ravel()
    assert same.mean() > 0.995                      # only silhouette pixels may differ
    fin = same & np.isfinite(t)
    rel = np.abs(depth.ravel()[fin] - t[fin]) / t[fin]
    # float32 vs float64: ~1e-7 on faces; near-tangent rays on thin round parts are
    # ill-conditioned (up to ~2e-4, i.e. 1 mm at 5 m on the edge of a table leg)
    assert np.mean(rel < 1e-5) > 0.99 and rel.max() < 1e-3


def test_orientation_left_is_left_up_is_up():
    cfg = CameraConfig()
    cam = pose_matrix(0, 0, 1.0)
    left = Shape("sphere", (0.1,), pose_matrix(2.0, 0.5, 1.0))
    up = Shape("sphere", (0.1,), pose_matrix(2.0, 0.0, 1.5))
    _, _, sid = render_full(cfg, cam, [left, up])
    (ul, vl), _, _ = blob(sid, 0)
    (uu, vu), _, _ = blob(sid, 1)
    assert ul < 79.5 - 10 and abs(vl - 59.5) < 1
    assert vu < 59.5 - 10 and abs(uu - 79.5) < 1


def test_flat_path_matches_block_path():
    cfg = CameraConfig(width=200, height=150)
    world = living_room()
    cam = camera_pose(cfg, pose_matrix(-0.4, -0.3, 0, yaw=0.3))
    a = render_full(cfg, cam, world, "follower")
    b = render_full(cfg, cam, world, "follower", force_flat=True)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[2], b[2])
    assert np.allclose(a[1], b[1])


def test_own_robot_hidden_and_leader_ball_seen():
    cfg = CameraConfig()
    world = living_room()
    follower = pose_matrix(-0.4, -0.3, 0, yaw=0.3)
    cam = camera_pose(cfg, follower)
    img, depth, sid = render_full(cfg, cam, world, exclude_owner="follower")
    names = {world[i].name for i in np.unique(sid) if i >= 0}
    assert not any(n.startswith("follower/") for n in names)
    assert "leader/green_ball" in names
    ball = [i for i, s in enumerate(world) if s.name == "leader/green_ball"][0]
    px = img[sid == ball]
    assert np.all(px[:, 1] > 2 * px[:, 0]) and np.all(px[:, 1] > 2 * px[:, 2])   # green
    assert img.dtype == np.uint8 and img.shape == (120, 160, 3)
    # the camera box contains the camera origin: even without exclusion its back
    # faces are ignored, so nothing changes except other own parts in view (none)
    img2, _, sid2 = render_full(cfg, cam, world)
    assert not np.any(sid2 == [i for i, s in enumerate(world) if s.name == "follower/camera"][0])


def test_background_depth_and_near_far():
    cfg = CameraConfig(near_m=0.5, far_m=3.0)
    cam = np.eye(4)
    near_ball = Shape("sphere", (0.1,), pose_matrix(0.3, 0, 0), (1, 0, 0))   # before near
    far_ball = Shape("sphere", (0.1,), pose_matrix(5.0, 0.3, 0), (1, 0, 0))  # beyond far
    mid = Shape("box", (0.2, 0.2, 0.2), pose_matrix(2.0, 0, 0), (0, 0, 1))  # behind near_ball
    img, depth, sid = render_full(cfg, cam, [near_ball, far_ball, mid], background=(0, 0, 0))
    assert set(np.unique(sid)) == {-1, 2}
    assert np.all(img[sid == -1] == 0) and np.all(np.isinf(depth[sid == -1]))
    assert np.allclose(depth[sid == 2], 1.9)          # the box's front face, optical depth


def test_third_person_and_living_room():
    world = living_room()
    img = third_person((-2.5, -2.0, 2.2), (0.3, 0.0, 0.3), world, 320, 240, 1.1)
    assert img.shape == (240, 320, 3) and img.dtype == np.uint8
    assert len({tuple(p) for p in img.reshape(-1, 3)[::7]}) > 20      # a varied picture
    pose = look_at((0, 0, 5), (0, 0, 0))                               # straight down works
    assert np.allclose(pose[:3, 0], [0, 0, -1])
    # the lidar sees the room too (sanity, same shapes)
    r = scan(LidarConfig(), pose_matrix(-0.4, -0.3, 0, yaw=0.3), world, exclude_owner="follower")
    assert np.all(np.isfinite(r)) and r.min() > 0.05


def test_no_preimage_pixels_show_background():
    # strong barrel distortion folds over before the image corners: those pixels have
    # no ray; they must show the background, the rest renders normally
    from plant.camera import _grid_for
    cfg = CameraConfig(k1=-0.5)
    grid = _grid_for(cfg)
    assert 0.5 < grid.valid.mean() < 1.0
    floor = Shape("box", (20, 20, 0.1), pose_matrix(0, 0, -0.05))
    img, _, sid = render_full(cfg, pose_matrix(0, 0, 0.5), [floor], background=(0, 0, 0))
    assert np.all(sid[~grid.valid] == -1) and np.all(img[~grid.valid] == 0)
    assert np.any(sid[grid.valid] == 0)


def test_scene_and_list_render_the_same():
    from plant.raycast import Scene
    cfg = CameraConfig()
    world = living_room()
    cam = camera_pose(cfg, pose_matrix(-0.4, -0.3, 0, yaw=0.3))
    a = render(cfg, cam, world, "follower")
    b = render(cfg, cam, Scene(world), "follower")
    assert np.array_equal(a, b)


def test_config_validation():
    with pytest.raises(ValueError, match="hfov_rad"):
        CameraConfig(hfov_rad=4.0)
    with pytest.raises(ValueError, match="width"):
        CameraConfig(width=0)
    with pytest.raises(ValueError, match="near_m"):
        CameraConfig(near_m=5.0, far_m=1.0)


def test_a_frame_is_the_rendered_picture_with_its_noise_to_the_bit():
    """camera.frame (render and noise in one kernel call, its fixed arguments kept per
    camera) gives render(camera_pose) then NoiseModel.apply's bytes: noise drawn by the
    kernel (with a bias), quantised noise (drawn in numpy), none; a distorted camera; the
    robot hidden or not; scenes that move, and one of other shapes (other colours,
    owners); two cameras in turn."""
    from plant.camera import frame
    from plant.noise import NoiseConfig, NoiseModel, stream_key
    from plant.raycast import Scene
    key = stream_key(5, "follower", "camera")
    noises = [None, NoiseModel(NoiseConfig(std=10.0, bias=3.0), key),
              NoiseModel(NoiseConfig(std=4.0, resolution=2.0), key), NoiseModel(NoiseConfig(), key)]
    cfgs = [CameraConfig(width=40, height=30, mount_yaw_rad=0.1),
            CameraConfig(width=33, height=25, hfov_rad=1.3, k1=-0.2, k2=0.05, mount_pitch_rad=0.2)]
    world = living_room()
    others = [s for s in world if s.name not in ("floor", "plant")]     # another layout
    for k in range(8):
        shapes = others if k == 5 else world
        moved = [Shape(s.kind, s.size, pose_matrix(0.05 * k, 0.0, 0.0) @ s.pose, s.color, s.name,
                       s.owner) if s.owner == "leader" else s for s in shapes]
        scene = Scene(moved)
        robot = pose_matrix(-0.4 + 0.1 * k, -0.3, 0, yaw=0.3 - 0.2 * k)
        for cfg in cfgs:
            for owner in ("follower", None):
                noise = noises[(k + (owner is None)) % len(noises)]
                want = render(cfg, camera_pose(cfg, robot), scene, owner)
                if noise is not None:
                    want = noise.apply(want, 40 + k)
                got = frame(cfg, robot, scene, owner, noise, 40 + k)
                assert got.shape == want.shape and got.dtype == np.uint8
                assert got.tobytes() == want.tobytes(), (k, cfg.width, owner, noise)
    assert frame(cfgs[0], robot, moved).tobytes() == \
        render(cfgs[0], camera_pose(cfgs[0], robot), moved).tobytes()     # a list of shapes


@pytest.mark.parametrize("size", [(160, 120), (37, 23)])
def test_the_box_test_four_pixels_at_a_time_gives_the_two_at_a_time_bytes(size):
    """Where the processor has AVX2 the kernel tests boxes four pixels at a time: picture,
    depth and shape of each pixel as with two at a time (rows of any length: the last
    pixels two, then one, at a time), from many poses in the living room."""
    from plant import kernels
    from plant.raycast import Scene
    if not kernels.camera_wide():
        pytest.skip("the processor has no AVX2: the kernel tests two pixels at a time only")
    cfg = CameraConfig(width=size[0], height=size[1], hfov_rad=1.2)
    scene = Scene(living_room())
    rng = np.random.default_rng(11)
    poses = [pose_matrix(x, y, 0.0, yaw=yaw) for x, y, yaw in
             zip(rng.uniform(-2.5, 2.5, 12), rng.uniform(-2.0, 2.0, 12), rng.uniform(-3, 3, 12))]
    poses.append(pose_matrix(-0.4, -0.3, 0, yaw=0.3))
    try:
        for robot in poses:
            pose = camera_pose(cfg, robot)
            wide = render_full(cfg, pose, scene, "follower")
            kernels.camera_wide(0)
            narrow = render_full(cfg, pose, scene, "follower")
            kernels.camera_wide(-1)
            for a, b in zip(wide, narrow):
                assert a.tobytes() == b.tobytes()
    finally:
        kernels.camera_wide(-1)
