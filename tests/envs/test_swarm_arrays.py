"""The swarm's vector env stepped as arrays (diffbot.envs.swarm_arrays) against the same env
through its messages (arrays=False), side by side, to the bit: every observation, reward,
flag and info of every robot of every world, for hundreds of steps through robots ending
alone, robot-robot contacts and the worlds' autoresets (next step and same step); the state
and frames written back; DART worlds too."""
from __future__ import annotations

import numpy as np
import pytest

from plant.footprint import FOOTPRINT_RADIUS_M, footprint_centres

pytest.importorskip("pettingzoo")
from diffbot.envs import swarm_v0  # noqa: E402

#: 6 robots driven forward at random: some touch each other or a wall, some reach their
#: goal (0.6 m), the others run out of steps, so robots end alone and worlds end often
KW = dict(n_robots=6, mode="kinematic", layout_seed=0, max_steps=40, robot="avoid",
          goal_radius_m=0.6)
W, STEPS = 3, 150


def _same(a, b, where: str) -> None:
    if isinstance(a, tuple):
        assert isinstance(b, tuple) and len(a) == len(b), where
        for k, (u, v) in enumerate(zip(a, b)):
            _same(u, v, f"{where}[{k}]")
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        assert a.shape == b.shape, where
        for i, (u, v) in enumerate(zip(a.tolist(), b.tolist())):
            if isinstance(u, dict):
                _same(u, v, f"{where}[{i}]")
            else:
                assert u == v, f"{where}[{i}]"
    else:
        a, b = np.asarray(a), np.asarray(b)
        assert a.dtype == b.dtype and a.shape == b.shape, where
        assert a.tobytes() == b.tobytes(), where


def _robot_contacts(infos: dict) -> int:
    """The robots whose contact this step was another robot's footprint (by their poses)."""
    n = 0
    for pose, hit, on in zip(infos["pose"], infos["contact"], infos["active"]):
        c = footprint_centres(*pose.T)
        d = np.hypot(*(c[:, None] - c[None]).transpose(2, 0, 1)) + 9 * np.eye(len(c))
        n += int((hit & on & (d < 2 * FOOTPRINT_RADIUS_M + 0.05).any(1)).sum())
    return n


@pytest.mark.parametrize("mode", ["next_step", "same_step"])
def test_arrays_give_the_messages_numbers_through_ends_contacts_and_autoresets(mode):
    fast = swarm_v0.vector_env(W, autoreset_mode=mode, **KW)
    slow = swarm_v0.vector_env(W, autoreset_mode=mode, arrays=False, **KW)
    assert fast.arrays is not None and slow.arrays is None
    rng = np.random.default_rng(7)
    seen = {"robots": 0, "contact": 0, "is_success": 0, "trunc": 0, "resets": 0}
    with fast, slow:
        _same(fast.reset(seed=21), slow.reset(seed=21), "reset")
        for s in range(STEPS):
            act = rng.uniform(fast.action_space.low, fast.action_space.high).astype(np.float32)
            act[..., 0] = np.abs(act[..., 0])
            if s == 70:                    # a masked reset of one world, mid-episode
                m = {"reset_mask": np.arange(W) == 1}
                _same(fast.reset(seed=5, options=m), slow.reset(seed=5, options=m), "mask")
            got, want = fast.step(act), slow.step(act)
            _same(got, want, f"step {s}")
            infos = got[4]
            seen["contact"] += int(infos["contact"].sum())
            seen["robots"] += _robot_contacts(infos)
            seen["is_success"] += int(infos["is_success"].sum())
            seen["trunc"] += int(got[3].sum())
            seen["resets"] += int(infos.get("_final_obs", np.zeros(W, bool)).sum())
            if s % 67 == 0:           # the objects written back: the global state
                _same(fast.state(), slow.state(), f"state at {s}")
        assert fast.arrays.ticks._plan is not None            # (the arrays did step)
    # every way a robot's episode ends happened, so each was compared
    assert seen["robots"] and seen["contact"] and seen["is_success"] and seen["trunc"], seen
    if mode == "same_step":
        assert seen["resets"], seen


def test_frames_after_array_steps_are_the_messages_ones():
    kw = {**KW, "render_mode": "rgb_array"}
    fast = swarm_v0.vector_env(2, **kw)
    slow = swarm_v0.vector_env(2, arrays=False, **kw)
    with fast, slow:
        fast.reset(seed=3)
        slow.reset(seed=3)
        act = np.tile(np.float32([0.3, 0.5]), (2, KW["n_robots"], 1))
        for _ in range(4):
            fast.step(act)
            slow.step(act)
        for a, b in zip(fast.render(), slow.render()):
            assert np.array_equal(a, b)


def test_the_worlds_state_is_the_cores_data_a_row_per_world_and_robot():
    """The arrays' state is a plant.core Data of the W worlds of N robots: world w's robot
    r's dead reckoning, limiter and noise keys at [w, r], each world's clock at [w], as the
    message path leaves them in its objects."""
    fast, slow = swarm_v0.vector_env(2, **KW), swarm_v0.vector_env(2, arrays=False, **KW)
    with fast, slow:
        fast.reset(seed=3)
        slow.reset(seed=3)
        act = np.tile(np.float32([0.3, 0.5]), (2, KW["n_robots"], 1))
        act[1, :, 1] *= -1                       # (the worlds' robots turn apart)
        for _ in range(3):
            fast.step(act)
            slow.step(act)
        data = fast.arrays.ticks.data
        assert data.odometry["pose"].shape == (2, KW["n_robots"], 3)
        for w, env in enumerate(slow.envs):
            sim = env.task.transport.tick.sim
            assert data.steps[w] == sim.steps > 0 and data.t_ns[w] == env.task.t_ns
            for r, name in enumerate(slow.possible_agents):
                od = env.task.observers[name].odom
                assert data.odometry["pose"][w, r].tolist() == [od.x, od.y, od.theta]
                assert data.odometry["vel"][w, r].tolist() == [od.v, od.w]
                assert (float(data.drive["v"][w, r]), float(data.drive["w"][w, r]),
                        tuple(data.drive["wheels"][w, r].tolist())) == \
                    sim.drive.limiter(sim.drive.index[name])
                assert data.drive["keys"][w, r] == sim.motion_noise[name].key


def test_every_noise_on_worlds_out_of_phase_give_the_messages_numbers(monkeypatch):
    """Encoder, lidar and motion noise on every robot, each drawn at its own world's tick
    (a world reset mid-run: the worlds' clocks apart) from its own robot's key: the same
    bits as the messages."""
    import plant.swarm_world as sw
    tables = sw._robot_tables

    def noisy(robot: str) -> list[str]:      # (the lidar's table last: its noise, then more)
        return tables(robot)[:-1] + ["noise = { std = 0.01 }", "", "[robots.encoders]",
                                     "noise = { std = 0.002 }", "", "[robots.motion]",
                                     "command_noise_std_radps = 0.05", ""]
    monkeypatch.setattr(sw, "_robot_tables", noisy)
    kw = {**KW, "n_robots": 3, "max_steps": 60}
    fast = swarm_v0.vector_env(3, **kw)
    slow = swarm_v0.vector_env(3, arrays=False, **kw)
    rng = np.random.default_rng(4)
    with fast, slow:
        _same(fast.reset(seed=8), slow.reset(seed=8), "reset")
        spec = fast.envs[0].task.spec.robots
        assert all(r.sensors.encoder_noise.std and r.sensors.lidar_noise.std
                   and r.sensors.command_noise_std_radps for r in spec)
        for s in range(12):
            if s == 5:                     # world 1 starts again: its clock behind the others'
                m = {"reset_mask": np.arange(3) == 1}
                _same(fast.reset(seed=2, options=m), slow.reset(seed=2, options=m), "mask")
            act = rng.uniform(fast.action_space.low, fast.action_space.high).astype(np.float32)
            act[..., 0] = np.abs(act[..., 0])
            _same(fast.step(act), slow.step(act), f"step {s}")
        steps = fast.arrays.ticks.data.steps
        assert steps[1] < steps[0] == steps[2]


def test_dart_worlds_as_arrays_give_the_messages_numbers():
    """DART steps each world once a tick between the kernel's two halves (the robots
    pushing each other are DART's contacts): the same bits, through ends and resets."""
    kw = {**KW, "mode": "dynamic", "n_robots": 3, "max_steps": 8}
    fast = swarm_v0.vector_env(2, autoreset_mode="same_step", **kw)
    slow = swarm_v0.vector_env(2, autoreset_mode="same_step", arrays=False, **kw)
    rng = np.random.default_rng(2)
    with fast, slow:
        _same(fast.reset(seed=4), slow.reset(seed=4), "reset")
        for s in range(20):
            act = rng.uniform(fast.action_space.low, fast.action_space.high).astype(np.float32)
            _same(fast.step(act), slow.step(act), f"step {s}")
        assert fast.arrays.ticks._plan is not None and not fast.arrays.ticks._plan.kinematic
        _same(fast.state(), slow.state(), "state")


def test_a_world_that_diverges_is_named():
    venv = swarm_v0.vector_env(3, **KW)
    with venv:
        venv.reset(seed=1)
        venv.envs[2].task.transport.tick.sim.kin.pose[1, 0] = np.nan
        with pytest.raises(FloatingPointError, match=r"swarm world 2 diverged"):
            venv.step(np.zeros((3, KW["n_robots"], 2), np.float32))


def test_a_cast_is_the_worlds_scenes_built_afresh_with_every_robot_where_it_is():
    """The lidars' cast of a step (every world's scene laid out once, the robots' parts
    written in place each cast) against :func:`plant.lidar.scan_worlds` of each world's
    scene built afresh, step after step while the robots move and see each other: the same
    bits, for every robot and for some."""
    from plant import lidar as lid
    from plant.raycast import Scene
    venv = swarm_v0.vector_env(2, **{**KW, "max_steps": 200})
    act = np.tile(np.float32([0.4, 0.9]), (2, KW["n_robots"], 1))
    seen = 0
    with venv:
        venv.reset(seed=3)
        for _ in range(5):
            venv.step(act)
            plan = venv.arrays.ticks._plan
            due = np.arange(len(plan.at))
            firsts = np.unique(plan.world_of)
            world = np.searchsorted(firsts, plan.world_of)
            tfs = plan.worlds.transforms(due)
            fresh = [Scene.from_shapes(plan.sims[k].shapes()) for k in firsts.tolist()]
            want = lid.scan_worlds(plan.cfg, fresh, tfs, plan.names, world)
            assert plan._cast_worlds(due).tobytes() == want.tobytes()
            for k, sc in enumerate(fresh):              # every shape where it is, seen or not
                rows = slice(plan.scenes.starts[k], plan.scenes.starts[k + 1])
                assert plan.scenes.centers[rows].tobytes() == sc.centers.tobytes()
                assert plan.scenes.rotations[rows].tobytes() == sc.rotations.tobytes()
            some = due[1::3]
            assert plan._cast_worlds(some).tobytes() == want[some].tobytes()
            rooms = lid.scan_worlds(plan.cfg, [plan.sims[k].room_scene() for k in firsts],
                                    tfs, [None] * len(due), world)
            seen += int((want != rooms).any(axis=1).sum())    # lidars that saw a robot
    assert seen >= 5, seen
