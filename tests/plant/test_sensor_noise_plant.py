"""Sensor noise as the plant publishes it (``plant.sensors.RobotSensors``, world overrides).

Over 10k samples the spread matches the configured std within 5 % for encoders (rad),
GPS (m), lidar (m) and camera (0..255 levels, away from clipping); the study's
Webots-style values mean std 0.2 x 80 m for the lidar and 0.2 x 255 for the camera
(checked against the clipped-normal spread the sensors' range limits leave);
same seed -> identical streams, different seeds -> different; enabling the camera
leaves the encoder stream unchanged.
"""
from __future__ import annotations

import numpy as np
import pytest

from diffbot.study.experiments import expected_clipped_std
from plant import camera as cam
from plant import lidar as lid
from plant.raycast import Scene
from plant.sensors import RobotSensors
from plant.sim import Simulation
from plant.world import load_world

N = 10_000
TICK = 0.02


def sensors(world: str, sets=(), seed: int = 0, camera: bool = False, lidar: bool = True):
    """RobotSensors of robot1 and the world's shapes and true robot state at its start pose."""
    spec = load_world(world, list(sets))
    rs = spec.robot("robot1")
    if not camera:
        rs.sensors.camera = None          # as `diffbot plant --disable camera` does
    if not lidar:
        rs.sensors.lidar = None
    sim = Simulation(spec)
    return RobotSensors(rs, spec.control_tick_s, seed), Scene(sim.shapes()), sim.state("robot1")


def topic(msgs, name):
    return dict(msgs)[name]


def encoder_stream(s, st, n_ticks, scene=None):
    return np.array([topic(s.messages(k, k * 20_000_000, st, scene), "joint_states").position
                     for k in range(n_ticks)])


def scans(s, st, scene, n):
    period = s.periods["scan"]
    return np.array([np.asarray(topic(s.messages(k * period, 0, st, scene), "scan").ranges,
                                dtype=float) for k in range(n)])


# ------------------------------------------------------------------ configured std, 10k samples
def test_encoder_noise_std_rad():
    s, _, st = sensors("empty", ["robots.robot1.encoders.noise={std = 0.05}"])
    pos = encoder_stream(s, st, N // 2)                       # 2 wheels per reading
    resid = (pos - st.enc_pos).ravel()
    assert resid.size == N
    assert abs(resid.std() / 0.05 - 1) < 0.05
    assert abs(resid.mean()) < 4 * 0.05 / np.sqrt(N)


def test_encoder_webots_noise_is_absolute_rad():
    s, _, st = sensors("empty", ["robots.robot1.encoders.noise={webots_noise = 0.2}"])
    assert s.enc_noise.config.std == pytest.approx(0.2)
    resid = (encoder_stream(s, st, N // 2) - st.enc_pos).ravel()
    assert abs(resid.std() / 0.2 - 1) < 0.05


def test_gps_noise_std_m():
    s, _, st = sensors("empty", ["robots.robot1.gps.noise={std = 0.03}"])
    pts = []
    for k in range(N // 3 + 1):
        p = topic(s.messages(k, 0, st, None), "gps").point
        pts.append((p.x, p.y, p.z))
    resid = (np.array(pts) - st.xyz).ravel()[:N]
    assert abs(resid.std() / 0.03 - 1) < 0.05


def test_lidar_noise_std_m():
    s, scene, st = sensors("living_room", ["robots.robot1.lidar.noise={std = 0.05}"])
    clean = lid.scan(s.lidar, st.tf, scene, exclude_owner="robot1")
    assert np.all(np.isfinite(clean)) and clean.max() < 10          # every ray hits the room
    noisy = scans(s, st, scene, N // len(clean) + 1)
    resid = (noisy - clean).ravel()[:N]
    assert abs(resid.std() / 0.05 - 1) < 0.05


def test_camera_noise_std_levels_away_from_clipping():
    s, scene, st = sensors("living_room", ["robots.robot1.camera.noise={std = 10.0}"],
                           camera=True, lidar=False)
    clean = cam.render(s.camera, cam.camera_pose(s.camera, st.tf), scene, exclude_owner="robot1")
    img = topic(s.messages(0, 0, st, scene), "camera/image_raw")
    from bus import codec
    noisy = codec.image_to_array(img)
    mid = (clean >= 40) & (clean <= 215)                        # 4 sigma from 0 and 255
    resid = noisy.astype(float)[mid] - clean.astype(float)[mid]
    assert resid.size >= N
    # rounding to whole levels adds 1/12 level^2 of variance
    assert abs(resid.std() / np.sqrt(10.0 ** 2 + 1 / 12) - 1) < 0.05


# ------------------------------------------------------------------ the study's Webots values
def test_webots_lidar_noise_is_relative_to_max_range():
    s, scene, st = sensors("living_room", ["robots.robot1.lidar.noise={webots_noise = 0.2}"])
    c = s.lidar
    assert c.max_range_m == 80.0
    assert s.lidar_noise.config.std == pytest.approx(0.2 * 80.0)   # 16 m
    clean = lid.scan(c, st.tf, scene, exclude_owner="robot1")
    noisy = scans(s, st, scene, N // len(clean) + 1)
    resid = noisy - clean
    # ranges of 1-5 m with 16 m of noise: the reading is clipped to [min, max] range
    want = expected_clipped_std(np.tile(clean, len(noisy)), 16.0, c.min_range_m, c.max_range_m)
    assert 8.0 < want < 16.0
    assert abs(resid.std() / want - 1) < 0.05
    assert np.isclose(noisy, c.min_range_m).mean() > 0.2


def test_webots_camera_noise_is_fraction_of_255():
    s, scene, st = sensors("living_room", ["robots.robot1.camera.noise={webots_noise = 0.2}"],
                           camera=True, lidar=False)
    assert s.camera_noise.config.std == pytest.approx(0.2 * 255.0)  # 51 levels
    clean = cam.render(s.camera, cam.camera_pose(s.camera, st.tf), scene, exclude_owner="robot1")
    from bus import codec
    noisy = codec.image_to_array(topic(s.messages(0, 0, st, scene), "camera/image_raw"))
    resid = noisy.astype(float) - clean.astype(float)
    want = expected_clipped_std(clean.ravel(), 51.0, 0.0, 255.0)
    assert abs(resid.std() / want - 1) < 0.05
    # mid-grey pixels (>= 1.9 sigma from both limits) come close to the full 51
    mid = (clean >= 100) & (clean <= 155)
    assert mid.sum() > 1000
    assert abs(resid[mid].std() / 51.0 - 1) < 0.10


# ------------------------------------------------------------------ seeds and independence
NOISY = ["robots.robot1.encoders.noise={std = 0.01}", "robots.robot1.gps.noise={std = 0.02}",
         "robots.robot1.lidar.noise={std = 0.05}"]


def streams(seed: int, n: int = 20):
    s, scene, st = sensors("living_room", NOISY, seed=seed)
    out = []
    for k in range(n):
        m = dict(s.messages(k, 0, st, scene))
        out.append(np.concatenate([m["joint_states"].position,
                                   [m["gps"].point.x, m["gps"].point.y],
                                   np.asarray(m["scan"].ranges, dtype=float)
                                   if "scan" in m else []]))
    return np.concatenate(out)


def test_same_seed_same_streams_different_seed_different():
    a, b, c = streams(7), streams(7), streams(8)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.mean(a == c) < 0.01


def test_enabling_the_camera_leaves_the_encoder_stream_unchanged():
    sets = ["robots.robot1.encoders.noise={std = 0.01}",
            "robots.robot1.camera.noise={std = 20.0}"]
    with_cam, scene, st = sensors("living_room", sets, seed=3, camera=True)
    without, _, _ = sensors("living_room", sets, seed=3, camera=False)
    assert "camera/image_raw" in with_cam.periods and "camera/image_raw" not in without.periods
    a = encoder_stream(with_cam, st, 20, scene)
    b = encoder_stream(without, st, 20, scene)
    assert np.array_equal(a, b)
    assert not np.array_equal(a[0], st.enc_pos)                 # noise is really on
