"""diffbot.envs.swarm_sb3.SwarmVecEnv: the swarm's batched worlds as an SB3 VecEnv of W x N
agents, agent k robot k % N of world k // N, each what the vector env (same-step
autoreset) gives that robot, with SB3's conventions per agent (done at the robot's end,
terminal_observation, TimeLimit.truncated, "episode" statistics, zero rows until its world
resets, reset_infos, seeds through seed()); PPO takes it."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pettingzoo")
pytest.importorskip("torch", reason="torch is not installed (make setup installs the sb3 extra)")
pytest.importorskip("stable_baselines3",
                    reason="the sb3 extra is not installed (make setup installs it)")
from diffbot.envs.swarm_sb3 import SwarmVecEnv  # noqa: E402
from diffbot.envs.swarm_vector import SwarmVectorEnv  # noqa: E402
from stable_baselines3.common.monitor import Monitor  # noqa: E402

#: no wall-clock promise: runs beside the serial tests, at a low CPU priority (conftest.py)
pytestmark = pytest.mark.background

#: robots end alone (goals within 2 m: reached at the first step) and with the 4-step limit
KW = dict(n_robots=3, mode="kinematic", layout_seed=5, max_steps=4, goal_radius_m=2.0)
W = 2


def _row(infos: dict, i: int, j: int) -> dict:
    return {k: v[i, j] for k, v in infos.items()
            if k not in ("active", "plant") and not k.startswith(("final", "_final"))}


def test_each_agent_is_its_robot_in_the_vector_env_with_sb3s_conventions():
    ours = SwarmVecEnv(W, **KW)
    ref = SwarmVectorEnv(W, "SameStep", **KW)
    n = ref.n_robots
    try:
        assert ours.num_envs == W * n
        assert ours.seed(11) == [11] * n + [12] * n
        obs = ours.reset()
        r_obs, r_infos = ref.reset(seed=11)
        assert all(obs[k].tobytes() == r_obs[k].reshape(W * n, -1).tobytes() for k in obs)
        assert [ours.reset_infos[k]["plant"].seed for k in range(W * n)] == [11] * n + [12] * n
        rng = np.random.default_rng(2)
        ret, length = np.zeros((W, n)), np.zeros((W, n), int)
        counts = {"alone": 0, "world": 0}
        for step in range(10):
            act = (rng.uniform(-1, 1, (W * n, 2)) * ours.action_space.high).astype(np.float32)
            o, rew, dones, infos = ours.step(act)
            r_obs, r_rew, term, trunc, r_inf = ref.step(act.reshape(W, n, 2))
            done = term | trunc
            assert rew.dtype == np.float32
            assert rew.tobytes() == r_rew.reshape(-1).astype(np.float32).tobytes()
            assert list(dones) == list(done.reshape(-1))
            ended = r_inf["_final_obs"]
            step_info = np.where(ended[:, None], r_inf["final_info"]["active"], r_inf["active"])
            ret += r_rew
            length += step_info
            for k in range(W * n):
                i, j = divmod(k, n)
                where = f"step {step}, agent {k}"
                info = infos[k]
                zero = done[i, j] and not ended[i]   # the robot ended, its world goes on
                for key in o:
                    want = np.zeros_like(r_obs[key][i, j]) if zero else r_obs[key][i, j]
                    assert o[key][k].tobytes() == want.tobytes(), (where, key)
                if not step_info[i, j]:
                    assert info == {"TimeLimit.truncated": False}, where
                    continue
                src = r_inf["final_info"] if ended[i] else r_inf
                for key, v in _row(src, i, j).items():
                    assert np.asarray(info[key]).tobytes() == np.asarray(v).tobytes(), where
                if not done[i, j]:
                    assert "terminal_observation" not in info, where
                    continue
                counts["world" if ended[i] else "alone"] += 1
                last = r_inf["final_obs"][i] if ended[i] else {
                    key: r_obs[key][i] for key in r_obs}
                assert all(info["terminal_observation"][key].tobytes() == last[key][j].tobytes()
                           for key in last), where
                assert info["TimeLimit.truncated"] == bool(trunc[i, j] and not term[i, j])
                assert (info["episode"]["r"], info["episode"]["l"]) == \
                    (round(float(ret[i, j]), 6), int(length[i, j])), where
                ret[i, j], length[i, j] = 0.0, 0
            for i in np.flatnonzero(ended):
                for j in range(n):
                    assert ours.reset_infos[i * n + j]["pose"].tobytes() == \
                        r_inf["pose"][i, j].tobytes()
        assert counts["alone"] >= 1 and counts["world"] >= W, counts
        assert ours.env_is_wrapped(Monitor) == [True] * (W * n)
        with pytest.raises(ValueError, match="SAME_STEP"):
            SwarmVecEnv(1, autoreset_mode="NextStep", **KW)
    finally:
        ours.close()
        ref.close()


@pytest.mark.timeout(300)
def test_ppo_learns_through_the_swarm_adapter():
    from stable_baselines3 import PPO
    venv = SwarmVecEnv(W, **{**KW, "max_steps": 8, "goal_radius_m": 0.3},
                       normalize_actions=True)
    try:
        model = PPO("MultiInputPolicy", venv, n_steps=16, batch_size=48, n_epochs=1, seed=0,
                    device="cpu")
        model.learn(16 * W * venv.n_robots)              # one rollout and its update
        assert model.num_timesteps == 16 * W * venv.n_robots
        # every robot's episode ended within 8 steps: the logger read each one's "episode"
        assert len(model.ep_info_buffer) >= W * venv.n_robots
        assert all(1 <= e["l"] <= 8 for e in model.ep_info_buffer)
    finally:
        venv.close()
