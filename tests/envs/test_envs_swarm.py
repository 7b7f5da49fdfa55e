"""The swarm env's episodes can be played again: PettingZoo's parallel_seed_test passes
(two envs made alike give the same infos), ``info["plant"]`` carries the reset seed (also
of a reset without one) and the generated world's text, and a plant built from it is the
env's world."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pettingzoo")
from diffbot.envs import swarm_v0  # noqa: E402
from plant.swarm_world import swarm_world_text  # noqa: E402
from plant.world import load_world  # noqa: E402

KW = dict(n_robots=3, mode="kinematic", robot="avoid", layout_seed=5)


def test_parallel_seed_test_passes():
    from pettingzoo.test import parallel_seed_test
    parallel_seed_test(lambda: swarm_v0.parallel_env(**KW), num_cycles=20)


def test_every_episode_carries_its_seed_and_world_and_replays(tmp_path):
    env = swarm_v0.parallel_env(**KW)
    again = swarm_v0.parallel_env(**KW)
    try:
        env.reset(seed=8)
        obs, infos = env.reset()                        # no seed: one is drawn
        ep = infos["r0"]["plant"]
        assert ep.seed is not None and ep.world == "swarm"
        assert ep.world_toml == swarm_world_text(3, 5, "kinematic", "avoid")
        assert all(info["plant"] is ep for info in infos.values())
        replay, infos2 = again.reset(seed=ep.seed)
        assert infos2["r0"]["plant"] == ep
        for a in obs:
            assert all(obs[a][k].tobytes() == replay[a][k].tobytes() for k in obs[a])
        # the plant's world from the episode: the env's own, every robot at its start
        path = ep.write_world(str(tmp_path))
        args = ep.plant_args(path)
        sets = [v for k, v in zip(args, args[1:]) if k == "--set"]
        spec = load_world(args[args.index("--world") + 1], sets)
        assert spec.floor_size_m == env.task.spec.floor_size_m
        for r in spec.robots:
            assert r.pose == ep.poses[r.name]
        with pytest.raises(ValueError, match="write_world"):
            ep.plant_args()
        # an episode's seed stays with it: the next unseeded reset is another
        _, infos3 = env.reset()
        assert infos3["r0"]["plant"].seed != ep.seed
    finally:
        env.close()
        again.close()
    assert np.isfinite(ep.plant_seed)


def test_max_steps_truncates_every_robot_still_out_at_the_last_step():
    """The swarm env has no TimeLimit wrapper: its task's own step count ends the episode,
    truncated (not terminated) for each robot still out at step ``max_steps``, counted from
    each reset."""
    env = swarm_v0.parallel_env(**KW, max_steps=3)
    try:
        for seed in (4, 5):
            env.reset(seed=seed)
            idle = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.agents}
            for step in range(1, 4):
                _, _, term, trunc, _ = env.step({a: idle[a] for a in env.agents})
                assert not any(term.values()), (seed, step, term)
                assert list(trunc.values()) == [step == 3] * 3, (seed, step, trunc)
            assert env.agents == []
    finally:
        env.close()
