"""The front half of a tick (plant/core/drive.py, plant/kernels/drive.c's
plant_drive_commands) against its oracle, robot by robot in Python (DriveLimiter and the
motion noise's normals: plant.core.drive.reference_commands), to the bit; and every host's
tick keeps the limiters in the core's arrays, one owner."""
from __future__ import annotations

import math

import numpy as np

from bus.controller import Twist, WheelSpeeds
from plant import kernels
from plant.core import drive as cd
from plant.drive import DriveLimiter
from plant.noise import stream_key
from plant.swarm_world import write_swarm_world
from plant.tick import Tick
from plant.world import DriveSpec, RobotSpec, load_world

DT = 0.02


def _robots(rng, n: int) -> list[RobotSpec]:
    """Drives with limits that bind: slow ramps (a command takes many ticks), wheel speed
    limits below what the twists ask (the wheels scaled together), a robot without noise."""
    out = []
    for i in range(n):
        d = DriveSpec(wheel_radius_m=rng.uniform(0.03, 0.2), wheel_separation_m=rng.uniform(0.1, 0.6),
                      max_wheel_speed_radps=rng.uniform(2.0, 15.0),
                      max_wheel_accel_radps2=rng.uniform(1.0, 80.0),
                      max_linear_mps=rng.uniform(0.2, 2.0), max_angular_radps=rng.uniform(0.5, 4.0),
                      max_linear_accel_mps2=rng.uniform(0.1, 5.0),
                      max_angular_accel_radps2=rng.uniform(0.5, 20.0))
        r = RobotSpec(f"r{i}", (0.0, 0.0, 0.0), drive=d)
        r.sensors.command_noise_std_radps = 0.0 if i == 1 else float(rng.uniform(0.0, 0.5))
        out.append(r)
    return out


def _command(rng, lim: list[float]) -> tuple[int, float, float]:
    """A tick's command of a robot whose limits are ``lim`` (limits_of's row)."""
    u = rng.random()
    if u < 0.15:
        return cd.KEEP, 0.0, 0.0
    if u < 0.3:
        return cd.TWIST, 0.0, 0.0                       # stand still (Tick.drive(None))
    if u < 0.35:
        return cd.WHEELS, -0.0, 0.0                     # wheels at rest: no noise
    if u < 0.7:
        return cd.TWIST, rng.uniform(-3, 3) * lim[0], rng.uniform(-3, 3) * lim[1]
    return cd.WHEELS, rng.uniform(-2, 2) * lim[6], rng.uniform(-2, 2) * lim[6]


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float64).view(np.uint64)


def test_the_kernel_is_the_limiter_and_the_motion_noise_to_the_bit():
    rng = np.random.default_rng(57)
    W, R, ticks = 3, 7, 150
    robots = _robots(rng, R)
    limits, std = cd.limits_of(robots, DT), cd.motion_std(robots)
    st = cd.state_arrays(W, R)
    st["keys"][:] = [[stream_key(w, r.name, "motion") for r in robots] for w in range(W)]
    tick = np.zeros(W, np.int64)
    call = kernels.drive_commands_call(W, R, tick, limits, std, st["keys"], st["kind"],
                                       st["cmd"], st["v"], st["w"], st["wheels"],
                                       st["targets"])
    oracle = [[DriveLimiter(r.drive) for r in robots] for _ in range(W)]
    targets, kind = np.zeros((W, R, 2)), np.zeros((W, R), np.int64)
    moved = stood = scaled = 0
    for k in range(ticks):
        tick[:] = [k, 3 * k + 1, 1000 + k]              # (each world at a tick of its own)
        for w in range(W):
            for i in range(R):
                kind[w, i], a, b = _command(rng, limits[i].tolist())
                st["cmd"][w, i] = (a, b)
                scaled += kind[w, i] == cd.WHEELS and max(abs(a), abs(b)) > limits[i, 6]
        st["kind"][:] = kind
        call()
        for w in range(W):
            cd.reference_commands(oracle[w], kind[w], st["cmd"][w], std, st["keys"][w],
                                  int(tick[w]), DT, targets[w])
            for i, lim in enumerate(oracle[w]):
                assert (st["v"][w, i], st["w"][w, i]) == (lim.v, lim.w), (k, w, i)
                assert tuple(st["wheels"][w, i]) == lim.wheels, (k, w, i)
                moved += lim.wheels != (0.0, 0.0) and std[i] > 0
                stood += lim.wheels == (0.0, 0.0)
        assert np.array_equal(_bits(st["targets"]), _bits(targets)), k
        assert not st["kind"].any()                     # (every command taken)
    assert moved > 500 and stood > 20 and scaled > 100  # (each branch taken, often)


def _noisy_swarm(tmp_path, mode: str):
    spec = load_world(write_swarm_world(str(tmp_path / f"{mode}.toml"), 4, seed=5, mode=mode))
    for i, r in enumerate(spec.robots):
        r.sensors.command_noise_std_radps = 0.0 if i == 2 else 0.1
    return spec


def test_every_host_files_commands_into_the_core_and_the_step_runs_them(tmp_path):
    """Tick.drive files the commands (the targets change only when the step starts), the
    step gives what the robot-by-robot limiters and motion noise give, and the limiters live
    in the core's arrays (the Simulation's drive is a view of them), through a reset."""
    for mode in ("kinematic", "dynamic"):
        spec = _noisy_swarm(tmp_path, mode)
        tick = Tick(spec)
        names = list(tick.sensors)
        oracle = [DriveLimiter(r.drive) for r in spec.robots]
        std = cd.motion_std(spec.robots)
        want = np.zeros((len(names), 2))
        for k in range(12):
            if k == 7:                                  # a reset: a rebuilt world at rest
                tick.reset(seed=11)
                oracle = [DriveLimiter(r.drive) for r in spec.robots]
                want[:] = 0.0
            d = tick.sim.drive
            for a in ("v", "w", "wheels", "targets", "keys"):
                assert np.shares_memory(getattr(d, a), tick.data.drive[a]), a
            assert d.keys.tolist() == [stream_key(spec.seed, n, "motion") for n in names]
            kind, cmd = np.zeros(len(names), np.int64), np.zeros((len(names), 2))
            for i, name in enumerate(names):
                c = [None, Twist(0.3, 0.9 * math.sin(k + i)), WheelSpeeds(9.0, 2.0 - i)][(k + i) % 3]
                tick.drive(name, c)
                kind[i] = cd.WHEELS if isinstance(c, WheelSpeeds) else cd.TWIST
                cmd[i] = (c.left, c.right) if kind[i] == cd.WHEELS else \
                    (0.0, 0.0) if c is None else (c.linear, c.angular)
            assert np.array_equal(d.targets, want)        # (filed, not yet run)
            cd.reference_commands(oracle, kind, cmd, std, d.keys.copy(),
                                  tick.t_ns // tick.tick_ns, spec.control_tick_s, want)
            assert tick.step()
            assert np.array_equal(_bits(d.targets), _bits(want)), (mode, k)
            assert [d.limiter(i) for i in range(len(names))] == \
                [(lim.v, lim.w, lim.wheels) for lim in oracle], (mode, k)


def test_a_world_without_robots_has_an_empty_front_half():
    d = cd.WorldDrive.alone([], DT)                 # (a world file may list no robot)
    assert d.run(0).shape == (0, 2)
