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


def main(argv: list[str] | None = None) -> int:
    """``python -m diffbot.envs.deploy --seed S --policy FILE.npz``: the Avoid episode of
    reset seed S played over the bus by ``diffbot run`` (a lockstep plant in the episode's
    state, the policy a process of its own), or ``--print`` the commands that start the
    same by hand."""
    import argparse
    import os
    import shlex
    p = argparse.ArgumentParser(prog="python -m diffbot.envs.deploy",
                                description="Play a diffbot/Avoid-v0 episode on a plant over "
                                            "the bus with a trained policy.")
    p.add_argument("--seed", type=int, required=True, help="the episode's reset seed")
    p.add_argument("--policy", metavar="FILE.npz", help="an MLPPolicy file "
                   "(diffbot controller policy)")
    p.add_argument("--controller", metavar="ARGS", help="instead of --policy: the controller's "
                   "arguments, e.g. 'python:my_pkg.agent:Agent --arg model=m.zip' (the "
                   "episode's goal is appended: --goal=X,Y, or --arg goal=(X, Y) to a class)")
    p.add_argument("--world", default="living_room")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="the env's overrides (its overrides= argument); repeatable")
    p.add_argument("--duration", type=float, default=30.0, metavar="S")
    p.add_argument("--out", default=None, help="output directory (default out/episode_SEED)")
    p.add_argument("--record", action="store_true", help="record the run (OUT/episode.mcap)")
    p.add_argument("--print", action="store_true", dest="print_only",
                   help="print the plant's and the controller's command lines, run nothing")
    args = p.parse_args(argv)
    if (args.policy is None) == (args.controller is None):
        p.error("give one of --policy and --controller")
    ep = episode(args.seed, args.world, overrides=tuple(args.set))
    if args.policy is not None:
        ctl = ["controller", "policy", "--file", os.path.abspath(args.policy), ep.goal_arg()]
    else:
        words = shlex.split(args.controller)
        gx, gy = ep.goal
        from controllers.hosted import is_target
        goal = (["--arg", f"goal=({gx!r}, {gy!r})"] if words and is_target(words[0])
                else [ep.goal_arg()])
        ctl = ["controller", *words, *goal]
    if args.print_only:
        q = shlex.join
        print(f"diffbot plant {q(ep.plant_args())} --expect policy_{ep.robot} "
              f"--end-with policy_{ep.robot}")
        print(f"diffbot {q(ctl)} --robot {ep.robot} --name policy_{ep.robot}")
        return 0
    out = os.path.abspath(args.out or os.path.join("out", f"episode_{args.seed}"))
    os.makedirs(out, exist_ok=True)
    path = os.path.join(out, "episode.toml")
    with open(path, "w") as f:
        f.write(scenario(ep, None, args.duration, controller=ctl))
    from diffbot.launcher import main as run_main
    run = [path, "--seed", str(ep.plant_seed), "--out", out]
    if args.record:
        run += ["--record", os.path.join(out, "episode.mcap")]
    print("diffbot run " + shlex.join(run), flush=True)
    return run_main(run)


if __name__ == "__main__":
    raise SystemExit(main())
