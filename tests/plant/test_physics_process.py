"""DART in a process of its own (plant/physics_process.py): the same motion bit for bit,
the same run on the bus, and no process left behind however the plant ends."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from plant.mirror import Mirror
from plant.physics_process import (ADAPTIVE, ALWAYS_PLANT, ALWAYS_WORKER, Layout,
                                   PhysicsError, PhysicsProcess, store_state)
from plant.sim import Simulation
from plant.swarm_world import write_swarm_world
from plant.stepper import Stepper
from plant.tick import Tick, build_world
from plant.world import load_world

from ..conftest import ROOT, wait_for


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1].startswith("Z")      # a zombie is gone too
    except FileNotFoundError:
        return True


@pytest.mark.slow
@pytest.mark.parametrize("reader", [ALWAYS_WORKER, ALWAYS_PLANT, ADAPTIVE],
                         ids=["worker reads", "plant's mirror reads", "adaptive"])
def test_the_state_reads_as_the_world_stepped_here(tmp_path, reader):
    """The worker hands back positions and velocities, and reads the rows and parts itself
    or leaves that to the plant's mirror of its world: either reads as a world stepped in
    this process, every robot's state, the parts' poses and finiteness, tick after tick
    (robots pressing on each other and a wall), after a rebuild, and with the present
    tick read while the next step runs."""
    spec = load_world(write_swarm_world(str(tmp_path / "w.toml"), 4, seed=3))
    spec.robot("r0").pose = (0.0, 0.0, 0.0)            # head on into r1
    spec.robot("r1").pose = (0.6, 0.05, math.pi)
    spec.robot("r2").pose = (4.5, 2.0, 0.0)            # into a wall
    local, mirror = Simulation(spec), Simulation(spec)
    physics = PhysicsProcess(spec, mirror, reader)
    contacts, by_worker = [], []
    try:
        names = list(local.robots)
        for k in range(40):
            if k == 25:                       # a sim/reset: rebuilt, one robot moved
                spec.robot("r1").pose = (0.5, -0.05, math.pi)
                local, mirror = Simulation(spec), Simulation(spec)
                physics.build(spec, mirror)
            for i, name in enumerate(names):  # the plant's own copy turns commands into
                mirror.command_twist(name, 0.9, 0.5 * math.sin(k / 7 + i))   # targets
                local.command_twist(name, 0.9, 0.5 * math.sin(k / 7 + i))
            physics.start_step(mirror.command_targets(), with_parts=k % 3 == 0)
            local.step_tick()
            physics.finish_step()
            by_worker.append(physics.read_by_worker)
            assert np.array_equal(physics.rows(), local.state_rows())
            for name in names:
                want, got = local.state(name), physics.state(name)
                assert np.array_equal(want.tf, got.tf) and want.yaw == got.yaw
                assert np.array_equal(want.v_body, got.v_body)
                assert np.array_equal(want.w_body, got.w_body)
                assert np.array_equal(want.enc_pos, got.enc_pos)
                assert np.array_equal(want.enc_vel, got.enc_vel)
            assert np.array_equal(physics.parts(), local.part_transforms())
            assert physics.finite and local.is_finite()
            physics.start_step(mirror.command_targets(), with_parts=True)  # the next one
            assert np.array_equal(physics.rows(), local.state_rows())     # under way:
            assert np.array_equal(physics.parts(), local.part_transforms())   # still now
            physics.finish_step()
            local.step_tick()
            contacts.append(local.world.getLastCollisionResult().getNumContacts())
        assert max(contacts) > 3 * len(names)        # more than the wheels on the floor
    finally:
        physics.close()
    assert physics.proc.poll() == 0
    if reader is not ADAPTIVE:                        # (adaptive: as the two race)
        assert set(by_worker) == {reader is ALWAYS_WORKER}


@pytest.mark.slow
def test_a_world_that_is_not_finite_is_told_as_the_plant_would_find_it():
    """The worker's answer says whether the robots' state is finite, as
    Simulation.is_finite finds the same world here: a start pose of NaN is not (after a
    step, as DART left it); rebuilt sound, it is again."""
    spec = load_world("empty")
    spec.robots[0].pose = (math.nan, 0.0, 0.0)
    local, mirror = Simulation(spec), Simulation(spec)
    physics = PhysicsProcess(spec, mirror)
    try:
        assert not local.is_finite() and not physics.finite
        local.step_tick()
        physics.start_step(np.zeros((1, 2)))
        physics.finish_step()
        assert physics.finite == local.is_finite()
        spec.robots[0].pose = (0.5, 0.0, 0.0)
        physics.build(spec, Simulation(spec))
        assert physics.finite
        physics.start_step(np.full((1, 2), 3.0))
        physics.finish_step()
        assert physics.finite
    finally:
        physics.close()


@pytest.mark.slow
@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="one CPU: nothing to split")
def test_the_plant_and_its_physics_process_keep_to_cores_of_their_own(monkeypatch):
    """Asked to (DIFFBOT_PIN_PHYSICS=1), the worker runs on a core the plant's thread does
    not (so a woken worker cannot queue behind the plant on its core), and the plant's
    thread gets its cores back when the physics process closes; unasked, neither is pinned
    (runs side by side would pin their workers to one core)."""
    before = os.sched_getaffinity(0)
    spec = load_world("empty")
    monkeypatch.delenv("DIFFBOT_PIN_PHYSICS", raising=False)
    physics = PhysicsProcess(spec, Simulation(spec))
    try:
        assert os.sched_getaffinity(0) == before == os.sched_getaffinity(physics.proc.pid)
    finally:
        physics.close()
    if len(before) < 2:
        pytest.skip("one CPU: nothing to keep apart")
    monkeypatch.setenv("DIFFBOT_PIN_PHYSICS", "1")
    physics = PhysicsProcess(spec, Simulation(spec))
    try:
        mine, theirs = os.sched_getaffinity(0), os.sched_getaffinity(physics.proc.pid)
        assert mine and theirs and not mine & theirs and mine | theirs == before
        physics.start_step(np.zeros((1, 2)))
        physics.finish_step()
    finally:
        physics.close()
    assert os.sched_getaffinity(0) == before


@pytest.mark.parametrize("mode,n", [("dynamic", 4), ("dynamic", 2), ("kinematic", 4)])
def test_the_snapshot_holds_each_robots_state_and_parts_to_the_bit(tmp_path, mode, n):
    """What the plant reads of every robot at once (Simulation.state_rows,
    part_transforms), is what Simulation.state and DART's world transforms give: read for
    all robots in one pass (4) or robot by robot (a few: 2)."""
    sim = Simulation(load_world(write_swarm_world(str(tmp_path / "w.toml"), n, 5, mode)))
    for k in range(30):
        for i, name in enumerate(sim.robots):
            sim.command_twist(name, 0.4, 1.5 * math.sin(k / 5 + i))
        sim.step_tick()
    rows = sim.state_rows()
    assert rows.shape == (n, 26)
    for row, name in zip(rows, sim.robots):
        st = sim.state(name)
        assert row.tolist() == np.concatenate([st.tf.ravel(), st.v_body, st.w_body,
                                               st.enc_pos, st.enc_vel]).tolist()
    if mode == "dynamic":
        assert sim.part_transforms().tolist() == \
            [sn.getWorldTransform().matrix().tolist() for sn, *_ in sim._robot_parts]
        # a mirror of that world, loaded from the worker's slot, reads the same rows (its
        # wheels from the slot)
        layout = Layout(sim)
        slot = np.full(layout.state_len, np.nan)
        store_state(sim, layout, slot)
        mirror = Mirror(Simulation(sim.spec), layout.skeletons, [np.zeros_like(slot), slot])
        mirror.load(1)
        assert mirror.rows(1).tobytes() == rows.tobytes()


def test_the_step_asks_for_the_parts_where_a_robot_casts_rays_at_the_next_tick(tmp_path):
    """The stepper asks the physics process for the parts' poses at a tick exactly where
    some robot's lidar or camera is due then (RobotSensors.needs_scene), robots of
    different rates and one without a lidar."""
    spec = load_world(write_swarm_world(str(tmp_path / "w.toml"), 3, seed=1))
    spec.robot("r1").sensors.lidar = dataclasses.replace(spec.robot("r1").sensors.lidar,
                                                         rate_hz=25.0)   # every 2nd tick
    spec.robot("r2").sensors.lidar = None
    sim, sensors = build_world(spec, 0)
    asked = []

    class Physics:                        # the stepper's side of a physics process
        finite = True

        def start_step(self, targets, with_parts=False):
            asked.append(with_parts)

        def finish_step(self):
            pass

    stepper = Stepper(spec, sim, Physics(), sensors, overlap=True)
    want = []
    for k in range(12):
        want.append(any(s.needs_scene(k + 1) for s in sensors.values()))
        stepper.start()
        stepper.finish()
    assert asked == want and want.count(True) == 7


@pytest.mark.slow
def test_the_tick_tells_its_host_when_to_publish():
    """The host asks the tick when to publish a tick's sensors: at its start, or, where the
    step overlaps the publishing, between start_step and finish_step (the physics process
    stepping, the world still at tick k); once a tick, and still owed where the run ends."""
    here = Tick(load_world("empty"))                  # in this process: never overlaps
    assert here.begin() and not here.publish_due()
    assert not here.start_step() and here.finish_step()
    tick = Tick(load_world("empty"), physics_process=True, overlap=True)
    try:
        t0 = tick.t_ns
        assert not tick.begin()
        assert tick.start_step() and tick.t_ns == t0  # publish tick k while it steps
        assert not tick.publish_due()
        assert tick.finish_step() and tick.t_ns == t0 + tick.tick_ns
        assert not tick.begin()
        assert tick.publish_due() and not tick.publish_due()   # the run ends here
        assert not tick.start_step()                  # published already
        tick.finish_step()
    finally:
        tick.close()


@pytest.mark.slow
def test_the_physics_process_tells_its_own_cpu_time(tmp_path):
    """cpu_s is the worker's CPU (user + system) as of its last step, not the plant's: what
    the operating system accounts to it (/proc, to the clock tick's resolution), grown by
    its steps (8 robots' 100 ticks cost it several hundredths of a second)."""
    spec = load_world(write_swarm_world(str(tmp_path / "w.toml"), 8, seed=0))
    physics = PhysicsProcess(spec, Simulation(spec))
    try:
        built = physics.cpu_s()
        for _ in range(100):
            physics.start_step(np.full((8, 2), 3.0))
            physics.finish_step()
        told = physics.cpu_s()
        with open(f"/proc/{physics.proc.pid}/stat") as f:       # (it waits: no CPU now)
            fields = f.read().rsplit(")", 1)[1].split()
        accounted = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    finally:
        physics.close()
    assert 0.05 < built and told - built > 0.03          # (it imported DART, built a world)
    assert told == pytest.approx(accounted, abs=0.025)
    assert physics.cpu_s() is None                       # closed


@pytest.mark.slow
def test_a_dead_physics_process_is_an_error_naming_it(tmp_path):
    spec = load_world("empty")
    physics = PhysicsProcess(spec, Simulation(spec))
    try:
        physics.proc.kill()
        physics.proc.wait(10)
        with pytest.raises(PhysicsError, match="physics process is gone"):
            physics.start_step(np.zeros((1, 2)))
            physics.finish_step()
    finally:
        physics.close()


@pytest.mark.slow
def test_a_failure_in_the_physics_process_comes_back_with_its_traceback():
    spec = load_world("empty")
    physics = PhysicsProcess(spec, Simulation(spec))
    try:
        bad = load_world("empty")
        bad.collision_detector = "no-such-detector"        # its world cannot be built there
        with pytest.raises(PhysicsError, match=r"(?s)physics process failed.*KeyError"):
            physics.build(bad, Simulation(spec))
    finally:
        physics.close()
    assert physics.proc.poll() == 1


def _swarm(tmp_path, name: str, *extra: str) -> tuple[dict, str, dict]:
    out = tmp_path / name
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "run", "swarm", "--robots", "3",
                        "--controller-processes", "2", "--coupling", "pipelined",
                        "--duration", "3", "--out", str(out), *extra],
                       cwd=ROOT, capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr
    with open(out / "summary.json") as f:
        summary = json.load(f)
    with open(out / "logs" / "plant.json") as f:
        return summary, (out / "paths.csv").read_text(), json.load(f)


@pytest.mark.slow
def test_pipelined_lockstep_with_the_physics_process_gives_the_same_run(tmp_path):
    """The plant publishes tick k while the physics steps to k+1: nothing on the bus
    changes, only who does the work when. The robots' distances are sums over every
    ground truth (scans steer them), so one different bit anywhere would show."""
    here, paths_here, st_here = _swarm(tmp_path, "in-process", "--no-physics-process")
    there, paths_there, st_there = _swarm(tmp_path, "own-process", "--physics-process")
    assert not st_here["physics_process"] and st_there["physics_process"]
    assert st_here["published"] == st_there["published"]
    assert st_here["published"]["r2/scan"] == 31                # 3 s of 10 Hz, both ends
    assert here["message_counts"] == there["message_counts"]
    assert here["metrics"]["distance_m"] == there["metrics"]["distance_m"]
    assert here["metrics"]["collisions"] == there["metrics"]["collisions"]
    assert paths_here == paths_there
    assert there["sim_time_s"] == pytest.approx(3.0)


@pytest.mark.slow
def test_the_physics_process_goes_with_a_killed_plant(procs, endpoint, tmp_path):
    plant = procs.diffbot("plant", "--world", "empty", "--mode", "fast", "--physics-process",
                          "--endpoint", endpoint, name="plant")

    def worker():
        for pid in os.listdir("/proc"):
            if pid.isdigit():
                try:
                    with open(f"/proc/{pid}/cmdline", "rb") as f:
                        cmd = f.read().split(b"\0")
                except OSError:
                    continue
                if b"plant.physics_process" in cmd and str(plant.pid).encode() in cmd:
                    return int(pid)
        return None
    pid = wait_for(worker, 30, what="the physics process")
    wait_for(lambda: "running empty" in procs.log(plant), 30, what="the plant running")
    plant.send_signal(signal.SIGKILL)
    plant.wait(10)
    wait_for(lambda: _gone(pid), 10, what="the physics process gone with the plant")
