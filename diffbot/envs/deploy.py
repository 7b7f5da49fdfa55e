"""From a policy trained on ``diffbot/Avoid-v0`` to the same episode over the bus.

An Avoid episode is fixed by its ``reset`` seed: the start pose, the goal and the plant's
noise seed. :func:`episode` draws them as the environment does; :func:`scenario` writes a
scenario file that starts a lockstep plant (sequential coupling) in that state and
``diffbot controller policy`` to drive the robot, so ``diffbot run FILE --record R.mcap``
plays the episode with the policy a process of its own; :func:`ground_truth` reads the
robot's path back from the recording, and :func:`play` runs the policy in-process on the
same episode. As long as the controller drives (until its odometry says it is at the goal),
both paths are the same to the bit: the controller observes and decides exactly as the
environment's step does (docs/learning.md). :func:`compare` checks that, pose by pose;
``python -m diffbot.launch.deploy --seed S --policy P.npz --compare`` plays, records and
checks in one command (:mod:`diffbot.launch.deploy`).
"""
from __future__ import annotations

import json

import numpy as np

from bus import codec
from bus.keys import Keys
from controllers.learned import MLPPolicy

from .episode import Episode

ROBOT = "robot1"


def episode(seed: int, world: str = "living_room", **env_kw) -> Episode:
    """The episode ``diffbot/Avoid-v0`` plays after ``reset(seed=seed)``: ``info["plant"]``."""
    from .avoid import AvoidEnv
    env = AvoidEnv(world=world, **env_kw)
    try:
        _, info = env.reset(seed=seed)
        return info["plant"]
    finally:
        env.close()


def scenario(ep: Episode, policy_file: str | None, duration_s: float,
             goal_radius_m: float = 0.3, controller: list[str] | None = None) -> str:
    """A scenario file's text: the episode's plant (its world, start pose, overrides;
    ``diffbot run --seed ep.plant_seed``) and a controller process whose exit ends the run:
    ``diffbot controller policy`` with ``policy_file``, or the ``controller`` argv given
    (e.g. ``["controller", "python:my.module:MyPolicy", "--arg", "goal=1,2"]``)."""
    # JSON strings are valid TOML basic strings; repr() of a float reads back exactly
    q = json.dumps
    robot = ep.robot
    if controller is None:
        controller = ["controller", "policy", "--file", policy_file, ep.goal_arg(),
                      f"--goal-radius={float(goal_radius_m)!r}"]
    controller = [*controller, "--robot", robot]
    plant_args = [*ep.world_args()]
    if ep.disabled:
        plant_args += ["--disable", ",".join(ep.disabled)]
    desc = f"a trained policy drives {robot} through an Avoid episode (plant seed {ep.plant_seed})"
    return f'''[scenario]
description = {q(desc)}
world = {q(ep.world)}
mode = "lockstep"
coupling = "sequential"
duration_s = {float(duration_s)!r}
robot = {q(robot)}
analysis = "none"
plant_args = [{", ".join(q(a) for a in plant_args)}]

[[process]]
name = {q("policy_" + robot)}
command = [{", ".join(q(a) for a in controller)}]
ends_run = true
'''


def ground_truth(mcap: str, robot: str = ROBOT) -> dict[int, tuple[float, float, float]]:
    """The robot's true pose (x, y, yaw) by stamp (ns) in a recording."""
    from bridges.mcapfile import Recorded, iter_recording
    key = Keys().topic(robot, "ground_truth")
    rec = Recorded(mcap)
    out = {}
    for m in iter_recording(mcap, rec):
        if rec.key_of(m.channel_id) == key:
            msg = codec.decode(m.data, "nav_msgs/msg/Odometry")
            p = msg.pose.pose
            out[codec.msg_stamp_ns(msg)] = (p.position.x, p.position.y,
                                            codec.quaternion_to_yaw(p.orientation))
    return out


def play(policy: MLPPolicy, seed: int, max_steps: int = 300, world: str = "living_room",
         **env_kw) -> tuple[dict[int, tuple[float, float, float]], dict]:
    """The policy on the episode of ``seed``, in-process: the true pose after each step by
    sim time (ns), and the last step's info."""
    from .avoid import AvoidEnv
    env = AvoidEnv(world=world, **env_kw)
    try:
        obs, info = env.reset(seed=seed)
        path = {0: tuple(float(v) for v in info["pose"])}
        for _ in range(max_steps):
            obs, _, term, _, info = env.step(np.asarray(policy.act(obs), np.float32))
            path[env.task.t_ns] = tuple(float(v) for v in info["pose"])
            if term:
                break
        return path, info
    finally:
        env.close()


def compare(path: dict[int, tuple], truth: dict[int, tuple]) -> dict:
    """The in-process path (:func:`play`: pose by sim time, ns) against a recording's ground
    truth (:func:`ground_truth`): every step's pose but the last (the controller stops on
    its odometry, the environment on ground truth: they may part there) must be in the
    recording, equal to the bit. ``{"identical", "steps", "equal", "first_difference"
    (None, or {"t_s", "in_process", "over_the_bus"}), "last_in_process", "last_over_the_bus"}``."""
    steps = sorted(path)[:-1]
    equal, first = 0, None
    for t in steps:
        got = truth.get(t)
        if got is not None and tuple(got) == tuple(path[t]):
            equal += 1
        elif first is None:
            first = {"t_s": t * 1e-9, "in_process": list(path[t]),
                     "over_the_bus": None if got is None else list(got)}
    return {"identical": bool(steps) and equal == len(steps), "steps": len(steps),
            "equal": equal, "first_difference": first,
            "last_in_process": list(path[max(path)]) if path else None,
            "last_over_the_bus": list(truth[max(truth)]) if truth else None}
