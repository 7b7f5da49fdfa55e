"""The core (plant/core: model, data, step) against the per-message path, its oracle.

``Tick.messages`` makes every robot's messages at once (plant.core: the bytes, or the
messages of the same values for in-process hosts); the
per-message path (plant.sensors.RobotSensors through plant.tick.tick_messages) makes them
robot by robot. Two copies of a world, driven alike, must publish the same bytes, tick
after tick: several robots, kinematic and dynamic, noise on every stream, readers that
come and go (a due topic nobody reads is not built, its noise still drawn), lidars due and
not, a camera robot.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bus import codec, packed
from plant.camera import CameraConfig
from plant.noise import NoiseConfig
from plant.swarm_world import write_swarm_world
from plant import core
from plant.tick import Tick, tick_messages
from plant.world import load_world

from bus.controller import Twist, WheelSpeeds


def _noisy(spec, camera: bool):
    for k, r in enumerate(spec.robots):
        s = r.sensors
        s.encoder_noise = NoiseConfig(std=0.01, bias=0.001 * k)
        s.gps_noise = NoiseConfig(std=0.02, resolution=0.005 if k % 2 else 0.0)
        if s.lidar is not None and k != 1:          # robot 1's lidar noise-free
            s.lidar_noise = NoiseConfig(std=0.05, resolution=0.01 if k == 2 else 0.0)
        elif s.lidar is not None:                   # (its ranges quantised: a lidar of its own)
            s.lidar = dataclasses.replace(s.lidar, resolution_m=0.02)
        s.command_noise_std_radps = 0.05
    if camera:
        cam = spec.robots[-1].sensors
        cam.camera = CameraConfig(width=32, height=24, rate_hz=25.0)
        cam.camera_noise = NoiseConfig(std=8.0)
    return spec


def _world(kind: str, tmp_path):
    if kind == "follow":                       # dynamic, a lidar robot and a camera robot
        return _noisy(load_world("living_room_follow"), camera=False)
    n = 10 if kind == "kinematic" else 5          # (more than bus.packed's few rows)
    path = write_swarm_world(str(tmp_path / f"{kind}.toml"), n, seed=3, mode=kind)
    return _noisy(load_world(path), camera=True)


def _wanted(names, tick: int):
    """Readers that come and go: a pure function of (robot, topic, tick); some ticks
    every topic is read (None)."""
    if tick % 7 == 3:
        return None
    return {n: (lambda topic, i=i: (len(topic) + i + tick) % 3 != 0 or (i + tick) % 5 == 4)
            for i, n in enumerate(names)}


def _drive(tick: Tick, k: int) -> None:
    for i, name in enumerate(tick.sensors):
        if (i + k) % 4 == 0:
            tick.drive(name, WheelSpeeds(2.0 + 0.1 * i, 3.0 - 0.2 * k % 2))
        elif (i + k) % 4 == 3:
            tick.drive(name, None)
        else:
            tick.drive(name, Twist(0.4, 0.6 * ((i % 3) - 1) + 0.01 * k))


@pytest.mark.parametrize("kind", ["kinematic", "dynamic", "follow"])
def test_core_bytes_equal_the_per_message_path(kind, tmp_path):
    core_tick, oracle = Tick(_world(kind, tmp_path)), Tick(_world(kind, tmp_path))
    names = list(core_tick.sensors)
    seen: dict[str, int] = {}
    for k in range(26):
        want = _wanted(names, k)
        got = list(core_tick.messages(want, encoded=True))
        objects = list(core_tick.messages(want))          # (what in-process hosts read)
        # the plant's: only the read ones, each with its place among the due ones
        assert core_tick.messages_read(want or {}) == (
            len(got), [(i, *m) for i, m in enumerate(got) if m[2] is not None]), k
        st = oracle.stepper
        expect = list(tick_messages(oracle.t_ns, oracle.tick_ns, oracle.sensors, st.state,
                                    st.shapes, want, encoded=True))
        assert [m[:2] for m in got] == [m[:2] for m in expect] == [m[:2] for m in objects], k
        _check_poses(core_tick, oracle, got, k)
        _check_state(core_tick, oracle, k)
        for (robot, topic, data), (_, _, ref), (_, _, msg) in zip(got, expect, objects):
            assert data == ref, (k, robot, topic)
            assert (msg is None) == (ref is None), (k, robot, topic)
            assert msg is None or codec.encode(msg) == ref, (k, robot, topic)
            key = topic if data is not None else "unread"
            seen[key] = seen.get(key, 0) + 1
        for t in (core_tick, oracle):
            _drive(t, k)
            t.step()
            if k == 13:                         # a reset: another seed, the noise keys too
                t.reset(seed=11)
    # every kind of message was made and compared, and some were not read
    assert {"joint_states", "gps", "ground_truth", "scan", "unread"} <= set(seen)
    if kind != "dynamic":
        assert seen.get("camera/image_raw", 0) > 0 and seen.get("camera/camera_info", 0) > 0


def _check_state(core_tick: Tick, oracle: Tick, k: int) -> None:
    """The core's state arrays (a dynamic world's read in one pass) hold what
    ``Simulation.state`` gives robot by robot, to the bit: pose, yaw, body speeds, wheels."""
    d = core_tick.data
    for i, name in enumerate(oracle.sensors):
        st = oracle.stepper.state(name)
        for got, ref in ((d.tf[0, i], st.tf), (d.yaw[0, i], st.yaw), (d.v[0, i], st.v_body[0]),
                         (d.w[0, i], st.w_body[2]), (d.enc_pos[0, i], st.enc_pos),
                         (d.enc_vel[0, i], st.enc_vel)):
            assert np.asarray(got, float).tobytes() == np.asarray(ref, float).tobytes(), (k, name)


def _check_poses(core_tick: Tick, oracle: Tick, got: list, k: int) -> None:
    """``sim/poses`` of the tick the core sensed: rosbags' bytes of the TFMessage built from
    the per-message path's states (robot by robot, in the world's order), and each
    transform's doubles those of the robot's ground_truth pose where it was made."""
    T, t_ns = codec.T, oracle.t_ns
    data = core.poses(core_tick.model, core_tick.data, 0, core_tick.t_ns)
    transforms = []
    for name in oracle.sensors:
        st = oracle.stepper.state(name)
        (x, y, z), (qx, qy, qz, qw) = st.xyz, st.quaternion
        transforms.append(T["geometry_msgs/msg/TransformStamped"](
            header=codec.header(t_ns, "world"), child_frame_id=f"{name}/base_link",
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                rotation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))))
    assert data == codec.encode(T["tf2_msgs/msg/TFMessage"](transforms=transforms)), k
    tfs = {tf.child_frame_id: tf.transform
           for tf in codec.decode(data, "tf2_msgs/msg/TFMessage").transforms}
    for robot, topic, msg in got:
        if topic == "ground_truth" and msg is not None:
            p, tr = codec.decode(msg, "nav_msgs/msg/Odometry").pose.pose, tfs[f"{robot}/base_link"]
            pose = [p.position.x, p.position.y, p.position.z, p.orientation.x,
                    p.orientation.y, p.orientation.z, p.orientation.w]
            same = [tr.translation.x, tr.translation.y, tr.translation.z, tr.rotation.x,
                    tr.rotation.y, tr.rotation.z, tr.rotation.w]
            assert np.array(pose).tobytes() == np.array(same).tobytes(), (k, robot)


@pytest.mark.parametrize("n", [3, 12])
def test_rows_pack_equals_the_single_message_encoders(n):
    """bus.packed.Rows, a few rows (each written on its own) and many (one matrix): rows of
    different frame ids (different lengths and field places), a subset of rows, the bytes
    of the per-message encoders."""
    frames = [f"{'r' * (1 + i % 5)}{i}/base_link" for i in range(n)]
    rows = packed.odometry_rows(["world"] * n, frames)
    rng = np.random.default_rng(0)
    pose, twist = rng.normal(size=(n, 7)), np.zeros((n, 6))
    twist[:, [0, 5]] = rng.normal(size=(n, 2))
    t_ns = 12_345_678_901
    got = rows.pack(t_ns, {"pose": pose, "twist": twist})
    pick = list(range(n))[::-1][:n - 1]
    sub = rows.pack(t_ns, {"pose": pose[pick], "twist": twist[pick]}, pick)
    for i, f in enumerate(frames):
        assert got[i] == packed.odometry(t_ns, *pose[i, :3], pose[i, 3:], twist[i, 0],
                                         twist[i, 5], frame_id="world", child_frame_id=f)
    assert sub == [got[i] for i in pick]
    lasers = [f"{'x' * (1 + i % 3)}/laser" for i in range(n)]
    scan = packed.laser_scan_rows(lasers, 5, -1.0, 1.0, 0.5, 0.1, 0.01, 8.0)
    ranges = rng.uniform(0.01, 8.0, size=(n, 5)).astype("<f4")
    ranges[0, 2] = np.inf
    for i, (f, m) in enumerate(zip(lasers, scan.pack(t_ns, {"ranges": ranges}))):
        assert m == codec.encode(codec.laser_scan(t_ns, -1.0, 1.0, 0.5, 0.1, 0.01, 8.0,
                                                  ranges[i], frame_id=f))


def test_a_model_of_several_worlds_senses_each_as_alone(tmp_path):
    """One Model and Data for W copies of a world (other seeds, other commands): world w's
    messages from the shared arrays are its own per-message path's, to the bit."""
    ticks = []
    for seed in (1, 2, 3):
        spec = _world("kinematic", tmp_path)
        spec.seed = seed
        ticks.append(Tick(spec))
    model = core.Model([t.spec for t in ticks])
    data = core.Data(model)
    assert data.tf.shape == (3, len(model.robots), 4, 4)
    for w, t in enumerate(ticks):
        data.set_streams(w, t.sensors)
    names = list(ticks[0].sensors)
    for k in range(12):
        for w, t in enumerate(ticks):
            core.observe(model, data, w, t.stepper)
        for w, t in enumerate(ticks):
            want = _wanted(names, k + w)
            got = core.sense(model, data, w, t.t_ns, t.stepper.shapes, want)
            expect = list(tick_messages(t.t_ns, t.tick_ns, t.sensors, t.stepper.state,
                                        t.stepper.shapes, want, encoded=True))
            assert got == expect, (k, w)
            _drive(t, k + 2 * w)
            t.step()
    assert ticks[0].sim.kin.pose.tolist() != ticks[1].sim.kin.pose.tolist()


def test_settled_readers_are_worked_out_once_a_phase_and_anew_for_new_readers(tmp_path):
    """The plant's readers (core.Settled: answers that hold for the object's life): what a
    tick reads is worked out at the first tick of each phase of the sensors' periods and
    kept; a new Settled object (a reader came or went) is asked again. The messages equal
    those of a plain dict with the same answers, lidar ticks and the others."""
    tick = Tick(_world("kinematic", tmp_path))
    names = list(tick.sensors)
    asked = []

    def readers(seed: int) -> dict:
        def wanted(i):
            def f(topic):
                asked.append((i, topic))
                return (len(topic) + i + seed) % 3 != 0
            return f
        return {n: wanted(i) for i, n in enumerate(names)}

    first, due = core.Settled(readers(0)), set()
    for k in range(12):
        if k == 7:
            first = core.Settled(readers(1))         # the readers changed
            asked.clear()
        got = tick.messages_read(first)
        assert got == tick.messages_read(readers(0 if k < 7 else 1)), k
        assert len(got[1]) < got[0], k              # (some due message is unread)
        due.add(got[0])
        if k in (5, 6, 11):                          # (phases met before, as the same object)
            asked.clear()
            tick.messages_read(first)
            assert asked == [], k
        tick.step()
    assert len(due) > 1                              # (ticks with a lidar due and without)
