"""The environments follow the conventions RL libraries expect: a normalised action option,
finite observation bounds, out-of-range actions clipped (non-finite ones refused), the
same ``info`` keys on reset and step, starts drawn from the seed, PettingZoo's ``state()``."""
from __future__ import annotations

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("pettingzoo")
import diffbot.envs  # noqa: E402,F401


def _same(a: dict, b: dict) -> bool:
    return all(np.asarray(a[k]).tobytes() == np.asarray(b[k]).tobytes() for k in a)


def test_normalized_actions_are_the_unit_box_scaled_to_the_drive_limits():
    raw = gym.make("diffbot/Avoid-v0")
    unit = gym.make("diffbot/Avoid-v0", normalize_actions=True)
    try:
        assert np.array_equal(unit.action_space.low, [-1, -1])
        assert np.array_equal(unit.action_space.high, [1, 1])
        v, w = raw.action_space.high
        raw.reset(seed=4)
        unit.reset(seed=4)
        for a in ([0.5, 0.25], [-0.2, 1.0], [1.0, -0.5]):
            ra = raw.step(np.array([a[0] * v, a[1] * w], np.float32))
            ua = unit.step(np.array(a, np.float32))
            assert _same(ra[0], ua[0]) and ra[1] == ua[1], f"differ at action {a}"
    finally:
        raw.close()
        unit.close()


@pytest.mark.parametrize("normalize", [False, True])
def test_out_of_range_actions_are_clipped_and_non_finite_ones_refused(normalize):
    envs = [gym.make("diffbot/Avoid-v0", normalize_actions=normalize) for _ in range(2)]
    try:
        for e in envs:
            e.reset(seed=1)
        hi = envs[0].action_space.high
        for big, edge in (([9.0, -9.0], [hi[0], -hi[1]]), ([-3.0, 0.0], [-hi[0], 0.0])):
            a = envs[0].step(np.array(big, np.float32))
            b = envs[1].step(np.array(edge, np.float32))
            assert _same(a[0], b[0]), f"{big} is not clipped to {edge}"
        for bad in ([np.nan, 0.0], [0.0, np.inf], [0.1, 0.2, 0.3]):
            with pytest.raises(ValueError, match="2 finite numbers"):
                envs[0].step(np.array(bad, np.float32))
        envs[0].step(np.zeros(2, np.float32))      # still usable
    finally:
        for e in envs:
            e.close()


def _boxes(space):
    if isinstance(space, gym.spaces.Dict):
        for s in space.values():
            yield from _boxes(s)
    else:
        yield space


@pytest.mark.parametrize("env_id,kw", [("diffbot/Avoid-v0", {}),
                                       ("diffbot/Follow-v0", {"detection": True})])
def test_observation_bounds_are_finite_and_info_keys_the_same_on_reset_and_step(env_id, kw):
    env = gym.make(env_id, **kw)
    try:
        for box in _boxes(env.observation_space):
            assert np.all(np.isfinite(box.low)) and np.all(np.isfinite(box.high)), box
        obs, info = env.reset(seed=0)
        assert env.observation_space.contains(obs)
        obs, _, _, _, info2 = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
        assert set(info) == set(info2)
        assert "plant" in info and "contact" in info
    finally:
        env.close()


def test_follow_start_is_drawn_from_the_seed_and_the_ball_is_in_view():
    env = gym.make("diffbot/Follow-v0", detection=True)
    fixed = gym.make("diffbot/Follow-v0", fixed_start=True)
    try:
        starts = {}
        for seed in (3, 4, 3):
            obs, info = env.reset(seed=seed)
            assert obs["ball"][0] == 1.0, f"seed {seed}: the leader's ball is not in view"
            assert not info["contact"]
            p = (tuple(info["pose"]), tuple(info["leader_pose"]))
            assert starts.setdefault(seed, p) == p, "the same seed gave another start"
        assert starts[3] != starts[4], "seeds 3 and 4 gave the same start"
        _, info = fixed.reset(seed=5)
        spec = fixed.unwrapped.spec_
        assert tuple(info["pose"][:2]) == pytest.approx(spec.robot("follower").pose[:2])
    finally:
        env.close()
        fixed.close()


def test_swarm_state_is_every_robots_true_pose_and_goal():
    from diffbot.envs import swarm_v0
    env = swarm_v0.parallel_env(n_robots=3)
    try:
        with pytest.raises(RuntimeError, match="reset"):
            env.state()
        obs, infos = env.reset(seed=2)
        s = env.state()
        assert env.state_space.contains(s) and s.shape == (15,)
        for i, a in enumerate(env.possible_agents):
            want = np.concatenate([infos[a]["pose"], infos[a]["goal"]]).astype(np.float32)
            assert np.array_equal(s[5 * i:5 * i + 5], want)
        _, _, _, _, infos2 = env.step({a: env.action_space(a).sample() for a in env.agents})
        assert all(set(infos[a]) == set(infos2[a]) for a in infos2)
    finally:
        env.close()


@pytest.mark.parametrize("env_id", ["diffbot/Avoid-v0", "diffbot/Follow-v0"])
def test_check_env_passes_without_a_warning_with_normalized_actions_and_rendering(env_id):
    import warnings
    from gymnasium.utils.env_checker import check_env
    env = gym.make(env_id, normalize_actions=True, render_mode="rgb_array")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            check_env(env.unwrapped)
    finally:
        env.close()


def test_a_diverged_world_raises_and_a_reset_starts_a_sound_episode():
    """In-process, a DART world that is no longer finite ends the step with a
    FloatingPointError that says what to do (the single env and the batch alike: both step
    through diffbot/envs/kinbatch.py); reset() then gives a fresh world that steps as a new
    env with that seed does."""
    env = gym.make("diffbot/Avoid-v0")
    fresh = gym.make("diffbot/Avoid-v0")
    envs = gym.make_vec("diffbot/Avoid-v0", num_envs=2, vectorization_mode="vector_entry_point")
    go = np.array([0.2, 0.0], np.float32)
    try:
        env.reset(seed=1)
        envs.reset(seed=1)
        for _ in range(2):
            env.step(go)
            envs.step(np.stack([go, go]))

        def break_world(task):
            sk = task.transport.tick.sim.robots[task.robots[0]].skeleton
            v = sk.getVelocities()
            v[:] = np.nan
            sk.setVelocities(v)
        break_world(env.unwrapped.task)
        with pytest.raises(FloatingPointError, match=r"env 0 diverged .*reset\(\)"):
            env.step(go)
        break_world(envs.unwrapped.tasks[1])
        with pytest.raises(FloatingPointError, match=r"env 1 diverged"):
            envs.step(np.stack([go, go]))
        a, b = env.reset(seed=5), fresh.reset(seed=5)
        assert _same(a[0], b[0])
        for _ in range(3):
            a, b = env.step(go), fresh.step(go)
            assert _same(a[0], b[0]) and a[1] == b[1]
    finally:
        env.close()
        fresh.close()
        envs.close()


def test_the_scan_bound_is_the_longest_reading_the_room_allows():
    from diffbot.envs.avoid import scan_bound
    from plant.world import load_world
    env = gym.make("diffbot/Avoid-v0", overrides=("world.mode=kinematic",))
    try:
        assert float(env.observation_space["scan"].high.max()) == 9.0    # 6 m x 5 m, walled
        obs, _ = env.reset(seed=1)
        assert obs["scan"].max() <= 9.0
    finally:
        env.close()
    # without walls a ray may leave the room: the lidar's own range
    assert scan_bound(load_world("living_room", ["walls.height_m=0"]), "robot1") == 80.0
