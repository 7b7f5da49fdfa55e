"""The lidar kernel tries a shape only on the rays of its bearing sector, and none where the
sector falls between two rays: at the sector's very edge (a flat box whose corner lies on a
ray where the ray is tangent to the box's bounding circle, a hair inside or outside it,
near the sensor and far) the ranges are those of casting every ray at every shape, to the
bit."""
from __future__ import annotations

import math

import numpy as np
import pytest

from plant.lidar import LidarConfig, scan_many
from plant.raycast import Scene, cast_rays
from plant.shapes import Shape, pose_matrix

CFG = LidarConfig(num_rays=36, fov_rad=1.5 * math.pi, max_range_m=8.0, mount_x_m=0.0,
                  mount_y_m=0.0, mount_z_m=0.0)
SENSORS = [pose_matrix(-30.0, 0.0, 0.12, yaw=0.3), pose_matrix(0.0, 0.0, 0.31, yaw=-2.0),
           pose_matrix(30.0, 5.0, 0.05, yaw=math.pi)]


def _tangent_boxes(sensor: np.ndarray, ratio: float, shift: float, side: int,
                   rng) -> list[Shape]:
    """Flat boxes, one on every third ray: the ray tangent to the box's bounding circle
    (centre ``ratio`` radii away) at one of its corners, then the box moved ``shift`` radii
    off the ray (> 0: away from it, so the ray just misses; < 0: just hits)."""
    out = []
    o, yaw = sensor[:2, 3], math.atan2(sensor[1, 0], sensor[0, 0])
    for j in range(0, CFG.num_rays, 3):
        hx, hy = rng.uniform(0.05, 0.3, 2)
        r = math.hypot(hx, hy)
        ray = yaw + float(CFG.angles()[j])
        u = np.array([math.cos(ray), math.sin(ray)])
        n = side * np.array([-u[1], u[0]])              # the ray's normal, towards the box
        t = math.sqrt(ratio * ratio - 1.0) * r          # the tangent point along the ray
        centre = o + t * u + (1.0 + shift) * r * n
        corner = o + t * u - centre                     # the corner's offset (length r)
        psi = math.atan2(corner[1], corner[0]) - math.atan2(hy, hx)
        out.append(Shape("box", (2 * hx, 2 * hy, 2e-6),
                         pose_matrix(centre[0], centre[1], sensor[2, 3], yaw=psi)))
    return out


@pytest.mark.parametrize("ratio", [1.3, 2.5, 12.0, 30.0])
def test_rays_at_the_edge_of_a_shapes_sector_are_cast(ratio):
    rng = np.random.default_rng(int(ratio * 10))
    a = CFG.angles()
    hits = 0
    for shift in (-1e-6, -1e-10, 0.0, 1e-10, 1e-6):
        for side in (1, -1):
            world = [b for s in SENSORS for b in _tangent_boxes(s, ratio, shift, side, rng)]
            got = scan_many(CFG, SENSORS, Scene(world), [None] * len(SENSORS))
            for g, sensor in enumerate(SENSORS):
                dirs = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1) @ sensor[:3, :3].T
                want, _, _ = cast_rays(sensor[:3, 3], dirs, world, max_range=CFG.max_range_m)
                want[want < CFG.min_range_m] = np.inf
                assert got[g].tobytes() == want.tobytes(), (ratio, shift, side, g)
            hits += int(np.isfinite(got).sum())
    assert hits > 0
