"""Train diffbot/Avoid-v0 in-process with numpy only, then drive the policy over the bus.

The cross-entropy method on a small policy (controllers/learned.py: 12 lidar sectors,
the goal's distance and bearing, v, w -> v, w; linear and squashed by default, 36
parameters, or an MLP with ``--hidden``). Each candidate is scored on the same few
training seeds, two worker processes (two cores) share the candidates, and the run stops
after ``--iterations`` or ``--minutes``. The best policy is then compared with random
actions on held-out seeds (success = the goal reached without contact), saved, and run
as a swap-in controller with ``diffbot run`` over the bus (a lockstep plant, sequential
coupling, ``diffbot controller policy``): the same seed's start and goal, a separate
process driving the robot.

    python examples/learn/train_avoid.py --out out/learn          # < 10 min on two cores
    python examples/learn/train_avoid.py --out out/learn --quick  # a smoke run
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from multiprocessing import get_context

import numpy as np

import gymnasium as gym

import diffbot.envs  # noqa: F401  (registers diffbot/Avoid-v0)
from controllers.learned import MLPPolicy
from diffbot.envs import deploy as deploy_

EPISODE_STEPS = 150              # 15 s: goals are 1-3 m away


def _make_env():
    return gym.make("diffbot/Avoid-v0", max_episode_steps=EPISODE_STEPS)


_ENV = None


def _episode(env, act, seed: int) -> tuple[float, bool]:
    obs, _ = env.reset(seed=seed)
    total, done, info = 0.0, False, {}
    while not done:
        obs, r, term, trunc, info = env.step(np.asarray(act(obs), np.float32))
        total += r
        done = term or trunc
    return total, bool(info.get("is_success"))


def _policy(theta, hidden, env) -> MLPPolicy:
    v, w = env.action_space.high
    return MLPPolicy.from_vector(theta, hidden, v_max=float(v), w_max=float(w),
                                 action_repeat=env.unwrapped.task.action_repeat,
                                 v_min=-0.2 * float(v))


def _worker_env():
    global _ENV
    if _ENV is None:
        _ENV = _make_env()
    return _ENV


def score(args) -> tuple[float, float]:
    """Mean return and success rate of one candidate over the seeds (in a worker)."""
    theta, hidden, seeds = args
    env = _worker_env()
    pol = _policy(theta, hidden, env)
    out = [_episode(env, pol.act, s) for s in seeds]
    return float(np.mean([r for r, _ in out])), float(np.mean([s for _, s in out]))


def random_success(seed: int) -> bool:
    """Whether random actions (drawn from ``seed``) win the episode of ``seed`` (a worker)."""
    env = _worker_env()
    env.action_space.seed(seed)
    return _episode(env, lambda o: env.action_space.sample(), seed)[1]


def evaluate(pool, theta, hidden, seeds) -> tuple[list[bool], list[bool]]:
    """Per held-out episode: did the policy win it, did random actions."""
    learned = [s > 0 for _, s in pool.map(score, [(theta, hidden, [s]) for s in seeds])]
    return learned, pool.map(random_success, seeds)


def train(args, pool) -> tuple[np.ndarray, list[dict]]:
    rng = np.random.default_rng(args.seed)
    n = MLPPolicy.size(args.hidden)
    mean, std = np.zeros(n), np.full(n, 0.5)
    history = []
    t0 = time.monotonic()
    for it in range(args.iterations):
        seeds = [1000 * it + k for k in range(args.episodes)]   # fresh seeds each time
        pop = mean + std * rng.standard_normal((args.population, n))
        scores = pool.map(score, [(theta, args.hidden, seeds) for theta in pop])
        ret = np.array([s[0] for s in scores])
        elite = pop[np.argsort(ret)[-args.elite:]]
        mean = elite.mean(axis=0)
        std = elite.std(axis=0) + 0.02
        i = int(np.argmax(ret))
        history.append({"iteration": it, "best_return": float(ret.max()),
                        "mean_return": float(ret.mean()),
                        "best_success": float(scores[i][1]),
                        "wall_s": round(time.monotonic() - t0, 1)})
        print(f"iter {it:2d}  return best {ret.max():6.2f} mean {ret.mean():6.2f}  "
              f"success of best {scores[i][1]:.2f}  ({time.monotonic() - t0:.0f} s)",
              flush=True)
        if time.monotonic() - t0 > args.minutes * 60:
            print("time budget reached", flush=True)
            break
    return mean, history


def deploy(policy: MLPPolicy, policy_path: str, seed: int, out: str) -> dict:
    """Run the saved policy over the bus with `diffbot run` on the episode of ``seed``
    (start pose, goal and noise seed as the environment draws them), the policy a process
    of its own, recorded; then compare the robot's path with the same episode in-process."""
    ep = deploy_.episode(seed)
    scenario = os.path.join(out, "avoid_policy.toml")
    with open(scenario, "w") as f:
        f.write(deploy_.scenario(ep, os.path.abspath(policy_path), EPISODE_STEPS * 0.1))
    run_out = os.path.join(out, "run")
    mcap = os.path.join(run_out, "episode.mcap")
    cmd = [sys.executable, "-m", "diffbot.cli", "run", scenario, "--seed", str(ep.plant_seed),
           "--out", run_out, "--record", mcap]
    print("$ diffbot", " ".join(cmd[3:]), flush=True)
    code = subprocess.call(cmd)
    result = {"exit_code": code, "scenario": scenario, "recording": mcap,
              "goal": list(ep.goal)}
    if code != 0:
        return result
    with open(os.path.join(run_out, "summary.json")) as f:
        result["end"] = json.load(f).get("end_reason")
    truth = deploy_.ground_truth(mcap)
    x, y, _ = truth[max(truth)]
    path, info = deploy_.play(policy, seed, max_steps=EPISODE_STEPS)
    same = 0
    for t in sorted(path):
        if truth.get(t) != path[t]:
            break
        same += 1
    result.update(final_distance_m=math.hypot(ep.goal[0] - x, ep.goal[1] - y),
                  reached=math.hypot(ep.goal[0] - x, ep.goal[1] - y) < 0.3 + 0.1,
                  inproc_success=bool(info["is_success"]), steps_inproc=len(path) - 1,
                  same_pose_steps=same - 1)
    print(f"over the bus: the robot stopped {result['final_distance_m']:.2f} m from the goal; "
          f"its true path equals the in-process episode's to the bit for "
          f"{same - 1} of {len(path) - 1} steps", flush=True)
    return result


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default="out/learn")
    p.add_argument("--iterations", type=int, default=12)
    p.add_argument("--population", type=int, default=12)
    p.add_argument("--elite", type=int, default=3)
    p.add_argument("--episodes", type=int, default=3, help="training seeds per candidate")
    p.add_argument("--eval", type=int, default=30, help="held-out seeds for the comparison")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--minutes", type=float, default=7.0, help="training time budget")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--hidden", type=int, nargs="*", default=[], metavar="N",
                   help="hidden layer sizes of the MLP (default none: a linear policy)")
    p.add_argument("--quick", action="store_true", help="2 iterations, a smoke run")
    p.add_argument("--policy", metavar="FILE.npz",
                   help="skip training: deploy this policy over the bus (the first held-out "
                        "episode)")
    args = p.parse_args()
    if args.quick:
        args.iterations, args.population, args.elite, args.episodes, args.eval = 2, 4, 2, 1, 4
    os.makedirs(args.out, exist_ok=True)
    held_out = [10**6 + k for k in range(args.eval)]
    if args.policy:
        policy = MLPPolicy.load(args.policy)
        print(json.dumps(deploy(policy, args.policy, held_out[0], args.out), indent=1))
        return 0
    t0 = time.monotonic()
    with get_context("spawn").Pool(args.workers) as pool:
        theta, history = train(args, pool)
        train_s = time.monotonic() - t0
        outcomes, rand_outcomes = evaluate(pool, theta, args.hidden, held_out)
    learned, rand = float(np.mean(outcomes)), float(np.mean(rand_outcomes))
    env = _make_env()
    policy = _policy(theta, args.hidden, env)
    env.close()
    path = os.path.join(args.out, "avoid_policy.npz")
    policy.save(path)
    print(f"success rate on {len(held_out)} held-out episodes: policy {learned:.2f}, "
          f"random {rand:.2f} (margin {learned - rand:+.2f}); trained in "
          f"{train_s:.0f} s, evaluated in {time.monotonic() - t0 - train_s:.0f} s; saved {path}",
          flush=True)
    result = {"success_policy": learned, "success_random": rand, "margin": learned - rand,
              "held_out_episodes": len(held_out), "train_wall_s": train_s,
              "history": history, "policy": path}
    # the first held-out episode the policy won in-process (else the first), over the bus
    wins = [s for s, ok in zip(held_out, outcomes) if ok]
    result["deploy"] = deploy(policy, path, (wins or held_out)[0], args.out)
    with open(os.path.join(args.out, "result.json"), "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps({k: v for k, v in result.items() if k != "history"}, indent=1))
    return 0 if result["deploy"]["exit_code"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
