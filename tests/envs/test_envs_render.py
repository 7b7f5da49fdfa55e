"""render_mode="rgb_array" draws the room from above with each robot, goal and lidar ray
where the ground truth has them: checked on the pixels."""
from __future__ import annotations

import math

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("pettingzoo")
import diffbot.envs  # noqa: E402,F401
from diffbot.analysis.swarm import FOOTPRINT_RADIUS_M  # noqa: E402
from diffbot.envs.geometry import Footprints  # noqa: E402
from diffbot.envs.render import GOAL, RAY, ROBOT_COLOURS  # noqa: E402


def _where(img: np.ndarray, colour) -> tuple[np.ndarray, int]:
    """Centroid (col, row) of the pixels of exactly this colour, and how many."""
    rows, cols = np.nonzero(np.all(img == np.array(colour, np.uint8), axis=2))
    return np.array([cols.mean(), rows.mean()]) if len(rows) else None, len(rows)


def _pixel(spec, img, x, y) -> np.ndarray:
    """Where world point (x, y) should be: north up, the floor filling the image."""
    fx, fy = spec.floor_size_m
    h, w = img.shape[:2]
    return np.array([(x + fx / 2) * w / fx, (fy / 2 - y) * h / fy])


def _px_per_m(spec, img) -> float:
    return img.shape[1] / spec.floor_size_m[0]


def test_avoid_draws_the_robot_the_goal_and_rays_where_the_state_says():
    env = gym.make("diffbot/Avoid-v0", render_mode="rgb_array")
    try:
        assert env.metadata["render_fps"] == 10
        env.reset(seed=3)
        for _ in range(4):
            _, _, _, _, info = env.step(np.array([0.3, 0.4], np.float32))
        img = env.render()
        spec = env.unwrapped.task.spec
        assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
        k = _px_per_m(spec, img)
        robot, n = _where(img, ROBOT_COLOURS[0])
        want = _pixel(spec, img, *Footprints.centre(*info["pose"]))
        assert np.linalg.norm(robot - want) < 2.5, (robot, want)
        # the footprint disc, less the heading line drawn over it
        assert 0.8 < n / (math.pi * (FOOTPRINT_RADIUS_M * k) ** 2) < 1.1
        goal, _ = _where(img, GOAL)
        assert np.linalg.norm(goal - _pixel(spec, img, *info["goal"])) < 2.5
        assert _where(img, RAY)[1] > 500, "no lidar rays drawn"
        # the robot moved: the next frame has it elsewhere, the room unchanged
        env.step(np.array([0.5, 0.0], np.float32))
        moved, _ = _where(env.render(), ROBOT_COLOURS[0])
        assert np.linalg.norm(moved - robot) > 1.0
    finally:
        env.close()


def test_follow_draws_both_robots_beside_the_camera_image():
    env = gym.make("diffbot/Follow-v0", render_mode="rgb_array")
    try:
        assert env.metadata["render_fps"] == 25
        env.reset(seed=4)
        obs, _, _, _, info = env.step(np.zeros(2, np.float32))
        img = env.render()
        spec = env.unwrapped.spec_
        fx, fy = spec.floor_size_m
        ch, cw = obs["image"].shape[:2]
        k = img.shape[0] // ch                    # the camera scaled by a whole factor
        side = img.shape[1] - cw * k
        top = img[:round(side * fy / fx), :side]
        for colour, pose in ((ROBOT_COLOURS[0], info["leader_pose"]),
                             (ROBOT_COLOURS[1], info["pose"])):
            at, _ = _where(top, colour)
            assert np.linalg.norm(at - _pixel(spec, top, *Footprints.centre(*pose))) < 2.5
        cam = img[:ch * k, side:]
        assert np.array_equal(cam[::k, ::k], obs["image"]), "the camera image is not beside"
    finally:
        env.close()


def test_swarm_draws_every_robot_in_its_colour():
    from diffbot.envs import swarm_v0
    env = swarm_v0.parallel_env(n_robots=3, render_mode="rgb_array")
    try:
        assert env.metadata["render_fps"] == 10
        _, infos = env.reset(seed=1)
        img = env.render()
        spec = env.task.spec
        r = 0.8 * FOOTPRINT_RADIUS_M * _px_per_m(spec, img)
        rows, cols = np.mgrid[:img.shape[0], :img.shape[1]]
        for i, a in enumerate(env.possible_agents):
            # (a goal's ring has its robot's colour too: look at the disc where it should be)
            cx, cy = _pixel(spec, img, *Footprints.centre(*infos[a]["pose"]))
            disc = (cols - cx) ** 2 + (rows - cy) ** 2 < r ** 2
            same = np.all(img[disc] == np.array(ROBOT_COLOURS[i], np.uint8), axis=1)
            assert same.mean() > 0.6, f"{a} is not drawn where it stands"   # (heading line)
    finally:
        env.close()


def test_no_render_mode_renders_nothing_and_a_bad_one_is_refused():
    env = gym.make("diffbot/Avoid-v0")
    try:
        env.reset(seed=0)
        assert env.render() is None
    finally:
        env.close()
    from diffbot.envs.avoid import AvoidEnv
    with pytest.raises(ValueError, match="render_mode"):
        AvoidEnv(render_mode="ansi")
