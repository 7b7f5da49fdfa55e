"""The batched Avoid env's autoreset modes and masked resets are Gymnasium's: with
``autoreset_mode`` SAME_STEP or DISABLED and ``reset(options={"reset_mask": m})`` it gives
what ``gymnasium.vector.SyncVectorEnv`` over single envs gives (observations, rewards,
flags and infos, ``final_obs``/``final_info`` included, to the bit), chunks in a worker
process too; what it cannot do it refuses with the reason."""
from __future__ import annotations

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
import diffbot.envs  # noqa: E402,F401
from gymnasium.vector import AutoresetMode, SyncVectorEnv  # noqa: E402

KW = dict(max_episode_steps=6, overrides=("world.mode=kinematic",
                                         "robots.robot1.lidar.noise={std = 0.01}"))


def _same(a, b, where: str = "") -> None:
    """Batched results alike: dicts with the same keys, arrays of one dtype and shape with
    the same bits (objects equal, dicts among them compared alike)."""
    if isinstance(a, tuple):
        assert isinstance(b, tuple) and len(a) == len(b), where
        for j, (u, v) in enumerate(zip(a, b)):
            _same(u, v, f"{where}[{j}]")
    elif isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (where, sorted(a), sorted(b))
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        assert b.dtype == object and a.shape == b.shape, where
        for j, (u, v) in enumerate(zip(a, b)):
            _same(u, v, f"{where}[{j}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and (a.dtype, a.shape) == (b.dtype, b.shape), where
        assert a.tobytes() == b.tobytes(), where
    else:
        assert a == b, where


def _pair(mode: AutoresetMode, n: int = 3, workers: int = 1):
    batch = gym.make_vec("diffbot/Avoid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                         autoreset_mode=mode, workers=workers, **KW)
    sync = SyncVectorEnv([lambda: gym.make("diffbot/Avoid-v0", **KW)] * n, autoreset_mode=mode)
    return batch, sync


def _actions(rng, space, n):
    return (rng.uniform(-1, 1, (n, 2)) * space.high).astype(np.float32)


@pytest.mark.slow
def test_same_step_autoreset_is_sync_vector_envs_with_final_obs_and_final_info():
    batch, sync = _pair(AutoresetMode.SAME_STEP, workers=2)   # env 2 in a worker process
    try:
        assert batch.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
        _same(batch.reset(seed=11), sync.reset(seed=11), "reset")
        rng, ended = np.random.default_rng(0), 0
        for step in range(14):
            a = _actions(rng, batch.single_action_space, 3)
            got, want = batch.step(a), sync.step(a)
            _same(got, want, f"step {step}")
            ended += int((got[2] | got[3]).sum())
            if "final_obs" in got[4]:
                # the row is the new episode's first observation; its seed replays it
                for i in np.flatnonzero(got[4]["_final_obs"]):
                    ep = got[4]["plant"][i]
                    assert ep.seed is not None and ep is not got[4]["final_info"]["plant"][i]
                    one = gym.make("diffbot/Avoid-v0", **KW)
                    obs, _ = one.reset(seed=ep.seed)
                    one.close()
                    assert all(obs[k].tobytes() == got[0][k][i].tobytes() for k in obs)
        assert ended >= 3, "no autoreset was crossed"
    finally:
        batch.close()
        sync.close()


def test_disabled_mode_refuses_a_step_of_an_ended_episode_and_reset_mask_resets_only_those():
    batch, sync = _pair(AutoresetMode.DISABLED)
    try:
        _same(batch.reset(seed=4), sync.reset(seed=4), "reset")
        rng, masked = np.random.default_rng(1), 0
        for step in range(20):
            a = _actions(rng, batch.single_action_space, 3)
            got, want = batch.step(a), sync.step(a)
            _same(got, want, f"step {step}")
            done = got[2] | got[3]
            if done.any():
                with pytest.raises(RuntimeError, match="reset_mask"):
                    batch.step(a)
                opts = {"reset_mask": done}
                _same(batch.reset(seed=100 + step, options=dict(opts)),
                      sync.reset(seed=100 + step, options=dict(opts)), f"masked reset {step}")
                masked += 1
        assert masked >= 2, "no masked reset was made"
    finally:
        batch.close()
        sync.close()


def test_reset_mask_in_next_step_mode_keeps_the_other_episodes_going():
    batch, sync = _pair(AutoresetMode.NEXT_STEP)
    try:
        _same(batch.reset(seed=2), sync.reset(seed=2), "reset")
        rng = np.random.default_rng(2)
        a = _actions(rng, batch.single_action_space, 3)
        _same(batch.step(a), sync.step(a), "step")
        mask = np.array([False, True, False])
        obs, infos = batch.reset(options={"reset_mask": mask})
        want_obs, want_infos = sync.reset(options={"reset_mask": mask})
        _same((obs, infos), (want_obs, want_infos), "masked reset")
        assert list(infos["_pose"]) == [False, True, False]
        for step in range(8):
            a = _actions(rng, batch.single_action_space, 3)
            _same(batch.step(a), sync.step(a), f"step {step} after")
    finally:
        batch.close()
        sync.close()


def test_bad_modes_and_masks_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="autoreset_mode must be one of"):
        gym.make_vec("diffbot/Avoid-v0", num_envs=2, vectorization_mode="vector_entry_point",
                     autoreset_mode="sometimes")
    vec = gym.make_vec("diffbot/Avoid-v0", num_envs=2, vectorization_mode="vector_entry_point",
                       autoreset_mode="same_step")
    try:
        assert vec.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
        with pytest.raises(RuntimeError, match="without it first"):
            vec.reset(options={"reset_mask": np.array([True, False])})
        vec.reset(seed=0)
        for bad, err in (([True, False], TypeError), (np.array([True]), ValueError),
                         (np.array([1, 0]), TypeError), (np.zeros(2, bool), ValueError)):
            with pytest.raises(err, match="reset_mask"):
                vec.reset(options={"reset_mask": bad})
    finally:
        vec.close()
