"""The lidar kernel leaves out the shapes beyond a sensor's reach before its cull (a large
world's sensors see a fraction of its shapes): the ranges stay the numpy reference's to the
bit, with shapes of every kind just inside and just outside the reach."""
from __future__ import annotations

import math

import numpy as np

from plant.lidar import LidarConfig, scan_many, scan_many_reference
from plant.raycast import Scene
from plant.shapes import Shape, pose_matrix


def _shape(rng, x: float, y: float) -> Shape:
    kind = ("box", "cylinder", "sphere")[int(rng.integers(3))]
    size = {"box": tuple(rng.uniform(0.05, 0.8, 3)),
            "cylinder": (rng.uniform(0.05, 0.5), rng.uniform(0.1, 1.0)),
            "sphere": (rng.uniform(0.05, 0.6),)}[kind]
    tilt = rng.uniform(-0.5, 0.5, 2) if rng.random() < 0.3 else (0.0, 0.0)
    return Shape(kind, size, pose_matrix(x, y, rng.uniform(-0.2, 0.5), roll=tilt[0],
                                         pitch=tilt[1], yaw=rng.uniform(-math.pi, math.pi)))


def test_shapes_at_the_edge_of_reach_give_the_reference_ranges():
    rng = np.random.default_rng(11)
    cfg = LidarConfig(num_rays=181, fov_rad=2 * math.pi, max_range_m=3.0, mount_x_m=0.0,
                      mount_z_m=0.0)
    sensors = [pose_matrix(rng.uniform(-8, 8), rng.uniform(-8, 8), 0.1,
                           roll=rng.uniform(-0.3, 0.3) * (k % 2), yaw=rng.uniform(-3, 3))
               for k in range(12)]
    shapes = [_shape(rng, rng.uniform(-12, 12), rng.uniform(-12, 12)) for _ in range(300)]
    # around each sensor, shapes whose bounding sphere ends a hair inside or outside its
    # reach, or just meets it (the kernel's early test and its cull both at their limits)
    for m in sensors:
        for edge in (-1e-3, -1e-9, 0.0, 1e-9, 1e-3):
            s = _shape(rng, 0.0, 0.0)
            radius = float(np.linalg.norm(Scene([s]).halves[0]))
            bearing = rng.uniform(-math.pi, math.pi)
            d = cfg.max_range_m + radius + edge
            tf = s.pose.copy()
            tf[:2, 3] = m[:2, 3] + d * np.array([math.cos(bearing), math.sin(bearing)])
            tf[2, 3] = m[2, 3]
            shapes.append(Shape(s.kind, s.size, tf))
    # and flat boxes whose centre is out of range but whose near face, nearly a corner of
    # the bounding circle, is 1 mm within it on a ray: seen only if the reach is the whole
    # bounding radius (a square of half side a turned 40 degrees off the ray: its face is
    # a / cos 40 from the centre along the ray, the corner a sqrt 2)
    a, seen, flat = 0.3, [], []
    for m in sensors[::2]:
        j = int(rng.integers(cfg.num_rays))
        bearing = math.atan2(m[1, 0], m[0, 0]) + float(cfg.angles()[j])
        d = cfg.max_range_m + a / math.cos(math.radians(40)) - 1e-3
        c = m[:2, 3] + d * np.array([math.cos(bearing), math.sin(bearing)])
        flat.append(Shape("box", (2 * a, 2 * a, 0.002),
                          pose_matrix(c[0], c[1], m[2, 3], yaw=bearing + math.radians(40))))
        seen.append((len(seen) * 2, j))
    for scene in (Scene(shapes), Scene(shapes + flat), Scene(flat)):
        got = scan_many(cfg, sensors, scene, [None] * len(sensors))
        want = scan_many_reference(cfg, sensors, scene, [None] * len(sensors))
        assert got.tobytes() == want.tobytes()
        assert np.isfinite(got).any() and np.isinf(got).any()
    for g, j in seen:                               # (each flat box is seen, at the edge)
        assert cfg.max_range_m - 2e-3 < got[g, j] < cfg.max_range_m, (g, j, got[g, j])
