"""plant/kernels/sense.c against the Python it replaces, on any values.

The kernel writes every robot's joint_states, gps and ground_truth in one call, reads a
kinematic world's state and turns transforms into quaternions, and makes a lidar's
reported ranges; each is compared to the bit with the per-message path (the oracle:
plant.tick.tick_messages with plant.sensors.RobotSensors, plant.sim.Simulation.kin_state,
plant.sim.rotation_to_quaternion, plant.lidar.apply_noise) on states no world reaches:
NaN, infinities, -0.0, huge values, rotations of every branch of the quaternion's
formula, many robots, noisy and not, some topics not read.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from bus import codec
from plant import core, kernels
from plant import lidar as lid
from plant.noise import NoiseConfig, NoiseModel
from plant.sim import RobotState, Simulation, rotation_to_quaternion
from plant.swarm_world import write_swarm_world
from plant.tick import Tick, build_world, tick_messages
from plant.world import load_world

pytestmark = pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")  # (the oracle's)

ODD = [math.nan, -math.nan, math.inf, -math.inf, -0.0, 0.0, 1e300, -1e-310, 5e-324]


def _laws(k: int) -> NoiseConfig:
    """Robot k's noise: none, noise, bias alone, quantisation alone (by halves: ties to
    even), noise and bias, all together."""
    return [NoiseConfig(), NoiseConfig(std=0.01), NoiseConfig(bias=-0.003, mean=0.001),
            NoiseConfig(resolution=0.5), NoiseConfig(std=0.02, bias=0.3),
            NoiseConfig(std=0.2, mean=0.1, bias=0.05, resolution=0.01)][k % 6]


@pytest.fixture(scope="module")
def spec(tmp_path_factory):
    path = write_swarm_world(str(tmp_path_factory.mktemp("w") / "w.toml"), 40, seed=5,
                             mode="kinematic")
    spec = load_world(path)
    for k, r in enumerate(spec.robots):
        r.sensors.encoder_noise = _laws(k)
        r.sensors.gps_noise = _laws(k + 2)
    return spec


def _odd_state(rng, n: int) -> dict[str, np.ndarray]:
    """Random states of n robots, with odd values sprinkled in, and rotations of every
    kind (a trace above 0 and each diagonal element leading)."""
    tf = np.tile(np.eye(4), (n, 1, 1))
    tf[:, :3, :3] = rng.normal(size=(n, 3, 3))
    tf[:, :3, 3] = rng.normal(scale=30.0, size=(n, 3))
    enc_pos, enc_vel = rng.normal(scale=50.0, size=(n, 2)), rng.normal(size=(n, 2))
    v, w = rng.normal(size=n), rng.normal(size=n)
    for a in (tf[:, :3, :], enc_pos, enc_vel, v, w):
        flat = a.reshape(-1) if a.flags.c_contiguous else None
        if flat is None:
            flat = a
        pick = rng.random(a.shape) < 0.08
        a[pick] = rng.choice(ODD, size=int(pick.sum()))
    ties = rng.random((n, 3)) < 0.2          # (values a law quantising by halves ties)
    tf[:, :3, 3][ties] = rng.choice([0.25, -2.75, 1.25], size=int(ties.sum()))
    enc_pos[ties[:, :2]] = rng.choice([0.75, -0.25], size=int(ties[:, :2].sum()))
    for i in range(3):                       # robots whose diagonal element i leads
        tf[3 * i + 1, :3, :3] = -np.eye(3)
        tf[3 * i + 1, i, i] = 0.5
    return {"tf": tf, "enc_pos": enc_pos, "enc_vel": enc_vel, "v": v, "w": w}


def _wanted(names, k: int):
    if k % 3 == 0:
        return None
    return {n: (lambda topic, i=i: (len(topic) * (i + 1) + k) % 4 != 0)
            for i, n in enumerate(names)}


def test_sense_bytes_equal_the_oracle_on_any_state(spec):
    """40 robots, five noise laws, NaN/inf/-0.0/huge values in every field, topics read or
    not: core.sense's bytes (and its messages' encodings) are the per-message path's."""
    rng = np.random.default_rng(1)
    _, sensors = build_world(spec, spec.seed)
    model, names = core.Model([spec]), [r.name for r in spec.robots]
    data = core.Data(model)
    data.set_streams(0, sensors)
    lidar_period = int(model.periods["scan"].max())
    seen = {"noisy": 0, "unread": 0, "nan": 0}
    for k in range(1, 13):
        tick = k if k % lidar_period else k + 1    # (no lidar due: no scene wanted)
        t_ns = tick * model.tick_ns
        st = _odd_state(rng, len(names))
        data.tf[0], data.enc_pos[0], data.enc_vel[0] = st["tf"], st["enc_pos"], st["enc_vel"]
        data.v[0], data.w[0] = st["v"], st["w"]
        kernels.quaternions(data.tf[0], data.quaternion[0])
        states = {n: RobotState(st["tf"][i], 0.0, np.array([st["v"][i], 0.0, 0.0]),
                                np.array([0.0, 0.0, st["w"][i]]), st["enc_pos"][i],
                                st["enc_vel"][i]) for i, n in enumerate(names)}
        want = _wanted(names, k)
        got = core.sense(model, data, 0, t_ns, None, want)
        objects = core.sense(model, data, 0, t_ns, None, want, encoded=False)
        expect = list(tick_messages(t_ns, model.tick_ns, sensors, states.__getitem__, None,
                                    want, encoded=True))
        assert [m[:2] for m in got] == [m[:2] for m in expect] == [m[:2] for m in objects]
        for (robot, topic, data_), (_, _, ref), (_, _, msg) in zip(got, expect, objects):
            assert data_ == ref, (k, robot, topic)
            assert (msg is None) == (ref is None) and (msg is None or codec.encode(msg) == ref)
            seen["unread"] += ref is None
        seen["nan"] += int(np.isnan(st["tf"]).any())
        seen["noisy"] += sum(s.gps_noise is not None for s in sensors.values())
    assert all(seen.values()), seen


def test_quaternions_equal_rotation_to_quaternion_bit_for_bit():
    rng = np.random.default_rng(2)
    tf = np.tile(np.eye(4), (400, 1, 1))
    tf[:, :3, :3] = rng.normal(size=(400, 3, 3))
    tf[:20, :3, :3] = -np.eye(3)                         # ties on the diagonal
    tf[20:60, :3, :3] *= rng.random((40, 3, 3)) < 0.5
    odd = rng.random((400, 3, 3)) < 0.05
    tf[:, :3, :3][odd] = rng.choice(ODD, size=int(odd.sum()))
    q = np.empty((400, 4))
    kernels.quaternions(tf, q)
    expect = np.array([rotation_to_quaternion(m) for m in tf], float)
    assert q.tobytes() == expect.tobytes()


def test_kinematic_observe_equals_kin_state(tmp_path):
    """A kinematic world's state read in one call: kin_state's transform, yaw (atan2 of
    libm's sine and cosine), quaternion, velocities and wheels, bit for bit, large and odd
    yaws and NaN and infinite positions included."""
    tick = Tick(load_world(write_swarm_world(str(tmp_path / "k.toml"), 30, seed=2,
                                             mode="kinematic")))
    kin, model = tick.sim.kin, core.Model([tick.spec])
    data = core.Data(model)
    rng = np.random.default_rng(3)
    kin.pose[:] = rng.normal(scale=[5.0, 5.0, 1e3], size=kin.pose.shape)
    kin.pose[:4, 2] = [math.nan, -math.nan, -0.0, 1e22]    # (math.cos(inf) raises)
    kin.pose[4:6, :2] = [[math.inf, -math.nan], [5e-324, -math.inf]]
    kin.vel[:] = rng.normal(size=kin.vel.shape)
    kin.wheels[:] = rng.normal(scale=100, size=kin.wheels.shape)
    kin.speeds[:] = rng.normal(size=kin.speeds.shape)
    core.observe(model, data, 0, tick.stepper)
    for i in range(len(model.robots)):
        st = Simulation.kin_state(kin, i)
        assert data.tf[0, i].tobytes() == st.tf.tobytes(), i
        assert data.yaw[0, i].tobytes() == np.float64(st.yaw).tobytes(), i
        assert data.quaternion[0, i].tobytes() == np.array(st.quaternion).tobytes(), i
        assert (data.v[0, i], data.w[0, i]) == (st.v_body[0], st.w_body[2])
        assert data.enc_pos[0, i].tobytes() == st.enc_pos.tobytes()
        assert data.enc_vel[0, i].tobytes() == st.enc_vel.tobytes()


@pytest.mark.parametrize("lo,q", [(0.0, 0.0), (0.12, 0.01)])
def test_lidar_noise_equals_apply_noise(lo, q):
    """Reported ranges of 181-ray scans (the normals drawn in chunks) with every kind of
    noise law, through inf, NaN, -0.0 and values outside [min, max]: apply_noise's bits
    (as float32, the message's)."""
    cfg = lid.LidarConfig(num_rays=181, min_range_m=lo, max_range_m=8.0, resolution_m=q)
    rng = np.random.default_rng(4)
    laws = [NoiseConfig(), NoiseConfig(std=0.05), NoiseConfig(bias=-0.02),
            NoiseConfig(std=0.3, mean=0.01, bias=0.02, resolution=0.005),
            NoiseConfig(resolution=0.02), NoiseConfig(resolution=0.5, bias=0.0)]
    exact = rng.uniform(-1.0, 10.0, size=(len(laws), 181))
    exact[:, :8] = [math.inf, math.nan, -0.0, 0.0, -math.inf, lo, 8.0, 1e300]
    exact[:, 8:12] = [0.75, 1.25, 2.75, 3.25]            # (ties of the halves' law)
    keys = np.array([11, 2**64 - 1, 0, 12345, 7, 9], np.uint64)
    table = np.array([(c.std, c.mean, c.bias, c.resolution) for c in laws], float)
    for tick in (0, 7, 2**40):
        got = kernels.lidar_noise(exact, keys, table, tick, lo, 8.0, q)
        for r, c in enumerate(laws):
            model = None if c.is_zero and c.resolution == 0 else NoiseModel(c, int(keys[r]))
            ref = lid.apply_noise(cfg, exact[r], model, tick).astype(np.float32)
            assert got[r].tobytes() == ref.tobytes(), (tick, r)
