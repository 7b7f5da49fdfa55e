"""plant.lidar.WorldScenes: several worlds' scenes laid out once, their moving shapes
written in place before each cast, give scan_worlds' ranges of the scenes built afresh to
the bit; what does not fit its layout is an error that says so."""
from __future__ import annotations

import math

import numpy as np
import pytest

from plant.lidar import LidarConfig, WorldScenes, scan_worlds
from plant.raycast import Scene
from plant.shapes import pose_matrix
from plant.sim import Simulation
from plant.world import load_world


@pytest.fixture(scope="module")
def worlds():
    spec = load_world("living_room_follow")
    return spec, [Simulation(spec) for _ in range(2)]


def _moved(sims) -> None:
    """Each world's robots driven apart (world k turning at 0.8 k rad/s)."""
    for k, sim in enumerate(sims):
        for _ in range(12):
            sim.command_twist("leader", 0.5, 0.8 * k)
            sim.command_twist("follower", -0.3, 0.5)
            sim.step_tick()


def test_a_cast_after_the_robots_moved_is_each_worlds_scene_built_afresh(worlds):
    spec, sims = worlds
    cfg = spec.robot("follower").sensors.lidar or LidarConfig()
    layouts = [sim.scene_layout() for sim in sims]
    world_of = [0, 1, 1, 0, 1, 0]
    owners = ["follower", "leader", None, "leader", "follower", None]
    scenes = WorldScenes(cfg, [lay[0] for lay in layouts], owners, world_of,
                         [(lay[1], lay[2]) for lay in layouts])
    # the sensors ringed round each world's leader, looking at it
    rng = np.random.default_rng(5)
    before = [sim.scene() for sim in sims]
    _moved(sims)
    poses = []
    for k in world_of:
        x, y = sims[k].robots["leader"].transform()[:2, 3]
        a = rng.uniform(-math.pi, math.pi)
        poses.append(pose_matrix(x + 0.8 * math.cos(a), y + 0.8 * math.sin(a), 0.0,
                                 yaw=a + math.pi + rng.uniform(-0.3, 0.3)))
    scenes.move(np.concatenate([sim.part_transforms() for sim in sims]))
    fresh = [Scene(sim.shapes()) for sim in sims]
    want = scan_worlds(cfg, fresh, poses, owners, world_of)
    assert scenes.scan(poses).tobytes() == want.tobytes()
    for k, sc in enumerate(fresh):                  # every shape where it is, seen or not
        rows = slice(scenes.starts[k], scenes.starts[k + 1])
        assert scenes.centers[rows].tobytes() == sc.centers.tobytes()
        assert scenes.rotations[rows].tobytes() == sc.rotations.tobytes()
    some = np.array([4, 1])
    assert scenes.scan([poses[g] for g in some], some).tobytes() == want[some].tobytes()
    # where the robots stood before, the same sensors see other ranges: the moves are seen
    stale = scan_worlds(cfg, before, poses, owners, world_of)
    assert (stale != want).any(axis=1).sum() >= 3


def test_what_does_not_fit_the_layout_is_an_error(worlds):
    spec, sims = worlds
    cfg = LidarConfig()
    tpl, first, count, _, _ = sims[0].scene_layout()
    with pytest.raises(ValueError, match="do not fit"):
        WorldScenes(cfg, [tpl], ["leader"], [0], [(first, len(tpl))])
    with pytest.raises(ValueError, match="not one of the 1 scenes"):
        WorldScenes(cfg, [tpl], ["leader"], [1], [(first, count)])
    scenes = WorldScenes(cfg, [tpl], ["leader"], [0], [(first, count)])
    with pytest.raises(ValueError, match=f"1 poses for {count} moving shapes"):
        scenes.move(np.eye(4)[None])
    with pytest.raises(ValueError, match="2 robot poses for 1 robots"):
        scenes.scan([np.eye(4)] * 2)
