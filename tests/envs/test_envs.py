"""The Gymnasium / PettingZoo environments keep their APIs' contracts and clean up after
themselves (the bit-identity of the two transports: test_envs_identity.py)."""
from __future__ import annotations

import gc
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("pettingzoo")
from gymnasium.utils.env_checker import check_env  # noqa: E402

import diffbot.envs  # noqa: E402,F401
from diffbot.runner.procs import alive, descendants  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _shm() -> set[str]:
    try:
        return set(os.listdir("/dev/shm"))
    except OSError:
        return set()


def _shm_mapped(pids) -> set[str]:
    """The /dev/shm names these processes have mapped (multiprocessing's semaphores,
    Zenoh's segments): what they made or use, whatever else runs on the machine."""
    names = set()
    for pid in pids:
        try:
            with open(f"/proc/{pid}/maps") as f:
                for line in f:
                    i = line.find("/dev/shm/")
                    if i >= 0:
                        names.add(line[i + 9:].split()[0])
        except OSError:
            pass
    return names


def _children() -> set[int]:
    return set(descendants(os.getpid()))


@pytest.fixture
def socket_dirs(monkeypatch):
    """A temp folder of this test's own for the bus envs' socket folders (TMPDIR, which
    spawned workers read, and tempfile's cached choice, which forked ones inherit): the
    folders left are counted there, whatever else runs on the machine. Short, for a unix
    socket's path. Yields a function listing the ``diffbot-env-*`` folders in it."""
    d = tempfile.mkdtemp(prefix="dbt-env-", dir="/tmp")
    monkeypatch.setenv("TMPDIR", d)
    monkeypatch.setattr(tempfile, "tempdir", d)
    yield lambda: [n for n in os.listdir(d) if n.startswith("diffbot-env-")]
    shutil.rmtree(d, ignore_errors=True)


@pytest.mark.parametrize("env_id", ["diffbot/Avoid-v0", "diffbot/Follow-v0"])
def test_check_env_inproc(env_id):
    env = gym.make(env_id)
    try:
        check_env(env.unwrapped, skip_render_check=True)
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ["diffbot/Avoid-v0", "diffbot/Follow-v0"])
def test_check_env_bus(env_id):
    before = _children()
    env = gym.make(env_id, transport="bus")
    try:
        check_env(env.unwrapped, skip_render_check=True)
        assert _children() - before, "the bus transport started no plant"
    finally:
        env.close()
    assert not (_children() - before), "close() left a process behind"


def test_dt_is_simulated_seconds_per_step():
    env = gym.make("diffbot/Avoid-v0")
    try:
        _, info = env.reset(seed=0)
        assert env.unwrapped.dt == pytest.approx(0.1)
        _, _, _, _, info = env.step(np.zeros(2, np.float32))
        assert info["t"] == pytest.approx(0.1)
    finally:
        env.close()


def test_observation_odometry_starts_at_the_origin_and_the_goal_is_relative():
    # REP 105: odom in <robot>/odom (origin = the start pose, info["pose"] at reset),
    # goal in <robot>/base_link; info in world
    import math
    from controllers.learned import wrap
    env = gym.make("diffbot/Avoid-v0")
    try:
        obs, info = env.reset(seed=2)
        x0, y0, th0 = info["pose"]
        c, s = math.cos(th0), math.sin(th0)

        def from_start(x, y):            # a world point in the start pose's frame
            return c * (x - x0) + s * (y - y0), -s * (x - x0) + c * (y - y0)
        assert np.array_equal(obs["odom"][:3], np.zeros(3, np.float32))
        assert obs["goal"] == pytest.approx(from_start(*info["goal"]), abs=1e-5)
        for _ in range(10):              # forward and turning left, no noise in this world
            obs, _, term, _, info = env.step(np.array([0.2, 0.5], np.float32))
            assert not term
        x, y, th = info["pose"]
        odom = from_start(x, y)
        assert obs["odom"][0] > 0.1 and obs["odom"][1] > 0.0      # ahead and to the left
        assert obs["odom"][:2] == pytest.approx(odom, abs=0.02)   # wheel slip only
        assert obs["odom"][2] == pytest.approx(wrap(th - th0), abs=0.03)
    finally:
        env.close()


def test_reset_seed_gives_the_same_episode_and_seeds_differ():
    env = gym.make("diffbot/Avoid-v0")
    try:
        a, ia = env.reset(seed=5)
        b, ib = env.reset(seed=5)
        c, ic = env.reset(seed=6)
        assert all(np.array_equal(a[k], b[k]) for k in a)
        assert np.array_equal(ia["goal"], ib["goal"])
        assert not np.array_equal(ia["goal"], ic["goal"])
    finally:
        env.close()


def test_bad_arguments_and_actions_are_clear_errors():
    with pytest.raises(ValueError, match="transport"):
        gym.make("diffbot/Avoid-v0", transport="tcp")
    env = gym.make("diffbot/Avoid-v0").unwrapped
    try:
        env.reset(seed=0)
        with pytest.raises(ValueError, match="finite"):
            env.step(np.array([np.nan, 0.0], np.float32))
        env.step(np.array([0.1, 0.0], np.float32))     # still usable
    finally:
        env.close()


@pytest.mark.slow
def test_the_module_id_form_imports_the_package_itself():
    code = ("import gymnasium; e = gymnasium.make('diffbot.envs:diffbot/Avoid-v0'); "
            "o, _ = e.reset(seed=1); print(o['scan'].shape); e.close()")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "(180,)"


def test_swarm_parallel_api():
    from pettingzoo.test import parallel_api_test
    from diffbot.envs import swarm_v0
    env = swarm_v0.parallel_env(n_robots=3)
    try:
        parallel_api_test(env, num_cycles=40)
    finally:
        env.close()


def test_a_swarm_of_avoid_robots_has_avoids_spaces_and_steps_in_the_kinematic_world():
    from pettingzoo.test import parallel_api_test
    from diffbot.envs import swarm_v0
    avoid = gym.make("diffbot/Avoid-v0")
    swarm = swarm_v0.parallel_env(n_robots=3, robot="avoid", mode="kinematic")
    plain = swarm_v0.parallel_env(n_robots=3)
    try:
        for a in swarm.possible_agents:       # an Avoid policy's input and output as they are
            sp, av = swarm.observation_space(a), avoid.observation_space
            assert sp["odom"] == av["odom"] and sp["goal"] == av["goal"]
            assert (sp["scan"].shape, sp["scan"].dtype) == (av["scan"].shape, av["scan"].dtype)
            # the scan's bound is each room's (diffbot.envs.avoid.scan_bound): 10 m x 10 m
            assert (float(sp["scan"].high[0]), float(av["scan"].high[0])) == (16.0, 9.0)
            assert swarm.action_space(a) == avoid.action_space
            assert plain.observation_space(a) != avoid.observation_space    # 36 rays
        assert swarm.task.spec.mode == "kinematic"
        parallel_api_test(swarm, num_cycles=30)
        swarm.reset(seed=2)
        assert len(swarm.task.transport.tick.sim.kin) == 3      # every robot in one array
    finally:
        for e in (avoid, swarm, plain):
            e.close()


@pytest.mark.slow
@pytest.mark.timeout(240)
@pytest.mark.parametrize("mode", ["dynamic", "kinematic"])
def test_swarm_on_the_bus_matches_inproc(mode):
    from diffbot.envs import swarm_v0
    envs = [swarm_v0.parallel_env(n_robots=2, transport=t, mode=mode) for t in ("inproc", "bus")]
    try:
        outs = [e.reset(seed=4) for e in envs]
        rng = np.random.default_rng(1)
        for _ in range(40):
            live = envs[0].agents
            if not live:
                break
            acts = {a: rng.uniform(-0.5, 0.5, 2).astype(np.float32) for a in live}
            outs = [e.step(acts) for e in envs]
            for a in outs[0][0]:
                assert all(np.array_equal(outs[0][0][a][k], outs[1][0][a][k])
                           for k in outs[0][0][a])
            assert outs[0][1] == outs[1][1] and outs[0][2] == outs[1][2]
            assert envs[0].agents == envs[1].agents
    finally:
        for e in envs:
            e.close()


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_make_vec_async_on_the_bus_leaves_nothing_behind(socket_dirs):
    before, mine = _children(), _shm_mapped([os.getpid()])
    # spawn: this test process ran Zenoh sessions before (other tests), and a fork of a
    # running Zenoh runtime hangs (docs/learning.md)
    venv = gym.make_vec("diffbot/Avoid-v0", num_envs=2, vectorization_mode="async",
                        vector_kwargs={"context": "spawn"}, transport="bus")
    try:
        obs, _ = venv.reset(seed=3)
        assert obs["scan"].shape == (2, 180)
        assert not np.array_equal(obs["scan"][0], obs["scan"][1])   # seeds 3 and 4
        for _ in range(5):
            obs, rew, term, trunc, _ = venv.step(venv.action_space.sample())
        ours = _children() - before
        plants = [p for p in ours if b"plant" in open(f"/proc/{p}/cmdline", "rb").read()]
        assert len(plants) == 2, "each env has a plant of its own"
        used = _shm_mapped([os.getpid(), *ours]) - mine
        assert any(n.startswith("sem.mp-") for n in used), f"no semaphore seen: {used}"
    finally:
        venv.close()
    del venv
    gc.collect()
    # (multiprocessing's own resource tracker stays for the life of this process)
    left = [p for p in _children() - before if alive(p)
            and b"resource_tracker" not in open(f"/proc/{p}/cmdline", "rb").read()]
    assert not left, f"processes left after close(): {left}"
    assert not socket_dirs(), "socket directories left"
    # /dev/shm is shared with whatever else runs here: judge the names the envs' processes
    # had mapped (multiprocessing's semaphores sem.mp-*, Zenoh's segments). Zenoh unlinks a
    # segment a moment after the last process using it is gone, except sometimes a small
    # watchdog segment that the next Zenoh process on the machine reclaims (seen on Zenoh
    # 1.x whatever the env does): such a one may stay, but nothing may still map it.
    deadline = time.monotonic() + 5.0
    while (used & _shm()) and time.monotonic() < deadline:
        time.sleep(0.2)
    left = used & _shm()
    assert not {n for n in left if not n.endswith(".zenoh")}, f"shared memory left: {left}"
    assert not _shm_mapped(_children()) & left, f"still mapped after close(): {left}"


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_make_vec_async_forked_after_a_bus_env_refuses_with_the_reason_at_once(socket_dirs):
    """The default "fork" context after a bus env ran in this process: the forked workers
    would hang in their first Zenoh session; they refuse at once, naming the remedy, and
    leave no plant and no socket folder."""
    env = gym.make("diffbot/Avoid-v0", transport="bus")
    try:
        env.reset(seed=0)                       # Zenoh's runtime now runs in this process
    finally:
        env.close()
    before = _children()
    t0 = time.monotonic()
    venv = gym.make_vec("diffbot/Avoid-v0", num_envs=2, vectorization_mode="async",
                        vector_kwargs={"context": "fork"}, transport="bus")
    try:
        with pytest.warns(UserWarning), pytest.raises(Exception, match="forked from one that "
                                                      "runs Zenoh") as err:
            venv.reset(seed=3)
        took = time.monotonic() - t0
    finally:
        venv.close()
    assert 'vector_kwargs={"context": "spawn"}' in str(err.value)
    assert took < 30, f"refused only after {took:.1f} s"
    left = [p for p in _children() - before if alive(p)
            and b"resource_tracker" not in open(f"/proc/{p}/cmdline", "rb").read()]
    assert not left, f"processes left: {left}"
    assert not socket_dirs(), "socket directories left"


@pytest.mark.slow
def test_a_bus_env_dropped_without_close_stops_its_plant():
    env = gym.make("diffbot/Avoid-v0", transport="bus")
    env.reset(seed=0)
    plant = env.unwrapped.task.transport._res.plant
    pid = plant.pid
    assert alive(pid)
    del env, plant
    gc.collect()
    assert not alive(pid), "the plant outlived its garbage-collected environment"


@pytest.mark.slow
def test_a_bus_env_left_open_at_interpreter_exit_stops_its_plant():
    code = ("import gymnasium, diffbot.envs; e = gymnasium.make('diffbot/Avoid-v0', "
            "transport='bus'); e.reset(seed=0); "
            "print(e.unwrapped.task.transport._res.plant.pid, flush=True)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert not alive(int(out.stdout.split()[-1]))


@pytest.mark.slow
def test_policy_controller_refuses_a_bad_file(tmp_path):
    bad = tmp_path / "p.npz"
    bad.write_bytes(b"not a policy")
    out = subprocess.run([sys.executable, "-m", "diffbot.cli", "controller", "policy",
                          "--file", str(bad), "--goal", "1,1"], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert "not a policy file" in out.stderr


def test_a_saved_policy_loads_with_the_same_actions_and_bad_shapes_are_refused(tmp_path):
    from controllers.learned import MLPPolicy
    env = gym.make("diffbot/Avoid-v0")
    try:
        obs, _ = env.reset(seed=0)
    finally:
        env.close()
    rng = np.random.default_rng(0)
    for hidden in ((), (6,)):
        p = MLPPolicy.from_vector(rng.normal(size=MLPPolicy.size(hidden)), hidden, v_max=0.5,
                                  w_max=2.0, action_repeat=5, v_min=-0.1)
        p.save(str(tmp_path / "p.npz"))
        q = MLPPolicy.load(str(tmp_path / "p.npz"))
        assert q.act(obs) == p.act(obs) and q.action_repeat == 5
        v, w = q.act(obs)
        assert -0.1 <= v <= 0.5 and -2.0 <= w <= 2.0
    with pytest.raises(ValueError, match="chain"):
        MLPPolicy([(np.zeros((5, 2)), np.zeros(2))], 0.5, 2.0, 5)
    with pytest.raises(ValueError, match="parameters"):
        MLPPolicy.from_vector(np.zeros(3), (), v_max=0.5, w_max=2.0, action_repeat=5)


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_a_bus_env_joins_a_running_plant_and_leaves_it_running(procs, endpoint):
    from diffbot.envs.transport import TransportError
    plant = procs.diffbot("plant", "--world", "living_room", "--mode", "lockstep", "--coupling",
                          "sequential", "--disable", "camera", "--endpoint", endpoint,
                          name="plant")
    own = gym.make("diffbot/Avoid-v0")
    env = gym.make("diffbot/Avoid-v0", transport="bus", endpoint=endpoint)
    try:
        a, _ = own.reset(seed=9)
        b, _ = env.reset(seed=9)
        assert all(np.array_equal(a[k], b[k]) for k in a)
        for _ in range(3):
            act = np.array([0.2, 0.3], np.float32)
            assert np.array_equal(own.step(act)[0]["scan"], env.step(act)[0]["scan"])
    finally:
        env.close()
        own.close()
    # the env left in order (FINAL): the plant ends its run as every member finished
    # (docs/PROTOCOL.md "Finishing"), exit 0; it was not stopped by the env
    assert plant.wait(30) == 0, procs.log(plant)
    assert "member finished: stopping" in procs.log(plant)
    plant2 = procs.diffbot("plant", "--world", "living_room", "--mode", "lockstep",
                           "--coupling", "pipelined", "--disable", "camera", "--endpoint",
                           endpoint.replace("bus.sock", "b2.sock"), name="plant2")
    env = gym.make("diffbot/Avoid-v0", transport="bus",
                   endpoint=endpoint.replace("bus.sock", "b2.sock"))
    try:
        with pytest.raises(TransportError, match="sequential coupling"):
            env.reset(seed=0)
    finally:
        env.close()
    assert plant2.poll() is None


def test_follow_sees_the_leader_ball_in_its_camera():
    env = gym.make("diffbot/Follow-v0", detection=True)
    try:
        obs, info = env.reset(seed=0)
        assert obs["image"].shape == (120, 160, 3) and obs["image"].std() > 5, "no camera image"
        assert obs["ball"][0] == 1.0, "the leader's ball is not seen at the start"
        assert 0.3 < info["distance"] < 1.5
        obs, r, *_ = env.step(np.zeros(2, np.float32))
        assert obs["ball"][0] == 1.0 and -1.0 <= r <= 1.0
    finally:
        env.close()
