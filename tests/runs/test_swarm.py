"""The swarm: its generated world, the lidar avoid controller, and a short run."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from controllers.avoid import Avoid
from diffbot.analysis.swarm import FOOTPRINT_RADIUS_M, clearance_to_object, count_episodes
from plant.swarm_world import swarm_layout, swarm_world_text, write_swarm_world
from plant.world import load_world

from ..conftest import ROOT, check_real_time_factor

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background


def test_swarm_world_is_deterministic_and_differs_by_seed():
    assert swarm_world_text(8, 3) == swarm_world_text(8, 3)
    assert swarm_world_text(8, 3) != swarm_world_text(8, 4)


@pytest.mark.parametrize("n", [1, 8, 24])
def test_swarm_world_loads_with_clear_starts(tmp_path, n):
    w = load_world(write_swarm_world(str(tmp_path / "w.toml"), n, seed=1))
    assert [r.name for r in w.robots] == [f"r{i}" for i in range(n)]
    assert all(r.sensors.lidar is not None for r in w.robots)
    half = w.floor_size_m[0] / 2
    obstacles = [o for o in w.objects if o.name.startswith("obstacle")]
    assert len(obstacles) >= n
    for r in w.robots:
        x, y, _ = r.pose
        assert abs(x) < half - 0.5 and abs(y) < half - 0.5        # inside the walls
        for o in obstacles:                                        # no obstacle on a start
            assert clearance_to_object(np.array([x, y]), o) > FOOTPRINT_RADIUS_M + 0.3
    for o in obstacles:
        assert abs(o.pose[0]) < half and abs(o.pose[1]) < half


def test_swarm_world_rejects_no_robots():
    with pytest.raises(ValueError, match="at least 1 robot"):
        swarm_layout(0)


def _scan(obstacle_angle: float, obstacle_m: float, n: int = 36):
    angles = np.linspace(-0.75 * math.pi, 0.75 * math.pi, n)
    ranges = np.full(n, 8.0)
    ranges[np.abs(angles - obstacle_angle) < 0.3] = obstacle_m
    return angles, ranges


def test_avoid_drives_straight_when_free_and_turns_away_from_a_close_obstacle():
    free = Avoid().command(*_scan(0.0, 8.0))
    assert free.linear > 0.25 and abs(free.angular) < 1e-9
    left_near = Avoid().command(*_scan(0.4, 0.9))         # ahead-left, close: veer right
    assert 0 < left_near.linear < free.linear and left_near.angular < 0
    right_near = Avoid().command(*_scan(-0.4, 0.9))
    assert right_near.angular > 0


def test_avoid_stops_and_keeps_turning_one_way_when_blocked():
    a = Avoid()
    angles, ranges = _scan(0.0, 0.4)
    ranges[angles < -0.5] = 0.8                             # right side more crowded
    first = a.command(angles, ranges)
    assert first.linear == 0 and first.angular > 0          # turn left, toward room
    ranges[angles > 0.5] = 0.7                              # now left looks worse: keep going
    again = a.command(angles, ranges)
    assert again.linear == 0 and again.angular > 0


def test_collision_episodes_count_rising_edges():
    assert count_episodes([False, True, True, False, True]) == 2
    assert count_episodes([True, False]) == 1
    assert count_episodes([]) == 0


@pytest.mark.slow
def test_short_swarm_run_writes_summary_and_paths(tmp_path):
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "run", "swarm", "--robots", "4",
                        "--controller-processes", "2", "--duration", "6", "--out", str(tmp_path),
                        "--plots"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    s = json.load(open(tmp_path / "summary.json"))
    assert s["exit_codes"] == {"plant": 0, "avoid_g0": 0, "avoid_g1": 0}
    m = s["metrics"]
    assert m["robots"] == 4 and m["controller_processes"] == 2
    assert m["duration_s"] == pytest.approx(6.0, abs=0.05)
    # Each robot moved (0.3 m/s at most: at most 1.8 m in 6 s), none hit a wall.
    assert all(0.3 < d < 1.85 for d in m["distance_m"].values()), m["distance_m"]
    assert m["collisions"]["robot_wall"] == 0
    check_real_time_factor(s)
    assert s["physics_process"] is True                     # the scenario's default
    assert set(s["plant_per_tick_ms"]) == {"publish", "wait", "physics"}
    assert all(v >= 0 for v in s["plant_per_tick_ms"].values())
    # the CPU of both processes a tick: DART stepping 4 robots costs its worker some
    assert set(s["cpu_per_tick_ms"]) == {"plant", "physics"}
    assert s["cpu_per_tick_ms"]["physics"] > 0 and s["cpu_per_tick_ms"]["plant"] > 0
    assert (tmp_path / "paths.png").stat().st_size > 10_000
    assert (tmp_path / "world.toml").read_text() == swarm_world_text(4, 0)


@pytest.mark.slow
def test_robots_option_is_refused_by_a_fixed_world_scenario():
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "run", "square", "--robots", "3"],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--robots" in r.stderr and "fixed world" in r.stderr
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "run", "drive-test", "--physics",
                        "kinematic"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "fixed world" in r.stderr
