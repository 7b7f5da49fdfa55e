"""A policy for diffbot/Avoid-v0, deployed with `diffbot run` as `diffbot controller policy`
(the one command `python -m diffbot.launch.deploy`, whose `--compare` checks it), or with a plant and the controller
started by hand from the values of the reset's ``info["plant"]``, drives the robot over the
bus exactly as it did in the environment (the same path to the bit, noise on) and to the
goal."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("gymnasium")
from controllers.learned import N_FEATURES, MLPPolicy  # noqa: E402
from diffbot.envs import deploy  # noqa: E402
from diffbot.envs.episode import Episode  # noqa: E402

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _seek_goal() -> MLPPolicy:
    """A linear policy set by hand: ahead when the goal is ahead, turn toward it
    (features: 12 lidar sectors, distance, cos and sin of the bearing, v, w)."""
    W = np.zeros((N_FEATURES, 2))
    W[13, 0], W[12, 0] = 1.5, 1.0        # v: goal ahead and far -> fast
    W[14, 1] = 3.0                       # w: toward the goal's side
    return MLPPolicy([(W, np.array([-0.5, 0.0]))], v_max=0.5, w_max=2.0, action_repeat=5,
                     v_min=-0.1)


#: noise on everything the robot senses and does (each drawn from the plant's seed)
NOISE = ("robots.robot1.encoders.noise={std = 0.002}", "robots.robot1.lidar.noise={std = 0.01}",
         "robots.robot1.motion.command_noise_std_radps=0.05")


def _won_episode(policy: MLPPolicy):
    """The first episode this policy wins in-process (deterministic: seeds fix everything)."""
    for seed in range(20):
        path, info = deploy.play(policy, seed, max_steps=200, overrides=NOISE)
        if info["is_success"]:
            assert len(path) > 10
            return seed, path, info["plant"]
    pytest.fail("the hand-set policy reached no goal in 20 episodes")


def _same_path(path: dict, truth: dict, goal) -> None:
    # every step but the last (the controller stops on its odometry, the environment on
    # ground truth: they may part there) lands on the same pose, to the bit
    report = deploy.compare(path, truth)
    assert report["identical"] and report["steps"] > 10, report
    x, y, _ = truth[max(truth)]
    assert math.hypot(goal[0] - x, goal[1] - y) < 0.4, "the robot stopped off the goal"


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_deployed_policy_drives_the_same_path_over_the_bus(tmp_path):
    policy = _seek_goal()
    seed, path, ep = _won_episode(policy)
    assert ep.overrides == NOISE and ep.poses["robot1"] == tuple(path[0])
    pfile = str(tmp_path / "p.npz")
    policy.save(pfile)
    argv = [sys.executable, "-m", "diffbot.launch.deploy", "--seed", str(seed), "--policy", pfile,
            "--out", str(tmp_path / "run"), "--compare"]
    for o in NOISE:
        argv += ["--set", o]
    out = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr[-3000:]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert "policy_robot1 finished" in summary["end_reason"]
    report = json.loads((tmp_path / "run" / "compare.json").read_text())
    assert report["identical"] and report["in_process_success"] and "identical" in out.stdout
    _same_path(path, deploy.ground_truth(str(tmp_path / "run" / "episode.mcap")), ep.goal)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_plant_and_policy_started_by_hand_from_the_reset_info_match_to_the_bit(
        tmp_path, procs, endpoint):
    # what a user does with info["plant"]: `diffbot plant` with its values, the policy node
    # beside it (the values written as the Episode writes them: repr, exact)
    policy = _seek_goal()
    seed, path, ep = _won_episode(policy)
    pfile = str(tmp_path / "p.npz")
    policy.save(pfile)
    plant = procs.diffbot("plant", *ep.plant_args(), "--expect", "policy_robot1",
                          "--wait-for", "recorder", "--end-with", "policy_robot1",
                          "--endpoint", endpoint, name="plant")
    mcap = str(tmp_path / "r.mcap")
    rec = procs.diffbot("record", mcap, "--endpoint", endpoint, name="recorder")
    ctl = procs.diffbot("controller", "policy", "--file", pfile, ep.goal_arg(), "--robot",
                        "robot1", "--endpoint", endpoint, name="policy")
    for p in (ctl, plant, rec):
        assert p.wait(200) == 0, procs.log(p)[-2000:]
    _same_path(path, deploy.ground_truth(mcap), ep.goal)


def test_an_episode_writes_its_values_exactly():
    ep = Episode(7, {"robot1": (0.1 + 0.2, -1 / 3, 2 ** 0.5)}, {"robot1": (1e-17, 3.0)},
                        overrides=("robots.robot1.lidar.noise={std = 0.01}",))
    args = ep.plant_args()
    pose = args[args.index("--set") + 1]
    assert pose == f"robots.robot1.pose=[{0.1 + 0.2!r}, {-1 / 3!r}, {2 ** 0.5!r}]"
    from plant.world import load_world
    sets = [v for k, v in zip(args, args[1:]) if k == "--set"]
    assert load_world("living_room", sets).robot("robot1").pose == ep.poses["robot1"]
    assert ep.goal_arg() == "--goal=1e-17,3.0"
    assert args[args.index("--seed") + 1] == "7" and args[-2:] == ["--disable", "camera"]


def test_compare_finds_a_pose_one_ulp_off_and_a_missing_one():
    path = {0: (0.0, 0.0, 0.0), 100_000_000: (0.1, 0.2, 0.3), 200_000_000: (0.2, 0.4, 0.6),
            300_000_000: (0.3, 0.5, 0.7)}
    truth = {t: p for t, p in path.items()}
    truth[300_000_000] = (9.0, 9.0, 9.0)                 # the last step may part
    assert deploy.compare(path, truth)["identical"]
    off = dict(truth)
    off[200_000_000] = (np.nextafter(0.2, 1.0), 0.4, 0.6)
    r = deploy.compare(path, off)
    assert not r["identical"] and r["equal"] == 2 and r["first_difference"]["t_s"] == 0.2
    del off[200_000_000]
    r = deploy.compare(path, off)
    assert not r["identical"] and r["first_difference"]["over_the_bus"] is None
