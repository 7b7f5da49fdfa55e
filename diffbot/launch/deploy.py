"""``python -m diffbot.launch.deploy``: a policy trained on ``diffbot/Avoid-v0`` plays its
episode over the bus, a process of its own under ``diffbot run``; ``--compare`` checks the
run against the same episode in-process, pose for pose (the pieces: :mod:`diffbot.envs.deploy`).
"""
from __future__ import annotations

import json
import os
import sys

from controllers.learned import MLPPolicy

from ..envs.deploy import compare, episode, ground_truth, play, scenario
from ..envs.episode import Episode


def _check(args, ep: Episode, out: str, run_main) -> int:
    """``--compare``: the policy in-process on the episode, then over the bus (recorded, as
    long as the in-process episode lasted unless ``--duration``), and :func:`~diffbot.envs.deploy.compare`;
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
    """``python -m diffbot.launch.deploy --seed S --policy FILE.npz``: the Avoid episode of
    reset seed S played over the bus by ``diffbot run`` (a lockstep plant in the episode's
    state, the policy a process of its own), or ``--print`` the commands that start the
    same by hand; ``--compare`` to check that the run over the bus is the in-process
    episode, pose for pose."""
    import argparse
    import shlex
    p = argparse.ArgumentParser(prog="python -m diffbot.launch.deploy",
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
    from .launcher import main as run_main
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
