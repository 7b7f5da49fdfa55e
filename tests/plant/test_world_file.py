"""World files: shipped ones load; every mistake is one line `file:key: reason`, exit 2."""
import os
import re
import subprocess
import sys

import pytest

from plant.noise import NoiseConfig, parse_noise, webots_gps
from plant.world import WorldError, load_world

from ..conftest import ROOT

GOOD = """
[world]
physics_step_s = 0.001
control_tick_s = 0.02

[[objects]]
name = "ball"
shape = "sphere"
radius_m = 0.2
pose = [1.0, 0.0]

[[robots]]
name = "robot1"
pose = [0.0, 0.0, 0.0]
"""


def write(tmp_path, text):
    p = tmp_path / "w.toml"
    p.write_text(text)
    return str(p)


def test_shipped_worlds_load():
    lr = load_world("living_room")
    assert len(lr.objects) >= 15 and lr.wall_height_m > 0
    assert {o.shape for o in lr.objects} == {"box", "cylinder", "sphere"}
    assert lr.robots[0].drive.wheel_radius_m == 0.12
    assert lr.robots[0].drive.wheel_separation_m == 0.36
    empty = load_world("empty")
    assert empty.objects == [] and empty.substeps == 20


@pytest.mark.parametrize("edit,key,reason", [
    (("physics_step_s = 0.001", "physics_stp_s = 0.001"), "world.physics_stp_s", "did you mean 'physics_step_s'"),
    (("physics_step_s = 0.001", 'physics_step_s = "fast"'), "world.physics_step_s", "expected a number"),
    (("physics_step_s = 0.001", "physics_step_s = 0"), "world.physics_step_s", "must be > 0"),
    (("physics_step_s = 0.001", "physics_step_s = -0.001"), "world.physics_step_s", "must be > 0"),
    (("control_tick_s = 0.02", "control_tick_s = 0.0205"), "world.control_tick_s", "whole multiple"),
    # one tick that would take hours: refused, not hung on (a fuzz find: 3.5e16 s)
    (("control_tick_s = 0.02", "control_tick_s = 35394908873780496"), "world.control_tick_s",
     "at most 1 s"),
    (("physics_step_s = 0.001", "physics_step_s = 1e-9"), "world.physics_step_s",
     "20000000 physics steps a control tick (at most 1000)"),
    (("radius_m = 0.2", "radius_m = -0.2"), "objects[0].radius_m", "must be > 0"),
    (('shape = "sphere"', 'shape = "cone"'), "objects[0].shape", "must be one of"),
    (("pose = [1.0, 0.0]", "pose = [1.0]"), "objects[0].pose", "list of"),
    (('name = "robot1"', 'name = "robot/1"'), "robots[0].name", "invalid robot name"),
    (('name = "robot1"', 'name = "*"'), "robots[0].name", "invalid robot name"),
    (("pose = [0.0, 0.0, 0.0]", 'pose = [0.0, 0.0, 0.0]\ncolour = [1, 0, 0]'), "robots[0].colour", "unknown key"),
])
def test_mistakes_name_file_and_key(tmp_path, edit, key, reason):
    path = write(tmp_path, GOOD.replace(*edit, 1))
    with pytest.raises(WorldError) as e:
        load_world(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}:{key}: "), msg
    assert reason in msg
    assert "\n" not in msg


def test_overlapping_robots_are_refused(tmp_path):
    path = write(tmp_path, GOOD + '\n[[robots]]\nname = "robot2"\npose = [0.2, 0.1, 0.0]\n')
    with pytest.raises(WorldError, match="overlap"):
        load_world(path)


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(WorldError, match="no such world"):
        load_world(str(tmp_path / "nope.toml"))
    with pytest.raises(WorldError, match="not valid TOML"):
        load_world(write(tmp_path, "[world\n"))


@pytest.mark.slow
def test_plant_exits_2_with_one_line_and_no_traceback(tmp_path):
    path = write(tmp_path, GOOD.replace("control_tick_s = 0.02", "control_tick_s = 'x'"))
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "plant", "--world", path],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert f"{path}:world.control_tick_s: expected a number" in lines[0]
    assert "Traceback" not in r.stderr


@pytest.mark.slow
def test_run_with_unknown_scenario_exits_2(tmp_path):
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "run", "no-such-scenario",
                        "--out", str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "no such scenario" in r.stderr and "Traceback" not in r.stderr


def test_overrides_set_values_by_robot_name_and_are_validated():
    w = load_world("living_room", ["world.mode=kinematic",
                                   "robots.robot1.encoders.noise={webots_noise = 0.2}",
                                   "materials.floor.friction=0.4",
                                   "robots.robot1.lidar.noise={ std = 0.05 }"])
    assert w.mode == "kinematic"
    assert w.materials["floor"].friction == 0.4
    assert w.robots[0].sensors.encoder_noise.std == pytest.approx(0.2)
    assert w.robots[0].sensors.lidar_noise.std == pytest.approx(0.05)
    with pytest.raises(WorldError, match="no robot named 'ghost'"):
        load_world("living_room", ["robots.ghost.gps.noise={std=1}"])
    with pytest.raises(WorldError, match=r"world\.mode: must be one of"):
        load_world("living_room", ["world.mode=warp"])
    with pytest.raises(WorldError, match=r"robots\[0\]\.lidar\.noise\.stdev: unknown key"):
        load_world("living_room", ["robots.robot1.lidar.noise={stdev = 1}"])


def test_gps_webots_noise_is_its_std_in_metres():
    """Webots' GPS ``noise`` is an absolute std dev in metres (unlike the lidar's, relative to
    its range, or the camera's, where 1.0 is 255): the world file's GPS takes it as is."""
    w = load_world("living_room", ["robots.robot1.gps.noise={webots_noise = 0.2, bias = 0.05}"])
    assert w.robots[0].sensors.gps_noise == NoiseConfig(std=0.2, bias=0.05)
    assert parse_noise({"webots_noise": 0.35}, "gps") == webots_gps(0.35) == NoiseConfig(std=0.35)


def test_sensor_sections_parse_with_webots_values():
    w = load_world("living_room", ["robots.robot1.lidar.noise={webots_noise = 0.2}",
                                   "robots.robot1.camera.noise={webots_noise = 0.2}",
                                   "robots.robot1.camera.k1=-0.2"])
    s = w.robots[0].sensors
    assert s.lidar.num_rays == 180 and s.lidar.max_range_m == 80.0
    assert s.lidar_noise.std == pytest.approx(0.2 * 80.0)      # relative to max range
    assert s.camera_noise.std == pytest.approx(0.2 * 255)      # 1.0 means 255
    assert s.camera.k1 == -0.2
    assert load_world("empty").robots[0].sensors.lidar is None


def test_a_sensor_can_be_switched_off_in_place():
    w = load_world("living_room", ["robots.robot1.lidar.enabled=false",
                                   "robots.robot1.camera.enabled=false"])
    assert w.robots[0].sensors.lidar is None and w.robots[0].sensors.camera is None


@pytest.mark.parametrize("override,reason", [
    # what would run the plant out of memory or overflow a sensor's period: refused
    ("robots.robot1.lidar.num_rays=1000000000000", "lidar num_rays 1000000000000 is more than 10000"),
    ("robots.robot1.lidar.rate_hz=1e-320", "lidar rate_hz out of range"),
    ("robots.robot1.camera.width=100000", "camera width 100000 is more than 4096 pixels"),
    ("robots.robot1.camera.rate_hz=0.001", "camera rate_hz out of range"),
])
def test_sensors_beyond_their_bounds_are_world_errors(override, reason):
    with pytest.raises(WorldError) as e:
        load_world("living_room", [override])
    assert reason in str(e.value) and "robots[0]." in str(e.value), str(e.value)
    # the bounds themselves are accepted
    load_world("living_room", ["robots.robot1.lidar.num_rays=10000",
                               "robots.robot1.camera.width=4096", "robots.robot1.lidar.rate_hz=0.01"])


def _doc_block(page: str, after: str) -> str:
    """The first ```toml block of docs/``page`` after the line starting with ``after``."""
    text = open(os.path.join(ROOT, "docs", page)).read()
    rest = text[text.index(after):]
    return rest.split("```toml\n", 1)[1].split("```", 1)[0]


def test_the_documented_world_keys_load_and_are_every_key(tmp_path):
    """docs/scenarios.md's list of every world-file key is a world file the loader takes,
    and it names every key the loader knows (a new key must be documented there)."""
    import dataclasses

    from plant.camera import CameraConfig
    from plant.lidar import LidarConfig
    from plant.world import DriveSpec, RobotSpec, WorldSpec
    block = _doc_block("scenarios.md", "Every key of a world file")
    path = tmp_path / "every_key.toml"
    path.write_text(block)
    w = load_world(str(path))
    assert w.contact_solver == "pgs" and w.robots[0].sensors.camera is not None
    keys = set(re.findall(r"^\s*([a-z_0-9]+)\s*=", block, re.M))
    keys |= set(re.findall(r"\{ ?([a-z_]+) =", block))
    world_keys = {f.name for f in dataclasses.fields(WorldSpec)} - {
        "path", "materials", "objects", "robots", "floor_size_m", "floor_color",
        "floor_material", "wall_height_m", "wall_thickness_m", "wall_color"}
    robot_keys = {f.name for f in dataclasses.fields(RobotSpec)} - {"pose", "drive", "parts",
                                                                     "sensors"}
    known = (world_keys | robot_keys | {f.name for f in dataclasses.fields(DriveSpec)}
             | {f.name for f in dataclasses.fields(LidarConfig)}
             | {f.name for f in dataclasses.fields(CameraConfig)}
             | {"extends", "size_m", "height_m", "thickness_m", "material", "friction",
                "shape", "radius_m", "static", "mass_kg", "enabled", "noise", "std",
                "command_noise_std_radps"})
    assert known - keys == set()


def test_the_documented_object_heights_are_the_living_rooms():
    """docs/sensors.md's table of what the lidar and the camera see lists every object of
    the living room with its height range, and says "hit" exactly for those that cross the
    lidar's scan plane (robot1's wheel radius plus the lidar's mount height)."""
    from plant.footprint import bottom
    w = load_world("living_room")
    r = w.robot("robot1")
    plane = r.drive.wheel_radius_m + r.sensors.lidar.mount_z_m
    text = open(os.path.join(ROOT, "docs", "sensors.md")).read()
    assert f"its plane is at **{plane:.2f} m**" in text
    rows = {m[0]: m[1:] for m in re.findall(
        r"^\| `(\w+)` \| ([0-9.]+)-([0-9.]+) \| ([^|]+) \|", text, re.M)}
    assert set(rows) == {o.name for o in w.objects}
    for o in w.objects:
        low, high, lidar = rows[o.name]
        top = bottom(o) + (o.size[2] if o.shape == "box" else o.size[1] if o.shape == "cylinder"
                           else 2 * o.size[0])
        assert (float(low), float(high)) == (round(bottom(o), 2), round(top, 2)), o.name
        assert lidar.startswith("hit") == (bottom(o) <= plane <= top), o.name
