"""The Gymnasium environments give the same numbers in-process and over the bus, to the bit.

``transport="inproc"`` runs the plant's code (plant/tick.py, plant/sim.py, plant/sensors.py)
in the test's process; ``transport="bus"`` starts a real lockstep plant process and takes
part in it over Zenoh. With the same seed and the same actions, every observation, reward,
termination flag and ground-truth pose must be equal, bit for bit, over a few hundred steps
with resets in between.

If this fails after a change to the plant's tick (speed work on plant/process.py, plant/sim.py,
plant/sensors.py, plant/tick.py ...): the in-process transport (diffbot/envs/transport.py,
InProc) must do per tick exactly what the lockstep plant does: the commands of tick t
applied to every robot, one ``step_tick``, then the sensor messages due at the new tick,
drawing the noise streams in the same order. Keep both sides on plant/tick.py.
"""
from __future__ import annotations

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
import diffbot.envs  # noqa: E402,F401  (registers the environments)

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background

STEPS = 300


def _same_obs(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        a[k].dtype == b[k].dtype and a[k].tobytes() == b[k].tobytes() for k in a)


def _same_info(a: dict, b: dict, keys) -> bool:
    return all(np.asarray(a[k]).tobytes() == np.asarray(b[k]).tobytes() for k in keys)


def _compare(env_id: str, steps: int, info_keys, seed: int, **kw) -> dict:
    """Run both transports side by side with the same random actions; return counts."""
    inproc = gym.make(env_id, **kw)
    bus = gym.make(env_id, transport="bus", **kw)
    try:
        rng = np.random.default_rng(seed)
        oi, ii = inproc.reset(seed=seed)
        ob, ib = bus.reset(seed=seed)
        assert _same_obs(oi, ob) and _same_info(ii, ib, info_keys), "differ after reset"
        episodes = 1
        for step in range(steps):
            a = rng.uniform(inproc.action_space.low, inproc.action_space.high).astype(np.float32)
            ri, rb = inproc.step(a), bus.step(a)
            if step % 7 == 3:
                # a task read mid-episode (Avoid's fast path writes its state back to the
                # task's objects) changes nothing of what follows
                getattr(inproc.unwrapped, "task", None)
            where = f"step {step} of episode {episodes}"
            assert _same_obs(ri[0], rb[0]), f"observations differ at {where}"
            assert ri[1:4] == rb[1:4], f"reward/terminated/truncated differ at {where}"
            assert _same_info(ri[4], rb[4], info_keys), f"ground truth differs at {where}"
            if ri[2] or ri[3]:
                # alternately a new seed and the env's own stream of episodes
                s = None if episodes % 2 else seed + episodes
                oi, ii = inproc.reset(seed=s)
                ob, ib = bus.reset(seed=s)
                assert _same_obs(oi, ob) and _same_info(ii, ib, info_keys), \
                    f"differ after reset {episodes}"
                episodes += 1
        task = getattr(bus.unwrapped, "task", None)       # (Avoid's; Follow is its own)
        member = (task or bus.unwrapped).transport._res.member
        return {"episodes": episodes, "commands_sent": sum(
            n for k, n in member.published.items() if k.endswith("/cmd_vel"))}
    finally:
        bus.close()
        inproc.close()


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("mode", ["dynamic", "kinematic"])
def test_avoid_inproc_and_bus_agree_to_the_bit_over_300_steps_and_resets(mode):
    # short episodes so that several resets (sim/reset over the bus) are crossed. In both
    # world modes the in-process env steps through the batch's fast path for one world
    # (diffbot/envs/kinbatch.py, plant/kernels/ticks.c), the plant over the bus through
    # its messages: the same numbers, every noise on.
    out = _compare("diffbot/Avoid-v0", STEPS, ("pose", "goal", "distance", "t"), seed=7,
                   max_episode_steps=60,
                   overrides=(f"world.mode={mode}",
                              "robots.robot1.encoders.noise={std = 0.002}",
                              "robots.robot1.lidar.noise={std = 0.01}",
                              "robots.robot1.motion.command_noise_std_radps=0.05"))
    assert out["episodes"] >= 4
    # an action is one command over the bus, its other ticks held (PROTOCOL.md section 4,
    # "Holding"; without it, action_repeat = 5 of them), plus two per reset
    assert out["commands_sent"] <= STEPS + 2 * out["episodes"] + 1, out


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_follow_inproc_and_bus_agree_to_the_bit_with_camera_noise():
    _compare("diffbot/Follow-v0", 100, ("distance", "pose", "leader_pose", "t"), seed=3,
             detection=True, overrides=("robots.follower.camera.noise={std = 10.0}",))


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_avoid_over_the_bus_holding_at_the_bound_agrees_with_inproc_to_the_bit():
    """The project's own member (diffbot.envs.transport) holds each action's command for the
    bound's 25 ticks (sequential, 20 ms, cmd_timeout_s 0.5: PROTOCOL.md section 4, "Holding"),
    across resets: the command still acts on the last held tick, so the bus equals in-process."""
    out = _compare("diffbot/Avoid-v0", 24, ("pose", "goal", "distance", "t"), seed=11,
                   max_episode_steps=8, action_repeat=26,
                   overrides=("world.mode=kinematic",
                              "robots.robot1.motion.command_noise_std_radps=0.05"))
    assert out["episodes"] >= 3
    assert out["commands_sent"] <= 24 + 2 * out["episodes"] + 1, out     # one per action
