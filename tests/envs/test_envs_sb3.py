"""diffbot.envs.sb3.AvoidVecEnv follows Stable-Baselines3's VecEnv conventions: it gives
what SB3's DummyVecEnv over Monitor-wrapped single envs gives (observations, float32
rewards, dones, terminal_observation, TimeLimit.truncated, "episode" statistics, reset
infos, seeds through seed()), and PPO trains through it. Skipped, with the reason, where the
sb3 extra is not installed."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("torch", reason="torch is not installed (make setup installs the sb3 extra)")
pytest.importorskip("stable_baselines3",
                    reason="the sb3 extra is not installed (make setup installs it)")
import diffbot.envs  # noqa: E402,F401
from diffbot.envs.sb3 import AvoidVecEnv  # noqa: E402
from stable_baselines3.common.monitor import Monitor  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv  # noqa: E402

#: no wall-clock promise: runs beside the serial tests, at a low CPU priority (conftest.py)
pytestmark = pytest.mark.background

KW = dict(max_episode_steps=6, normalize_actions=True,
          overrides=("world.mode=kinematic", "robots.robot1.lidar.noise={std = 0.01}"))


def _same_info(a: dict, b: dict, where: str) -> None:
    assert set(a) == set(b), (where, sorted(a), sorted(b))
    for k in a:
        x, y = a[k], b[k]
        if k == "episode":                       # (its "t" is wall time)
            assert (x["r"], x["l"]) == (y["r"], y["l"]), where
            assert type(x["r"]) is type(y["r"]) and x["t"] >= 0
        elif k == "terminal_observation":
            assert all(x[o].tobytes() == y[o].tobytes() for o in y), where
        elif isinstance(y, np.ndarray):
            assert np.asarray(x).tobytes() == y.tobytes(), (where, k)
        else:
            assert x == y and type(x) is type(y), (where, k, x, y)


def test_the_adapter_is_dummy_vec_env_over_monitored_single_envs():
    n = 3
    ours = AvoidVecEnv(n, **KW)
    theirs = DummyVecEnv([lambda: Monitor(gym.make("diffbot/Avoid-v0", **KW))] * n)
    try:
        assert ours.seed(40) == theirs.seed(40) == [40, 41, 42]
        a, b = ours.reset(), theirs.reset()
        assert all(a[k].tobytes() == b[k].tobytes() for k in b)
        for i in range(n):
            _same_info(ours.reset_infos[i], theirs.reset_infos[i], f"reset info {i}")
        rng, episodes = np.random.default_rng(0), 0
        for step in range(14):
            act = rng.uniform(-1, 1, (n, 2)).astype(np.float32)
            (o1, r1, d1, i1), (o2, r2, d2, i2) = ours.step(act), theirs.step(act)
            where = f"step {step}"
            assert all(o1[k].tobytes() == o2[k].tobytes() for k in o2), where
            assert r1.dtype == r2.dtype == np.float32 and r1.tobytes() == r2.tobytes(), where
            assert d1.dtype == d2.dtype and list(d1) == list(d2), where
            for i in range(n):
                _same_info(i1[i], i2[i], f"{where}, env {i}")
                if d1[i]:
                    episodes += 1
                    _same_info(ours.reset_infos[i], theirs.reset_infos[i], where)
        assert episodes >= n, "no episode ended"
        assert ours.env_is_wrapped(Monitor) == [True] * n
        assert ours.get_attr("render_mode") == [None] * n
        with pytest.raises(ValueError, match="SAME_STEP"):
            AvoidVecEnv(1, autoreset_mode="next_step")
    finally:
        ours.close()
        theirs.close()


@pytest.mark.timeout(300)
def test_ppo_trains_through_the_adapter_and_evaluate_policy_reads_its_episodes():
    from stable_baselines3 import PPO
    from stable_baselines3.common.evaluation import evaluate_policy
    venv = AvoidVecEnv(8, **{**KW, "max_episode_steps": 40})
    try:
        venv.seed(0)
        model = PPO("MultiInputPolicy", venv, n_steps=64, batch_size=256, n_epochs=1, seed=0,
                    device="cpu")
        model.learn(2048)
        assert model.num_timesteps == 2048
        # the logger's episode statistics come from the infos' "episode" (Monitor's)
        assert len(model.ep_info_buffer) >= 8 * (2048 // 8) // 40 - 8
        assert all(e["l"] <= 40 for e in model.ep_info_buffer)
        assert len(model.ep_success_buffer) == len(model.ep_info_buffer)
        with warnings.catch_warnings():
            warnings.simplefilter("error")     # (no "not wrapped with a Monitor" warning)
            rewards, lengths = evaluate_policy(model, venv, n_eval_episodes=8,
                                               return_episode_rewards=True)
        assert len(rewards) == 8 and all(1 <= n <= 40 for n in lengths)
    finally:
        venv.close()
