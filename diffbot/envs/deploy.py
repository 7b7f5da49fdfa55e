"""From a policy trained on ``diffbot/Avoid-v0`` to the same episode over the bus.

An Avoid episode is fixed by its ``reset`` seed: the start pose, the goal and the plant's
noise seed. :func:`episode` draws them as the environment does; :func:`scenario` writes a
scenario file that starts a lockstep plant (sequential coupling) in that state and
``diffbot controller policy`` to drive the robot, so ``diffbot run FILE --record R.mcap``
plays the episode with the policy a process of its own; :func:`ground_truth` reads the
robot's path back from the recording, and :func:`play` runs the policy in-process on the
same episode. As long as the controller drives (until its odometry says it is at the goal),
both paths are the same to the bit: the controller observes and decides exactly as the
environment's step does (docs/learning.md).
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from bus import codec
from bus.keys import Keys
from controllers.learned import MLPPolicy

ROBOT = "robot1"


@dataclass
class Episode:
    seed: int                           # the reset seed
    plant_seed: int                     # the plant's noise seed it gives
    start: tuple[float, float, float]   # x, y, yaw in world (m, rad)
    goal: tuple[float, float]           # x, y in world (m)
    world: str = "living_room"


def episode(seed: int, world: str = "living_room") -> Episode:
    """The start, goal and plant seed ``diffbot/Avoid-v0`` draws for ``reset(seed=seed)``."""
    from .avoid import AvoidEnv
    env = AvoidEnv(world=world)
    try:
        _, info = env.reset(seed=seed)
        return Episode(seed, int(env.task.transport.spec.seed),
                       tuple(float(v) for v in info["pose"]),
                       tuple(float(v) for v in info["goal"]), world)
    finally:
        env.close()


def scenario(ep: Episode, policy_file: str, duration_s: float, goal_radius_m: float = 0.3
             ) -> str:
    """A scenario file's text: the episode's plant (``diffbot run --seed ep.plant_seed``)
    and the policy as a controller process whose exit ends the run."""
    x, y, yaw = ep.start
    gx, gy = ep.goal
    # JSON strings are valid TOML basic strings; repr() of a float reads back exactly
    q = json.dumps
    return f'''[scenario]
description = "a policy trained on diffbot/Avoid-v0 drives {ROBOT} to its goal (episode seed {ep.seed})"
world = {q(ep.world)}
mode = "lockstep"
coupling = "sequential"
duration_s = {float(duration_s)!r}
robot = "{ROBOT}"
analysis = "none"
plant_args = ["--disable", "camera", "--set", "robots.{ROBOT}.pose=[{x!r}, {y!r}, {yaw!r}]"]

[[process]]
name = "policy_{ROBOT}"
command = ["controller", "policy", "--robot", "{ROBOT}", "--file", {q(policy_file)},
           "--goal={gx!r},{gy!r}", "--goal-radius={float(goal_radius_m)!r}"]
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
