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
``python -m diffbot.envs.deploy --seed S --policy P.npz --compare`` plays, records and
checks in one command.
"""
from __future__ import annotations

import json
import os
import sys

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


def _check(args, ep: Episode, out: str, run_main) -> int:
    """``--compare``: the policy in-process on the episode, then over the bus (recorded, as
    long as the in-process episode lasted unless ``--duration``), and :func:`compare`;
    OUT/compare.json, one line said, exit 0 if identical, 1 if not."""
    policy = MLPPolicy.load(args.policy)
    path, info = play(policy, args.seed, args.max_steps, args.world, overrides=tuple(args.set))
    mcap = os.path.join(out, "episode.mcap")
    span = args.duration if args.duration is not None else max(path) * 1e-9 + 0.5
    code = run_main(args.run + ["--record", mcap, "--duration", repr(span)])
    if code != 0:
        print(f"the run over the bus failed (exit {code}): nothing compared", file=sys.stderr)
        return code
    report = {"seed": args.seed, "policy": os.path.abspath(args.policy),
              "in_process_success": bool(info["is_success"]), "recording": mcap,
              **compare(path, ground_truth(mcap, ep.robot))}
    with open(os.path.join(out, "compare.json"), "w") as f:
        json.dump(report, f, indent=2)
    if report["identical"]:
        print(f"identical: all {report['steps']} steps' poses over the bus equal the "
              f"in-process episode's, to the bit ({os.path.join(out, 'compare.json')})")
        return 0
    d = report["first_difference"]
    print(f"DIFFERENT: {report['equal']} of {report['steps']} steps equal; first at "
          f"t = {d['t_s']:.2f} s: in-process {d['in_process']}, over the bus "
          f"{d['over_the_bus']} ({os.path.join(out, 'compare.json')})", file=sys.stderr)
    return 1


def main(argv: list[str] | None = None) -> int:
    """``python -m diffbot.envs.deploy --seed S --policy FILE.npz``: the Avoid episode of
    reset seed S played over the bus by ``diffbot run`` (a lockstep plant in the episode's
    state, the policy a process of its own), or ``--print`` the commands that start the
    same by hand; ``--compare`` to check that the run over the bus is the in-process
    episode, pose for pose."""
    import argparse
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
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="sim seconds of the run (default 30; --compare: as long as the "
                        "in-process episode)")
    p.add_argument("--out", default=None, help="output directory (default out/episode_SEED)")
    p.add_argument("--record", action="store_true", help="record the run (OUT/episode.mcap)")
    p.add_argument("--print", action="store_true", dest="print_only",
                   help="print the plant's and the controller's command lines, run nothing")
    p.add_argument("--compare", action="store_true",
                   help="also play the policy in-process and check that every pose over the "
                        "bus equals the in-process one (OUT/compare.json; exit 1 if not)")
    p.add_argument("--max-steps", type=int, default=300, metavar="N",
                   help="--compare: the in-process episode's step limit (the env's: 300)")
    args = p.parse_args(argv)
    if (args.policy is None) == (args.controller is None):
        p.error("give one of --policy and --controller")
    if args.compare and args.policy is None:
        p.error("--compare plays the policy in-process too: give it as --policy FILE.npz")
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
        f.write(scenario(ep, None, 30.0 if args.duration is None else args.duration,
                         controller=ctl))
    from diffbot.launcher import main as run_main
    run = [path, "--seed", str(ep.plant_seed), "--out", out]
    if args.compare:
        args.run = run
        return _check(args, ep, out, run_main)
    if args.record:
        run += ["--record", os.path.join(out, "episode.mcap")]
    print("diffbot run " + shlex.join(run), flush=True)
    return run_main(run)


if __name__ == "__main__":
    raise SystemExit(main())
