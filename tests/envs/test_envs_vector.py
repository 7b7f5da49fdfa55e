"""gym.make_vec("diffbot/Avoid-v0", vectorization_mode="vector_entry_point") steps N worlds in
one process, and env i is the single env with seed + i, to the bit, through Gymnasium's
next-step autoresets, in both world modes, noise on."""
from __future__ import annotations

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
import diffbot.envs  # noqa: E402,F401
from gymnasium.vector import AutoresetMode  # noqa: E402

NOISE = ("robots.robot1.encoders.noise={std = 0.002}", "robots.robot1.lidar.noise={std = 0.01}",
         "robots.robot1.motion.command_noise_std_radps=0.05")


def _same_obs(batch: dict, k: int, one: dict) -> bool:
    return all(batch[key][k].tobytes() == one[key].tobytes() for key in one)


def _same_infos(a: dict, b: dict) -> bool:
    """Batched infos alike: the same keys in the same order, dtypes, shapes and values (the
    objects equal, the rest to the bit)."""
    if list(a) != list(b):
        return False
    for key in a:
        x, y = a[key], b[key]
        if x.dtype != y.dtype or x.shape != y.shape:
            return False
        if x.dtype == object:
            if not all(u == v for u, v in zip(x, y)):
                return False
        elif x.tobytes() != y.tobytes():
            return False
    return True


def _objects(task) -> tuple:
    """What a task's objects hold between steps (the array path writes it back only when
    asked: ArrayTicks.flush): odometry, observer scan, limiter, wheel targets, world clock,
    the task's time, truth and last scan (what its render draws)."""
    name = task.robots[0]
    sim, obs = task.transport.tick.sim, task.observers[name]
    od, i = obs.odom, sim.drive.index[name]
    scan = task.scans.get(name)
    return (od.x, od.y, od.theta, od.v, od.w, tuple(od._last), od._last_t,
            sim.drive.limiter(i), tuple(sim.drive.targets[i].tolist()), sim.steps, task.t_ns,
            task._ticks_left, task.truth, np.asarray(obs.scan).tobytes(),
            None if scan is None else np.asarray(scan.ranges, np.float32).tobytes())


@pytest.mark.timeout(600)
@pytest.mark.parametrize("mode", ["kinematic", "dynamic"])
def test_each_batched_env_is_the_single_env_with_its_seed(mode):
    n, seed, horizon = 3, 20, 12
    kw = dict(max_episode_steps=horizon, overrides=(f"world.mode={mode}", *NOISE))
    vec = gym.make_vec("diffbot/Avoid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                       **kw)
    singles = [gym.make("diffbot/Avoid-v0", **kw) for _ in range(n)]
    try:
        assert vec.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
        obs, infos = vec.reset(seed=seed)
        for k, env in enumerate(singles):
            one, info = env.reset(seed=seed + k)
            assert _same_obs(obs, k, one), f"env {k} differs after reset"
            assert infos["plant"][k] == info["plant"]
        rng = np.random.default_rng(1)
        over = [False] * n
        resets = 0
        for step in range(30):
            a = (rng.uniform(-1, 1, (n, 2)) * vec.single_action_space.high).astype(np.float32)
            obs, rew, term, trunc, infos = vec.step(a)
            expected: dict = {}          # the singles' infos as Gymnasium batches them
            for k, env in enumerate(singles):
                if over[k]:          # next-step autoreset: the action is ignored
                    one, info = env.reset()
                    r, te, tr = 0.0, False, False
                    resets += 1
                else:
                    one, r, te, tr, info = env.step(a[k])
                over[k] = te or tr
                where = f"env {k} at step {step}"
                assert _same_obs(obs, k, one), f"observation of {where}"
                assert (rew[k], term[k], trunc[k]) == (r, te, tr), f"reward/flags of {where}"
                assert infos["pose"][k].tobytes() == np.asarray(info["pose"]).tobytes(), where
                expected = vec.unwrapped._add_info(expected, info, k)
            assert _same_infos(infos, expected), f"infos at step {step}"
        assert resets >= n, "no autoreset was crossed"
    finally:
        vec.close()
        for env in singles:
            env.close()


def test_batched_contacts_end_the_same_episodes_as_the_single_env():
    """Full speed ahead until something is hit: the batch judges every world's contacts in
    one call (diffbot.envs.geometry.Footprints.contacts_of), each as the single env does."""
    n, seed = 3, 7
    kw = dict(max_episode_steps=200, overrides=("world.mode=kinematic",))
    vec = gym.make_vec("diffbot/Avoid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                       **kw)
    singles = [gym.make("diffbot/Avoid-v0", **kw) for _ in range(n)]
    try:
        vec.reset(seed=seed)
        for k, env in enumerate(singles):
            env.reset(seed=seed + k)
        ahead = np.tile(vec.single_action_space.high * [1.0, 0.0], (n, 1)).astype(np.float32)
        live, hits = [True] * n, 0
        for step in range(200):
            _, rew, term, trunc, infos = vec.step(ahead)
            for k, env in enumerate(singles):
                if not live[k]:
                    continue
                _, r, te, tr, info = env.step(ahead[k])
                assert (bool(infos["contact"][k]), rew[k], term[k], trunc[k]) == \
                    (info["contact"], r, te, tr), f"env {k} at step {step}"
                hits += info["contact"]
                live[k] = not (te or tr)
            if not any(live):
                break
        assert hits >= 2, f"only {hits} of {n} episodes ended on a contact"
    finally:
        vec.close()
        for env in singles:
            env.close()


#: every kind of noise the batch's arrays make, quantised where a world file may quantise
ALL_NOISE = ("robots.robot1.encoders.noise={std = 0.002, resolution = 0.001}",
             "robots.robot1.lidar.noise={std = 0.01, bias = 0.003}",
             "robots.robot1.lidar.resolution_m=0.005", "robots.robot1.gps.noise={std = 0.5}",
             "robots.robot1.motion.command_noise_std_radps=0.05")


#: the living room with a movable box in the middle (the lidars must see it)
MOVABLE = """[world]
extends = "living_room"

[[objects]]
name = "crate"
shape = "box"
size_m = [0.4, 0.4, 1.0]
pose = [0.3, -0.4, 0.0, 0.5]
color = [0.6, 0.5, 0.3]
static = false
mass_kg = 3.0
"""


@pytest.mark.parametrize("mode,repeat,normalize,world", [
    ("kinematic", 5, False, "living_room"), ("kinematic", 3, True, "movable"),
    pytest.param("dynamic", 5, False, "living_room", marks=pytest.mark.slow)])
def test_worlds_ticked_as_arrays_give_the_messages_numbers(mode, repeat, normalize, world,
                                                           tmp_path):
    """A batch of one-robot worlds ticks as arrays (diffbot.envs.kinbatch), kinematic or
    DART; the same batch through the plant's messages (arrays=None) is the oracle:
    observations, rewards, flags, poses, contacts and the rendered view to the bit, every
    noise on, through autoresets (an action_repeat of 3 puts the worlds' lidars out of
    phase after their resets), the drive limiter's ramps and clamps, robots standing (no
    command noise) between runs, actions in the robot's units and normalised, a movable
    object in the lidars' sight."""
    from diffbot.envs.kinbatch import ArrayTicks
    n = 6
    if world == "movable":
        (tmp_path / "movable.toml").write_text(MOVABLE)
        world = str(tmp_path / "movable.toml")
    kw = dict(max_episode_steps=60, action_repeat=repeat, render_mode="rgb_array", world=world,
              normalize_actions=normalize,
              overrides=(f"world.mode={mode}", *ALL_NOISE,
                         "robots.robot1.drive.max_wheel_speed_radps=5.0"))   # the cap bites
    fast = gym.make_vec("diffbot/Avoid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                        **kw)
    slow = gym.make_vec("diffbot/Avoid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                        **kw)
    slow.unwrapped.chunks[0].arrays = None
    try:
        a, _ = fast.reset(seed=11)
        b, _ = slow.reset(seed=11)
        assert ArrayTicks.eligible(fast.unwrapped.tasks)
        rng = np.random.default_rng(5)
        contacts = 0
        for step in range(150):   # mostly ahead (walls and furniture get hit), over the box
            act = (rng.uniform([0.3, -0.7], [1.2, 0.7], (n, 2))
                   * fast.single_action_space.high).astype(np.float32)
            if step % 20 >= 16:
                act[::2] = 0.0       # half the robots brake to a stop: no command noise
            ra, rb = fast.step(act), slow.step(act)
            for key in ra[0]:
                assert ra[0][key].tobytes() == rb[0][key].tobytes(), f"{key} at step {step}"
            for x, y in zip(ra[1:4], rb[1:4]):
                assert x.tobytes() == y.tobytes(), f"reward/flags at step {step}"
            assert _same_infos(ra[4], rb[4]), f"infos at step {step}"
            contacts += int(np.sum(ra[4]["contact"]))
            if step % 25 == 24:
                assert all(np.array_equal(x, y) for x, y in zip(fast.render(), slow.render()))
            if step % 25 == 12:      # (the objects up to date without a render first)
                assert ([_objects(t) for t in fast.unwrapped.tasks]
                        == [_objects(t) for t in slow.unwrapped.tasks]), f"objects at {step}"
        assert contacts >= 2, "no episode ended on a contact"
    finally:
        fast.close()
        slow.close()


@pytest.mark.slow
def test_workers_step_the_same_envs_to_the_bit_and_end_with_the_batch():
    """workers=2: the second chunk of worlds in a worker process (both cores), each env the
    same, to the bit, as in one process, through autoresets (short episodes), rendering
    included; a bad action for a worker's env is refused before any world moves (the batch
    stays in step); close() ends the worker."""
    import os

    from diffbot.runner import procs as dprocs
    before = set(dprocs.descendants(os.getpid()))
    n, seed = 5, 3
    kw = dict(max_episode_steps=6, render_mode="rgb_array",
              overrides=("world.mode=kinematic", *NOISE))
    one = gym.make_vec("diffbot/Avoid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                       **kw)
    two = gym.make_vec("diffbot/Avoid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                       workers=2, **kw)
    worker = two.unwrapped.chunks[1].proc.pid     # one worker: the first chunk is ours
    try:
        assert len(two.unwrapped.chunks) == 2
        assert worker in set(dprocs.descendants(os.getpid())) - before
        a, ia = one.reset(seed=seed)
        b, ib = two.reset(seed=seed)
        assert all(a[k].tobytes() == b[k].tobytes() for k in a)
        assert list(ia["plant"]) == list(ib["plant"])
        rng = np.random.default_rng(2)
        for step in range(14):                  # two autoresets per env
            act = (rng.uniform(-1, 1, (n, 2)) * one.single_action_space.high).astype(np.float32)
            ra, rb = one.step(act), two.step(act)
            assert all(ra[0][k].tobytes() == rb[0][k].tobytes() for k in ra[0]), step
            for x, y in zip(ra[1:4], rb[1:4]):
                assert x.tobytes() == y.tobytes(), step
            assert ra[4]["pose"].tobytes() == rb[4]["pose"].tobytes(), step
        fa, fb = one.render(), two.render()
        assert len(fb) == n and all(np.array_equal(x, y) for x, y in zip(fa, fb))
        bad = np.zeros((n, 2), np.float32)
        bad[-1, 0] = np.nan                       # the last env: in the worker
        with pytest.raises(ValueError, match="env 4"):
            two.step(bad)
        act = np.full((n, 2), 0.1, np.float32)    # refused before any world moved: in step
        ra, rb = one.step(act), two.step(act)
        assert all(ra[0][k].tobytes() == rb[0][k].tobytes() for k in ra[0])
    finally:
        one.close()
        two.close()
    assert not dprocs.alive(worker), "the worker outlived close()"


def test_batched_spaces_a_list_of_seeds_rendering_and_refusals():
    vec = gym.make_vec("diffbot/Avoid-v0", num_envs=2, vectorization_mode="vector_entry_point",
                       render_mode="rgb_array", normalize_actions=True)
    try:
        assert vec.action_space.shape == (2, 2) and vec.single_action_space.high[0] == 1.0
        assert vec.observation_space["scan"].shape == (2, 180)
        obs, _ = vec.reset(seed=[5, 5])
        assert np.array_equal(obs["goal"][0], obs["goal"][1]), "the same seed, other episodes"
        frames = vec.render()
        assert len(frames) == 2 and frames[0].shape == frames[1].shape
        with pytest.raises(ValueError, match="shape"):
            vec.step(np.zeros((3, 2), np.float32))
    finally:
        vec.close()
    with pytest.raises(ValueError, match="workers"):
        gym.make_vec("diffbot/Avoid-v0", num_envs=2, vectorization_mode="vector_entry_point",
                     workers=3)
    with pytest.raises(ValueError, match="async"):
        gym.make_vec("diffbot/Avoid-v0", num_envs=2, vectorization_mode="vector_entry_point",
                     transport="bus")


@pytest.mark.slow
def test_a_worker_ends_with_a_killed_parent():
    """A script holding a workers=2 batch is SIGKILLed: its worker does not outlive it."""
    import os
    import signal
    import subprocess
    import sys

    from diffbot.runner import procs as dprocs

    from ..conftest import ROOT, wait_for
    script = ("import gymnasium as gym, diffbot.envs, sys, time\n"
              "v = gym.make_vec('diffbot/Avoid-v0', num_envs=2, workers=2,\n"
              "                 vectorization_mode='vector_entry_point',\n"
              "                 overrides=('world.mode=kinematic',))\n"
              "v.reset(seed=0)\n"
              "print(v.unwrapped.chunks[1].proc.pid, flush=True)\n"
              "time.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, stdout=subprocess.PIPE,
                              text=True)
    try:
        worker = int(parent.stdout.readline())
        assert dprocs.alive(worker)
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(10)
        wait_for(lambda: not dprocs.alive(worker), 10, what="the worker to end")
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait(10)


def test_batch_truths_are_the_ground_truth_messages_poses():
    """obsmath.truths (all robots at once) gives each robot's (x, y, yaw) as its
    ground_truth message read back does (plant.sim.Simulation.kin_state, the quaternion,
    bus.codec.pose_2d), to the bit, both branches of the quaternion and the signed zeros."""
    import math
    from types import SimpleNamespace

    from bus import codec
    from diffbot.envs.obsmath import truths
    from plant.sim import Simulation
    rng = np.random.default_rng(3)
    edge = [0.0, -0.0, math.pi, -math.pi, 2 * math.pi / 3, -2 * math.pi / 3,
            np.nextafter(2 * math.pi / 3, 0), np.nextafter(2 * math.pi / 3, 4), 1e-300, -1e-300,
            math.pi / 2, 100.0, -57.3]
    yaw = np.concatenate([edge, rng.uniform(-7, 7, 2000)])
    w = yaw.size
    pose = np.stack([rng.uniform(-3, 3, w), rng.uniform(-3, 3, w), yaw], 1)
    kin = SimpleNamespace(pose=pose, radius=np.full(w, 0.12), vel=np.zeros((w, 2)),
                          wheels=np.zeros((w, 2)), speeds=np.zeros((w, 2)))
    got = truths(pose)
    for i in range(w):
        st = Simulation.kin_state(kin, i)
        x, y, z = st.xyz
        msg = codec.odometry(0, x, y, st.yaw, 0.0, 0.0, z=z, quaternion=st.quaternion)
        assert got[i].tobytes() == np.array(codec.pose_2d(msg)).tobytes(), f"yaw {yaw[i]!r}"


def test_an_ended_envs_ignored_action_may_be_anything_while_the_others_step():
    """Next-step autoreset: the step after env k's episode ended resets it and ignores its
    action, not a number included, while the other envs step (a kinematic batch steps the
    ended envs standing and drops their results, so it keeps its plan): the numbers of the
    message path (the oracle) given a finite action there."""
    kw = dict(num_envs=3, vectorization_mode="vector_entry_point", max_episode_steps=2,
              overrides=("world.mode=kinematic", *NOISE))
    fast, slow = (gym.make_vec("diffbot/Avoid-v0", **kw) for _ in range(2))
    slow.unwrapped.chunks[0].arrays = None
    try:
        act = np.tile(fast.single_action_space.high * 0.3, (3, 1)).astype(np.float32)
        for env in (fast, slow):
            env.reset(seed=4)
            env.step(act)
            env.reset(options={"reset_mask": np.array([False, False, True])})
        for step in range(3):   # envs 0, 1 truncated, reset (ignored actions), stepped
            a, b = act.copy(), act.copy()
            if step == 1:           # envs 0, 1 are reset
                a[:2], b[:2] = np.nan, 5.0
            (oa, *fa, ia), (ob, *fb, ib) = fast.step(a), slow.step(b)
            assert all(oa[k].tobytes() == ob[k].tobytes() for k in oa), f"obs at step {step}"
            assert all(x.tobytes() == y.tobytes() for x, y in zip(fa, fb)), f"step {step}"
            assert _same_infos(ia, ib), f"infos at step {step}"
            assert (fa[2].tolist() == [True, True, False]) == (step == 0)
    finally:
        fast.close()
        slow.close()


def test_batch_observations_are_the_observers():
    """obsmath.observation (every robot at once) gives each robot's odometry and goal parts
    as its AvoidObserver.observation does, to the bit: yaws wrapped from far out and at the
    wrap's edges, values clipped at both bounds."""
    import math

    from controllers.learned import AvoidObserver
    from diffbot.envs.obsmath import observation
    rng = np.random.default_rng(4)
    edge = [0.0, -0.0, math.pi, -math.pi, 3 * math.pi, -3 * math.pi, 2 * math.pi, 1e-300,
            np.nextafter(math.pi, 0), np.nextafter(-math.pi, 0), 1e6, -57.3]
    yaw = np.concatenate([edge, rng.uniform(-20, 20, 500)])
    w = yaw.size
    pose = np.stack([rng.uniform(-150, 150, w), rng.uniform(-150, 150, w), yaw], 1)
    vel = np.stack([rng.uniform(-15, 15, w), rng.uniform(-30, 30, w)], 1)
    goal = rng.uniform(-200, 200, (w, 2))
    scans = rng.uniform(0, 9, (w, 4)).astype(np.float32)
    got = observation(pose, vel, goal, scans)
    ob = AvoidObserver(0.05, 0.3, 4, 9.0)
    for i in range(w):
        od = ob.odom
        (od.x, od.y, od.theta), (od.v, od.w) = pose[i].tolist(), vel[i].tolist()
        ob.goal, ob.scan = tuple(goal[i].tolist()), scans[i]
        one = ob.observation()
        assert all(got[k][i].tobytes() == one[k].tobytes() for k in one), f"robot {i}"


def test_the_batchs_state_between_steps_is_the_cores_data():
    """The batch's state is its core's: a plant.core Model of its worlds and their Data,
    (W, R, ...) arrays holding every env's dead reckoning, limiter, wheel targets, noise
    keys and clock, as the message path leaves them in its objects."""
    n = 3
    kw = dict(num_envs=n, vectorization_mode="vector_entry_point", max_episode_steps=50,
              overrides=("world.mode=kinematic", *NOISE))
    fast, slow = gym.make_vec("diffbot/Avoid-v0", **kw), gym.make_vec("diffbot/Avoid-v0", **kw)
    slow.unwrapped.chunks[0].arrays = None
    try:
        fast.reset(seed=3)
        slow.reset(seed=3)
        rng = np.random.default_rng(1)
        for _ in range(7):
            act = (rng.uniform([0.2, -0.5], [1.0, 0.5], (n, 2))
                   * fast.single_action_space.high).astype(np.float32)
            fast.step(act)
            slow.step(act)
        arrays = fast.unwrapped.chunks[0].arrays
        model, data = arrays.model, arrays.data
        assert model.worlds == n and model.robots == ("robot1",)
        assert data.odometry["pose"].shape == (n, 1, 3) and data.drive["v"].shape == (n, 1)
        for w, task in enumerate(slow.unwrapped.tasks):
            name = task.robots[0]
            sim, od = task.transport.tick.sim, task.observers[name].odom
            i, sensors = sim.drive.index[name], task.transport.tick.sensors[name]
            assert data.odometry["pose"][w, 0].tolist() == [od.x, od.y, od.theta]
            assert data.odometry["vel"][w, 0].tolist() == [od.v, od.w]
            assert data.odometry["last"][w, 0].tolist() == list(od._last)
            assert data.odometry["last_t"][w, 0] == od._last_t
            assert sim.steps > 0 and data.steps[w] == sim.steps and data.t_ns[w] == task.t_ns
            assert data.tick[w] == sim.steps // sim.spec.substeps
            assert (float(data.drive["v"][w, 0]), float(data.drive["w"][w, 0]),
                    tuple(data.drive["wheels"][w, 0].tolist())) == sim.drive.limiter(i)
            assert data.drive["targets"][w, 0].tolist() == sim.drive.targets[i].tolist()
            assert data.drive["keys"][w, 0] == sim.motion_noise[name].key
            assert data.keys["encoders"][w, 0] == sensors.enc_noise.key
            assert data.keys["lidar"][w, 0] == sensors.lidar_noise.key
    finally:
        fast.close()
        slow.close()
