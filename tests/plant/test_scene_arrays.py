"""The tick's scene built from arrays (Simulation.scene: the parts' (P, 4, 4) poses written
into the world's scene stacked once) holds what the scene of the world's Shape objects
holds, every array the ray casters read, to the bit; and the tick makes no Shape."""
import pickle

import numpy as np
import pytest

from plant import lidar as lid
from plant.camera import camera_pose, render
from plant.raycast import Scene
from plant.sensors import RobotSensors
from plant.shapes import Shape
from plant.sim import Simulation
from plant.stepper import Stepper
from plant.world import load_world

#: three robots (the leader carries two parts more than the others) and a movable crate
WORLD = """[world]
extends = "living_room_follow"

[[objects]]
name = "crate"
shape = "box"
size_m = [0.4, 0.4, 1.0]
pose = [0.3, -0.4, 0.0, 0.5]
color = [0.6, 0.5, 0.3]
static = false
mass_kg = 3.0

[[robots]]
name = "leader"
pose = [-0.1, -1.25, 0.0]
color = [0.80, 0.45, 0.15]

[[robots.parts]]
name = "ball_post"
shape = "cylinder"
radius_m = 0.01
height_m = 0.1
pose = [-0.30, 0.0, 0.10, 0.0]
color = [0.3, 0.3, 0.3]

[[robots.parts]]
name = "green_ball"
shape = "sphere"
radius_m = 0.06
pose = [-0.30, 0.0, 0.18, 0.0]
color = [0.10, 0.85, 0.15]

[[robots]]
name = "follower"
pose = [-1.23, -1.25, 0.0]
color = [0.15, 0.35, 0.80]

[robots.camera]
width = 64
height = 48
mount_x_m = 0.18
mount_z_m = 0.24

[[robots]]
name = "scout"
pose = [0.6, 0.9, 2.5]
color = [0.2, 0.7, 0.7]

[robots.lidar]
num_rays = 90
"""

#: what the lidar and camera kernels and the numpy casters read of a scene
ARRAYS = ("centers", "rotations", "halves", "radii", "quad", "rr", "owner_ids", "owners")


@pytest.fixture(scope="module", params=["kinematic", "dynamic"])
def moved(request, tmp_path_factory):
    """A world of each kind whose robots drove apart for 15 ticks (turning, so every part's
    rotation differs from its start)."""
    path = tmp_path_factory.mktemp("scene") / "world.toml"
    path.write_text(WORLD)
    sim = Simulation(load_world(str(path), [f"world.mode={request.param}"]))
    for _ in range(15):
        for name, (v, w) in zip(sim.robots, ((0.3, 0.8), (0.2, -0.6), (0.25, 0.4))):
            sim.command_twist(name, v, w)
        sim.step_tick()
    return sim


def _same(a: Scene, b: Scene) -> None:
    assert len(a) == len(b)
    for key in ARRAYS:
        x, y = getattr(a, key), getattr(b, key)
        assert x.dtype == y.dtype and x.shape == y.shape, key
        assert np.array_equal(x, y), key
        assert x.flags.c_contiguous, key           # (the C kernels read them by address)
    assert a.colors == b.colors
    for key in ("rot_cols", "center_cols", "half_cols"):
        assert all(np.array_equal(u, v) for u, v in
                   zip(np.ravel(getattr(a, key)), np.ravel(getattr(b, key)))), key
    assert a._owner_ids == b._owner_ids


def test_scene_from_arrays_is_the_scene_of_the_objects(moved):
    sim = moved
    objects = sim.shapes()
    plain = Scene(list(objects))                    # every array stacked from the objects
    tfs = sim.part_transforms()
    for scene in (sim.scene(), sim.scene(tfs), sim.scene(tfs.tolist())):
        _same(scene, plain)
        _same(scene, Scene(objects))
    # the robots moved: the scene is not its world's as built
    assert not np.array_equal(sim.scene().centers, sim._scene_template.centers)
    # its shapes, made only when asked for, are the objects'
    lazy = sim.scene().shapes
    assert [(s.kind, s.size, s.color, s.name, s.owner) for s in lazy] == \
        [(s.kind, s.size, s.color, s.name, s.owner) for s in objects]
    assert all(np.array_equal(s.pose, o.pose) for s, o in zip(lazy, objects))
    _same(pickle.loads(pickle.dumps(sim.scene())), plain)    # (a worker's copy)
    with pytest.raises(ValueError, match="part poses"):
        sim.scene(tfs[1:])


def test_scans_and_images_of_the_array_scene_are_the_objects(moved):
    """The lidars of every robot and a camera see the same in both scenes, to the bit."""
    sim = moved
    scene, plain = sim.scene(), Scene(list(sim.shapes()))
    names = list(sim.robots)
    tfs = [sim.state(n).tf for n in names]
    cfg = sim.spec.robots[2].sensors.lidar
    a = lid.scan_many(cfg, tfs, scene, names)
    assert np.array_equal(a, lid.scan_many(cfg, tfs, plain, names))
    assert np.isfinite(a).any()
    cam = sim.spec.robots[1].sensors.camera
    pose = camera_pose(cam, tfs[1])
    assert np.array_equal(render(cam, pose, scene, "follower"),
                          render(cam, pose, plain, "follower"))


def test_the_tick_makes_no_shape_objects(moved, monkeypatch):
    """The sensors' scene of a tick (Stepper.shapes) comes from the arrays alone."""
    sim = moved
    want = Scene(list(sim.shapes()))

    def refuse(*_a, **_k):
        raise AssertionError("a Shape made for the tick's scene")

    monkeypatch.setattr(Shape, "placed", refuse)
    monkeypatch.setattr(Simulation, "shapes", refuse)
    sensors = {r.name: RobotSensors(r, sim.spec.control_tick_s, 0) for r in sim.spec.robots}
    scene = Stepper(sim.spec, sim, None, sensors, False).shapes()
    _same(scene, want)
