"""swarm_v0.vector_env: world i of the batch is swarm_v0.parallel_env after reset(seed +
i), step for step, to the bit, through robots ending alone (zero rows after) and the
worlds' autoresets (next step and same step); bad actions are refused before any world
moves; DISABLED refuses a step of an ended world until a masked reset."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pettingzoo")
from diffbot.envs import swarm_v0  # noqa: E402

#: goals lie 1-3 m from the start: within 2 m a robot succeeds at its first step while
#: the others go on to the 4-step limit, so robots end alone and worlds end often
KW = dict(n_robots=3, mode="kinematic", layout_seed=5, max_steps=4, goal_radius_m=2.0)
SEED, W = 11, 2


def _same(row, value) -> bool:
    a, b = np.asarray(row), np.asarray(value)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _check_world(out: tuple, i: int, agents: list[str], single: tuple, where: str) -> None:
    """World ``i``'s rows of the batch's (obs, rew, term, trunc, infos) against the single
    env's dicts (a reset: obs and infos only): the agents it gives, and zeros elsewhere."""
    obs, rew, term, trunc, infos = out
    s_obs, s_rew, s_term, s_trunc, s_infos = single
    for j, a in enumerate(agents):
        here = a in s_obs
        assert infos["active"][i, j] == here, f"{where}: active of {a}"
        for k in obs:
            want = s_obs[a][k] if here else np.zeros_like(obs[k][i, j])
            assert _same(obs[k][i, j], want), f"{where}: obs {k} of {a}"
        if s_rew is None or not here:
            assert (rew[i, j], term[i, j], trunc[i, j]) == (0.0, False, False), where
        else:
            assert (rew[i, j], term[i, j], trunc[i, j]) == (s_rew[a], s_term[a], s_trunc[a]), \
                f"{where}: reward/flags of {a}"
        for key, col in infos.items():
            if key in ("active", "plant") or key.startswith(("final", "_final")):
                continue
            if here:
                assert _same(col[i, j], s_infos[a][key]), f"{where}: info {key} of {a}"
            else:
                assert not np.any(col[i, j]), f"{where}: info {key} of ended {a}"
    ep = next(iter(s_infos.values()))["plant"]
    assert infos["plant"][i] == ep, f"{where}: episode"


@pytest.mark.parametrize("mode", ["kinematic", "dynamic"])
def test_each_world_is_the_parallel_env_with_its_seed_through_next_step_autoresets(mode):
    steps = 12 if mode == "kinematic" else 6
    kw = {**KW, "mode": mode}
    vec = swarm_v0.vector_env(num_worlds=W, **kw)
    singles = [swarm_v0.parallel_env(**kw) for _ in range(W)]
    try:
        agents = vec.possible_agents
        obs, infos = vec.reset(seed=SEED)
        flat = np.zeros((W, len(agents)))
        for i, env in enumerate(singles):
            o, info = env.reset(seed=SEED + i)
            _check_world((obs, flat, flat == 1, flat == 1, infos), i, agents,
                         (o, None, None, None, info), f"world {i} reset")
        assert vec.state().tobytes() == np.stack([e.state() for e in singles]).tobytes()
        rng = np.random.default_rng(3)
        alone = resets = 0
        for step in range(steps):
            act = (rng.uniform(-1, 1, (W, len(agents), 2))
                   * vec.single_action_space.high).astype(np.float32)
            out = vec.step(act)
            for i, env in enumerate(singles):
                where = f"world {i} at step {step}"
                if not env.agents:               # next-step autoreset: actions ignored
                    o, info = env.reset()
                    single = (o, None, None, None, info)
                    resets += 1
                else:
                    single = env.step({a: act[i, j] for j, a in enumerate(agents)
                                       if a in env.agents})
                    alone += sum(1 for a in single[2] if single[2][a] and env.agents)
                _check_world(out, i, agents, single, where)
        assert alone >= 1, "no robot ended while its world went on"
        assert resets >= W, "no autoreset was crossed"
    finally:
        vec.close()
        for env in singles:
            env.close()


def test_same_step_autoreset_gives_the_last_observation_and_the_next_episode_at_once():
    vec = swarm_v0.vector_env(num_worlds=W, autoreset_mode="SameStep", **KW)
    singles = [swarm_v0.parallel_env(**KW) for _ in range(W)]
    try:
        agents = vec.possible_agents
        vec.reset(seed=SEED)
        for i, env in enumerate(singles):
            env.reset(seed=SEED + i)
        act = np.zeros((W, len(agents), 2), np.float32)
        ended = 0
        for step in range(9):
            obs, rew, term, trunc, infos = vec.step(act)
            for i, env in enumerate(singles):
                where = f"world {i} at step {step}"
                last = env.step({a: act[i, j] for j, a in enumerate(agents) if a in env.agents})
                if env.agents:
                    assert not infos["_final_obs"][i]
                    _check_world((obs, rew, term, trunc, infos), i, agents, last, where)
                    continue
                ended += 1
                assert infos["_final_obs"][i] and infos["_final_info"][i], where
                final = (infos["final_obs"][i], rew, term, trunc,
                         {k: v for k, v in infos["final_info"].items()})
                # the final observation: (N, ...) arrays; as a (1, N, ...) batch row
                fin = ({k: v[None] for k, v in final[0].items()},
                       rew[i:i + 1], term[i:i + 1], trunc[i:i + 1],
                       {k: v[i:i + 1] for k, v in final[4].items()})
                _check_world(fin, 0, agents, last, where + " (final)")
                first, info = env.reset()
                assert all(infos["active"][i]), where
                for j, a in enumerate(agents):
                    assert all(_same(obs[k][i, j], first[a][k]) for k in obs), where
                    assert _same(infos["pose"][i, j], info[a]["pose"]), where
                assert infos["plant"][i] == info[agents[0]]["plant"], where
        assert ended >= W, "no world ended"
    finally:
        vec.close()
        for env in singles:
            env.close()


def test_bad_actions_are_refused_before_any_world_moves_and_disabled_waits_for_a_reset():
    vec = swarm_v0.vector_env(num_worlds=W, autoreset_mode="disabled", render_mode="rgb_array",
                              **KW)
    try:
        n = vec.n_robots
        with pytest.raises(RuntimeError, match="reset"):
            vec.step(np.zeros((W, n, 2)))
        vec.reset(seed=14)      # (its first step ends robots of both worlds, not all)
        before = vec.state().copy()
        with pytest.raises(ValueError, match=r"\(2, 3, 2\)"):
            vec.step(np.zeros((W, n)))
        bad = np.zeros((W, n, 2))
        bad[1, 2, 0] = np.nan
        with pytest.raises(ValueError, match="world 1, agent r2"):
            vec.step(bad)
        assert vec.state().tobytes() == before.tobytes(), "a world moved"
        assert all(e.task.steps == 0 for e in vec.envs)
        # a robot out of its episode: its row is not read
        _, _, term, _, infos = vec.step(np.zeros((W, n, 2)))
        out = ~infos["active"] | term
        assert out.any() and not out.all()
        junk = np.where(out[..., None], np.nan, np.zeros((W, n, 2)))
        vec.step(junk)
        while not all(not e.agents for e in vec.envs):
            vec.step(np.zeros((W, n, 2)))
        with pytest.raises(RuntimeError, match="world 0, 1 .*DISABLED"):
            vec.step(np.zeros((W, n, 2)))
        kept = vec._obs["scan"][0].copy()
        obs, infos = vec.reset(seed=[None, 40], options={"reset_mask": np.array([False, True])})
        assert obs["scan"][0].tobytes() == kept.tobytes()
        assert not infos["active"][0].any() and infos["active"][1].all()
        assert infos["plant"][1].seed == 40 and infos["plant"][0] is None
        with pytest.raises(RuntimeError, match="world 0 "):
            vec.step(np.zeros((W, n, 2)))
        frames = vec.render()                     # a frame per world, each its own
        assert len(frames) == W and frames[0].tobytes() != frames[1].tobytes()
        assert all(f.tobytes() == e.render().tobytes() for f, e in zip(frames, vec.envs))
    finally:
        vec.close()
    with pytest.raises(ValueError, match="inproc"):
        swarm_v0.vector_env(num_worlds=2, transport="bus")
