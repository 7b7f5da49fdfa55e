"""The DART robot: the study's velocities, no tipping, kinematic mode, determinism, limits."""
import math

import numpy as np
import pytest

from bus.controller import Twist
from plant import drive
from plant.sim import Simulation
from plant.world import DriveSpec, load_world


def run(sim, wl, wr, seconds, robot="robot1"):
    for _ in range(int(round(seconds / sim.spec.control_tick_s))):
        sim.command_wheels(robot, wl, wr)
        sim.step_tick()
    return sim.state(robot)


@pytest.mark.parametrize("mode", ["dynamic", "kinematic"])
def test_drive_test_velocities(mode):
    spec = load_world("empty")
    spec.mode = mode
    sim = Simulation(spec)
    st = run(sim, 1, 1, 5)
    assert st.v_body[0] == pytest.approx(0.120, rel=0.01)
    st = run(sim, 1, -1, 5)
    assert st.w_body[2] == pytest.approx(-0.12 / 0.18, rel=0.02)   # clockwise: negative yaw rate
    assert abs(st.v_body[0]) < 1e-3


def test_hard_braking_does_not_tip_the_robot():
    sim = Simulation(load_world("empty"))
    run(sim, 8, 8, 1.5)
    worst = 0.0
    for _ in range(50):
        st = run(sim, 0, 0, 0.02)
        up = st.tf[:3, 2]
        worst = max(worst, math.degrees(math.acos(min(1.0, up[2]))))
    assert worst < 5.0, f"chassis tilted {worst:.1f} deg"
    assert st.xyz[2] == pytest.approx(0.12, abs=0.005)


def test_same_commands_same_trajectory_bitwise():
    def trajectory():
        sim = Simulation(load_world("living_room"))
        out = []
        for k in range(150):
            sim.command_twist("robot1", 0.3, 0.5 * math.sin(k / 20))
            sim.step_tick()
            out.append(sim.state("robot1").tf.copy())
        return np.array(out)
    assert np.array_equal(trajectory(), trajectory())


def test_walls_stop_the_robot_in_kinematic_mode():
    spec = load_world("living_room")
    spec.mode = "kinematic"
    sim = Simulation(spec)
    st = run(sim, -4, -4, 12)              # backwards toward the bookshelf/back wall
    assert st.xyz[0] > -3.0 + 0.15        # stayed inside the room
    assert np.all(np.isfinite(st.tf))


def test_time_counts_in_whole_steps():
    sim = Simulation(load_world("empty"))
    for _ in range(7):
        sim.step_tick()
    assert sim.time_ns == 7 * 20_000_000


def test_inverse_and_forward_kinematics_agree():
    wl, wr = drive.inverse(0.3, -0.7, 0.12, 0.36)
    assert drive.forward(wl, wr, 0.12, 0.36) == pytest.approx((0.3, -0.7))
    assert drive.inverse(0.12, 0.0, 0.12, 0.36) == pytest.approx((1.0, 1.0))


def test_limiter_clamps_and_ramps():
    spec = DriveSpec(max_linear_mps=0.5, max_linear_accel_mps2=1.0, max_wheel_speed_radps=100,
                     max_wheel_accel_radps2=1000)
    lim = drive.DriveLimiter(spec)
    wl, wr = lim.from_twist(5.0, 0.0, 0.1)            # asks for 5 m/s
    assert lim.v == pytest.approx(0.1)               # ramped by 1 m/s^2 over 0.1 s
    for _ in range(20):
        lim.from_twist(5.0, 0.0, 0.1)
    assert lim.v == pytest.approx(0.5)               # clamped at the limit
    spec2 = DriveSpec(max_wheel_speed_radps=2.0, max_wheel_accel_radps2=1e6)
    lim2 = drive.DriveLimiter(spec2)
    wl, wr = lim2.from_wheels(8.0, 4.0, 0.02)
    assert (wl, wr) == pytest.approx((2.0, 1.0))     # scaled together: curvature kept


def _trajectory(spec, commands, robot="robot1"):
    sim = Simulation(spec)
    out = []
    for wl, wr, ticks in commands:
        for _ in range(ticks):
            sim.command_wheels(robot, wl, wr)
            sim.step_tick()
            out.append(sim.state(robot).tf.copy())
    return np.array(out)


def test_walled_floor_collides_as_a_plane_with_the_box_floors_motion(monkeypatch):
    """The cheaper plane floor (walled worlds, Bullet) moves the robot as the box floor
    did, to a fraction of a millimetre after 6 s of gentle and hard (slipping) driving."""
    from plant import robot as robot_mod
    spec = load_world("living_room")
    assert robot_mod.floor_is_plane(spec)
    assert not robot_mod.floor_is_plane(load_world("living_room", ["walls.height_m=0"]))
    commands = [(1, 1, 100), (1, -1, 50), (8, 8, 75), (0, 0, 50), (-8, -8, 40)]
    plane = _trajectory(spec, commands)
    monkeypatch.setattr(robot_mod, "floor_is_plane", lambda world: False)
    box = _trajectory(load_world("living_room"), commands)
    assert np.abs(plane[:, :3, 3] - box[:, :3, 3]).max() < 5e-4
    assert plane[-1][2, 3] == pytest.approx(0.12, abs=1e-3)     # resting on its wheels


def test_swarm_world_dantzig_keeps_the_pgs_trajectories(tmp_path):
    """The swarm world picks Dantzig first: there PGS fails on ~95 % of the solves and
    falls back to Dantzig anyway, so the robots' paths barely move."""
    from plant.swarm_world import write_swarm_world
    path = write_swarm_world(str(tmp_path / "swarm.toml"), 6, seed=2)
    runs = {}
    for solver in ("dantzig", "pgs"):
        spec = load_world(path, [f'world.contact_solver="{solver}"'])
        sim = Simulation(spec)
        out = []
        for k in range(60):
            for i, name in enumerate(sim.robots):
                sim.command_twist(name, 0.3, 0.4 * math.sin(k / 10 + i))
            sim.step_tick()
            out.append([sim.state(name).tf for name in sim.robots])
        runs[solver] = np.array(out)
    assert load_world(path).contact_solver == "dantzig"
    gap = np.abs(runs["dantzig"][..., :3, 3] - runs["pgs"][..., :3, 3]).max()
    assert gap < 1e-3


@pytest.mark.parametrize("mode", ["dynamic"])     # (DART does not step a kinematic world)
def test_a_tick_moves_the_robots_as_commands_set_before_every_step_do_bit_for_bit(mode):
    """step_tick sets a dynamic robot's wheel commands once a tick (world.step(False) keeps
    them): the motion is the reference loop's (commands set, world.step(), every step)."""
    import math

    from plant.sim import Simulation
    from plant.world import load_world
    specs = [load_world("living_room_follow", [f"world.mode={mode}"]) for _ in range(2)]
    fast, ref = Simulation(specs[0]), Simulation(specs[1])
    for k in range(60):
        for sim in (fast, ref):
            for i, name in enumerate(sim.robots):
                sim.command_twist(name, 0.4 * math.sin(0.1 * k + i), 1.5 * math.cos(0.1 * k))
        fast.step_tick()
        for _ in range(ref.spec.substeps):
            for r, (wl, wr) in zip(ref.robots.values(), ref.drive.targets.tolist()):
                r.apply(wl, wr)
            ref.world.step()
        for a, b in zip(fast.robots.values(), ref.robots.values()):
            assert a.skeleton.getPositions().tobytes() == b.skeleton.getPositions().tobytes()
            assert a.skeleton.getVelocities().tobytes() == b.skeleton.getVelocities().tobytes()


def test_is_finite_finds_any_non_finite_position_or_velocity():
    sim = Simulation(load_world("living_room"))
    sk = sim.robots["robot1"].skeleton
    assert sim.is_finite()
    q0, dq0 = sk.getPositions(), sk.getVelocities()
    for i in range(len(q0)):
        for bad in (math.nan, math.inf, -math.inf):
            for setter, base in ((sk.setPositions, q0), (sk.setVelocities, dq0)):
                v = base.copy()
                v[i] = bad
                setter(v)
                assert not sim.is_finite(), (i, bad)
                assert not sim.read_state()[1], (i, bad)          # (a tick's check)
                setter(base)
    q = q0.copy()
    q[:] = 1e308                  # finite, though their sum overflows
    sk.setPositions(q)
    assert sim.is_finite() and sim.read_state()[1]


def test_a_tick_reads_dart_once_a_step_and_again_after_a_restored_state(monkeypatch):
    """The step's finite check and the next tick's state come from one read of DART; a
    state put back at the same clock (the plant FMU's restore) is read anew."""
    from fmus.plant_state import set_world_state, world_state
    from plant.tick import Tick

    reads = []
    real = Simulation.read_state
    monkeypatch.setattr(Simulation, "read_state",
                        lambda self, *a: reads.append(1) or real(self, *a))
    driven, standing = (Tick(load_world("living_room"), ("lidar", "camera")) for _ in "ab")
    driven.drive("robot1", Twist(0.4, 1.0))
    standing.drive("robot1", None)
    for tick in (driven, standing):
        reads.clear()
        assert tick.step()
        rows = tick.stepper.rows()
        assert len(reads) == 1                  # finite() and rows() of the same step
    assert rows.tobytes() == real(standing.sim)[0].tobytes()
    assert rows.tobytes() != driven.stepper.rows().tobytes()
    set_world_state(standing, world_state(driven, None))      # the same clock, moved
    assert standing.stepper.rows().tobytes() == driven.stepper.rows().tobytes()
