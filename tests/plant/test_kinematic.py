"""The kinematic world (plant/kinematic.py): exact unicycle arcs, stopped by footprints,
several worlds stepped in one call to the bit as each alone."""
import math

import numpy as np
import pytest

from bus import codec
from bus.controller import Twist
from plant import kinematic
from plant.footprint import CHASSIS_CENTRE_X_M, FOOTPRINT_RADIUS_M, Footprints, footprint_centres
from plant.sim import Simulation
from plant.tick import Tick, messages_of, step_ticks
from plant.world import load_world


def kin_world(name="empty", overrides=()):
    return load_world(name, ["world.mode=kinematic", *overrides])


def test_a_robot_follows_the_exact_arc_of_its_wheel_speeds():
    spec = kin_world()
    k = kinematic.Kinematics(spec)
    r, d = spec.robots[0].drive.wheel_radius_m, spec.robots[0].drive.wheel_separation_m
    wl, wr = 2.0, 3.0
    v, w = r * (wr + wl) / 2, r * (wr - wl) / d
    T = spec.control_tick_s
    for n in range(1, 201):
        k.step(np.array([[wl, wr]]))
        t = n * T
        x = v / w * math.sin(w * t)                  # from (0, 0, 0): the closed form
        y = v / w * (1 - math.cos(w * t))
        assert k.pose[0] == pytest.approx([x, y, w * t], abs=1e-12)
    assert k.wheels[0] == pytest.approx([wl * 200 * T, wr * 200 * T], abs=1e-12)
    assert tuple(k.vel[0]) == pytest.approx((v, w))
    k.step(np.array([[1.0, 1.0]]))                   # straight: no division by w = 0
    assert k.vel[0, 1] == 0.0 and k.vel[0, 0] == pytest.approx(r)


def test_the_world_alone_moves_its_clock():
    """Simulated time has one owner: the Simulation counts its steps (a tick, ticks run
    elsewhere, a restored state, a restart); nobody else may write the count."""
    sim = Simulation(kin_world())
    sub, step_ns = sim.spec.substeps, round(sim.spec.physics_step_s * 1e9)
    sim.step_tick()
    sim.advance(3)
    assert sim.steps == 4 * sub and sim.time_ns == 4 * sub * step_ns
    with pytest.raises(AttributeError):
        sim.steps = 0
    sim.restore_clock(sub)
    assert sim.time_ns == sub * step_ns
    sim.restart()
    assert sim.steps == 0


def test_a_wall_stops_the_footprint_and_the_robot_can_leave():
    spec = kin_world()
    half = spec.floor_size_m[0] / 2
    spec.robots[0].pose = (half - 1.0, 0.0, 0.0)      # facing the +x wall, 1 m away
    sim = Simulation(spec)
    foot = Footprints(spec)
    for _ in range(300):                               # 0.4 m/s for 6 s: would cross it
        sim.command_twist("robot1", 0.4, 0.0)
        sim.step_tick()
    st = sim.state("robot1")
    c = foot.centre(*st.xyz[:2], st.yaw)
    clear = foot.clearance(c)
    assert FOOTPRINT_RADIUS_M <= clear < FOOTPRINT_RADIUS_M + 0.4 * spec.control_tick_s
    assert st.v_body[0] == 0.0 and st.w_body[2] == 0.0             # stopped, reports it
    angle = st.enc_pos[0]
    sim.command_twist("robot1", 0.4, 0.0)
    sim.step_tick()
    assert sim.state("robot1").enc_pos[0] > angle                  # its wheels still turn
    for _ in range(50):                                             # backing off is allowed
        sim.command_twist("robot1", -0.3, 0.0)
        sim.step_tick()
    assert sim.state("robot1").xyz[0] < st.xyz[0] - 0.1


def test_two_robots_head_on_stop_footprint_to_footprint():
    spec = kin_world("living_room", ["world.mode=kinematic"])
    foot = kinematic.Kinematics(spec).foot
    k = kinematic.Kinematics(spec)
    k.pose = np.array([[-0.6, 0.35, 0.0], [0.6, 0.35, math.pi]])   # two robots, one world
    k.names, k.radius = ["a", "b"], np.repeat(k.radius, 2)
    k.separation, k.world = np.repeat(k.separation, 2), np.zeros(2, np.int64)
    k.wheels, k.speeds, k.vel = np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2))
    assert foot.clearances(footprint_centres(*k.pose.T)).min() > FOOTPRINT_RADIUS_M
    for _ in range(200):
        k.step(np.array([[3.0, 3.0], [3.0, 3.0]]))
    c = footprint_centres(*k.pose.T)
    gap = math.dist(c[0], c[1])
    assert 2 * FOOTPRINT_RADIUS_M <= gap < 2 * FOOTPRINT_RADIUS_M + 2 * 0.36 * spec.control_tick_s
    assert (k.vel == 0).all()
    assert CHASSIS_CENTRE_X_M < 0


def test_several_worlds_in_one_call_move_as_each_alone_to_the_bit():
    """step_ticks and messages_of (one kinematic step and one lidar cast for all the
    worlds) against each world's own Tick.step and Tick.messages."""
    def worlds(seed0):
        out = []
        for i in range(4):
            spec = kin_world("living_room")
            tick = Tick(spec, ("camera",))
            tick.reset(seed0 + i, {"robot1": (-1.0 + 0.5 * i, 0.3 * i, 0.4 * i)})
            out.append(tick)
        return out
    alone, batched = worlds(7), worlds(7)
    rng = np.random.default_rng(3)
    for k in range(120):
        cmds = rng.uniform([-0.2, -1.5], [0.4, 1.5], (4, 2))
        for t, c in zip(alone, cmds):
            t.drive("robot1", Twist(*c))
            t.step()
        for t, c in zip(batched, cmds):
            t.drive("robot1", Twist(*c))
        step_ticks(batched)
        got = messages_of(batched, [None] * 4)
        for t, msgs in zip(alone, got):
            want = list(t.messages())
            assert [(n, topic) for n, topic, _ in want] == [(n, topic) for n, topic, _ in msgs]
            for (_, topic, a), (_, _, b) in zip(want, msgs):
                assert codec.encode(a) == codec.encode(b), (k, topic)
    assert any(len(t.sim.kin.batch.members) == 4 for t in batched)
    moved = [t.sim.state("robot1").xyz for t in alone]
    assert len({tuple(np.round(m, 6)) for m in moved}) == 4


def test_a_batch_takes_copies_of_one_world_only():
    a = kinematic.Kinematics(kin_world("living_room"))
    b = kinematic.Kinematics(kin_world("empty"))
    with pytest.raises(ValueError, match="copies of one world"):
        kinematic.join([a, b])


def test_a_restarted_kinematic_world_is_a_new_one_to_the_bit():
    """A reset restarts a kinematic world in place (no new DART world): the same messages,
    noise on, as a world built anew with that seed and those start poses."""
    def run(tick, ticks=60):
        out = []
        for k in range(ticks):
            out += [codec.encode(m) for _, _, m in tick.messages()]
            tick.drive("robot1", Twist(0.3, 0.8 * math.sin(k / 7)))
            tick.step()
        return out
    used = Tick(kin_world("living_room"), ("camera",))
    sim = used.sim
    run(used, 40)
    used.reset(11, {"robot1": (0.5, -0.4, 1.0)})
    assert used.sim is sim                                      # restarted, not rebuilt
    spec = kin_world("living_room")
    spec.seed, spec.robot("robot1").pose = 11, (0.5, -0.4, 1.0)
    fresh = Tick(spec, ("camera",))                             # built with them
    assert run(used) == run(fresh)
