"""The camera kernel's box path (plant/kernels/camera.c: a block of pixels two at a time)
against its general per-pixel path (``force_flat``: every pixel's ray given, each one cast
by the scalar intersection), to the bit: the picture, the depth and the shape of every
pixel, in scenes made to reach its corners (shapes at the edges of the view and behind it,
faces flush with one another, rays parallel to a face, odd image widths)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from plant.camera import CameraConfig, render_full
from plant.shapes import Shape, pose_matrix


def _scene(seed: int) -> list[Shape]:
    rng = np.random.default_rng(seed)
    shapes = []
    for k in range(40):                                  # boxes all round the camera
        size = tuple(rng.uniform(0.05, 1.5, 3))
        x, y, z = rng.uniform(-6.0, 6.0), rng.uniform(-6.0, 6.0), rng.uniform(-1.5, 1.5)
        roll, pitch, yaw = rng.uniform(-math.pi, math.pi, 3) * (k % 3 != 0)
        shapes.append(Shape("box", size, pose_matrix(x, y, z, roll, pitch, yaw),
                            tuple(rng.uniform(0.1, 1.0, 3)), f"box{k}"))
    for k, bearing in enumerate((-0.66, -0.64, 0.64, 0.66, -0.5, 0.5)):   # the view's edges
        d = 2.0 + k
        shapes.append(Shape("box", (0.3, 0.3, 0.3),
                            pose_matrix(d * math.cos(bearing), d * math.sin(bearing), 0.2 * k),
                            (0.9, 0.5, 0.1), f"edge{k}"))
    # two boxes whose front faces are flush at a depth a float holds exactly (ties keep the
    # lower index); two the camera stands in the plane of a face of (rays parallel to it,
    # 0 * inf in the slab test)
    shapes.insert(0, Shape("box", (0.25, 1.0, 1.0), pose_matrix(2.625, 0.3, 0.0), (1, 0, 0),
                           "flush_a"))
    shapes.insert(1, Shape("box", (0.25, 1.0, 1.0), pose_matrix(2.625, -0.3, 0.2), (0, 1, 0),
                           "flush_b"))
    shapes.append(Shape("box", (4.0, 2.0, 2.0), pose_matrix(4.0, 2.5, 1.0), (0, 0, 1), "above"))
    shapes.append(Shape("box", (4.0, 2.0, 2.0), pose_matrix(4.0, -2.5, -1.0), (0, 1, 1), "below"))
    shapes.append(Shape("box", (20.0, 20.0, 0.1), pose_matrix(0, 0, -0.55), (0.5, 0.5, 0.5), "floor"))
    return shapes


@pytest.mark.parametrize("size", [(160, 120), (33, 25), (7, 5)])
@pytest.mark.parametrize("seed", [1, 2])
def test_box_blocks_give_the_per_pixel_path_to_the_bit(size, seed):
    cfg = CameraConfig(width=size[0], height=size[1], hfov_rad=1.3, far_m=9.0)
    shapes = _scene(seed)
    poses = [np.eye(4), pose_matrix(0.0, 0.0, 0.0, yaw=0.5 * seed),
             pose_matrix(0.3, -0.2, 0.1, roll=0.1, pitch=-0.2, yaw=2.0 + seed)]
    hits = set()
    for pose in poses:
        block = render_full(cfg, pose, shapes)
        flat = render_full(cfg, pose, shapes, force_flat=True)
        for a, b in zip(block, flat):
            assert a.tobytes() == b.tobytes(), (size, seed, pose)
        hits |= set(np.unique(block[2]).tolist())
    names = {shapes[i].name for i in hits if i >= 0}
    assert {"flush_a", "flush_b", "above", "below"} <= names and -1 in hits
