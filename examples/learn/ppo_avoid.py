"""PPO from Stable-Baselines3 on diffbot/Avoid-v0, then the trained model as a bus node.

    make setup                     # installs the sb3 extra (stable-baselines3, CPU torch)
    .venv/bin/python examples/learn/ppo_avoid.py --out out/ppo --steps 100000
    .venv/bin/python examples/learn/ppo_avoid.py --out out/ppo --quick     # a smoke run

It trains ``MultiInputPolicy`` (the Dict observation as it is) through
:class:`diffbot.envs.sb3.AvoidVecEnv` (``--envs`` worlds stepped together in this process,
``--mode`` kinematic by default), on normalised actions (the unit box PPO's Gaussian policy
expects; ``--no-normalize``: m/s and rad/s), then scores the deterministic policy and random
actions on ``--eval`` held-out seeds (goal reached without contact), and writes
``OUT/model.zip``, ``OUT/model.spec.json`` (the env's spec: what :class:`SB3Policy` scales
actions by), ``OUT/curve.csv`` (episode return and success by training step),
``OUT/curve.png`` and ``OUT/result.json``.

The model deploys with no code of ours beyond this file's :class:`SB3Policy` (any class
would do)::

    diffbot controller examples/learn/ppo_avoid.py:SB3Policy --arg model=out/ppo/model.zip \\
        --arg 'goal=(1.2, -0.5)' --robot robot1
    python -m diffbot.launch.deploy --seed 3 \\
        --controller "examples/learn/ppo_avoid.py:SB3Policy --arg model=out/ppo/model.zip"
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from bus.node import Twist  # noqa: E402
from controllers.learned import AvoidObserver  # noqa: E402


class SB3Policy:
    """A trained SB3 model as a controller: the Avoid observation built from the robot's
    messages (the environment's own code), a decision every ``action_repeat`` ticks, the
    action scaled as the environment it was trained in scaled it. That environment's
    settings (``normalize_actions``, ``action_repeat``, ``world``, ``overrides``,
    ``goal_radius_m``) come from its spec, saved beside the model (``spec``; default
    MODEL.spec.json, as :func:`main` writes it); without one, the model's action space
    tells: the unit box (normalised) or the world's drive limits. Done when its odometry
    puts it within ``goal_radius_m`` of ``goal`` (world, m)."""
    inputs = ["joint_states", "scan"]

    def __init__(self, model: str, goal=(0.0, 0.0), goal_radius_m: float | None = None,
                 spec: str | None = None) -> None:
        from stable_baselines3 import PPO
        self.model = PPO.load(model, device="cpu")
        self.env_kw = _trained_with(model, spec)
        self.goal = (float(goal[0]), float(goal[1]))
        self.goal_radius = float(goal_radius_m if goal_radius_m is not None
                                 else self.env_kw.get("goal_radius_m", 0.3))
        self.action_repeat = int(self.env_kw.get("action_repeat", 5))
        self.observer = None
        self.action = (0.0, 0.0)
        self.ticks = 0
        self.done = False

    def configure(self, info: dict, robot: str) -> None:
        r = info["robots"][robot]
        lidar = r["sensors"]["lidar"]
        self.observer = AvoidObserver(r["wheel_radius_m"], r["wheel_separation_m"],
                                      int(lidar["num_rays"]), float(lidar["max_range_m"]))
        self.observer.reset(r["pose"], self.goal)
        self.drive = drive_of(self.model.action_space, self.env_kw, robot)

    def step(self, obs):
        self.observer.feed(obs.t_ns, obs.msgs)
        if self.ticks % self.action_repeat == 0:
            o = self.observer.observation()
            if math.hypot(*o["goal"]) < self.goal_radius:
                self.done = True
                return Twist(0.0, 0.0)
            a, _ = self.model.predict(o, deterministic=True)
            self.action = self.drive.command(a)
        self.ticks += 1
        return Twist(*self.action)


def _trained_with(model: str, spec: str | None) -> dict:
    """The env arguments of the spec saved beside ``model`` (or at ``spec``); {} if none."""
    from gymnasium.envs.registration import EnvSpec
    path = spec or (model[:-4] if model.endswith(".zip") else model) + ".spec.json"
    if not os.path.exists(path):
        if spec is not None:
            raise FileNotFoundError(f"{spec}: no such env spec file")
        return {}
    with open(path) as f:
        return dict(EnvSpec.from_json(f.read()).kwargs)


def drive_of(space, env_kw: dict, robot: str):
    """The action scaling the model was trained with (diffbot.envs.actions.Drive), from
    the env arguments of its spec, or (none saved) from its action space; a model whose
    action space is not the scaling's is refused."""
    from diffbot.envs.actions import Drive
    from plant.world import load_world
    d = load_world(env_kw.get("world", "living_room"), list(env_kw.get("overrides", ()))
                   ).robot(robot).drive
    ways = ([bool(env_kw["normalize_actions"])] if "normalize_actions" in env_kw
            else [True, False])
    for normalize in ways:
        drive = Drive(d.max_linear_mps, d.max_angular_radps, normalize=normalize)
        if (np.array_equal(drive.space.low, space.low)
                and np.array_equal(drive.space.high, space.high)):
            return drive
    raise ValueError(f"the model's action space {space} is not {robot}'s drive "
                     f"(normalize_actions={ways}) in the env it was trained in: "
                     "pass spec= (the env's spec.to_json() file)")


def evaluate(act, seeds, spec) -> float:
    """The share of episodes ``act`` wins (goal reached without contact), one a seed, in
    the env of ``spec``."""
    import gymnasium as gym
    env = gym.make(spec)
    wins = 0
    try:
        for s in seeds:
            obs, _ = env.reset(seed=int(s))
            env.action_space.seed(int(s))
            while True:
                obs, _, term, trunc, info = env.step(act(env, obs))
                if term or trunc:
                    wins += bool(info["is_success"])
                    break
    finally:
        env.close()
    return wins / len(seeds)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="out/ppo")
    p.add_argument("--steps", type=int, default=100_000, help="training env steps")
    p.add_argument("--envs", type=int, default=8)
    p.add_argument("--eval", type=int, default=30, help="held-out episodes to score")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--mode", choices=("kinematic", "dynamic"), default="kinematic",
                   help="the world's mode while training (kinematic: ~20x faster; a policy "
                        "trained there drives the dynamic world too)")
    p.add_argument("--no-normalize", dest="normalize", action="store_false",
                   help="actions in m/s and rad/s, not the unit box")
    p.add_argument("--quick", action="store_true", help="a smoke run: 512 steps, 2 episodes")
    args = p.parse_args(argv)
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from diffbot.envs.sb3 import AvoidVecEnv
    if args.quick:
        args.steps, args.envs, args.eval = 512, 2, 2
    os.makedirs(args.out, exist_ok=True)
    venv = AvoidVecEnv(args.envs, normalize_actions=args.normalize,
                       overrides=(f"world.mode={args.mode}",))
    venv.seed(args.seed * 1000)
    curve = []

    class Curve(BaseCallback):
        def _on_step(self) -> bool:
            for info in self.locals["infos"]:
                if "episode" in info:
                    curve.append((self.num_timesteps, info["episode"]["r"],
                                  float(info.get("is_success", False))))
            return True

    n_steps = 64 if args.quick else 256
    model = PPO("MultiInputPolicy", venv, n_steps=n_steps, batch_size=64, seed=args.seed,
                device="cpu", verbose=0)
    t0 = time.monotonic()
    model.learn(args.steps, callback=Curve())
    train_s = time.monotonic() - t0
    venv.close()
    path = os.path.join(args.out, "model.zip")
    model.save(path)
    with open(os.path.join(args.out, "model.spec.json"), "w") as f:
        f.write(venv.spec.to_json())                # SB3Policy reads the scaling from it
    held_out = np.arange(10_000, 10_000 + args.eval)
    ppo = evaluate(lambda env, o: model.predict(o, deterministic=True)[0], held_out, venv.spec)
    rnd = evaluate(lambda env, o: env.action_space.sample(), held_out, venv.spec)
    with open(os.path.join(args.out, "curve.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "episode_return", "success"])
        w.writerows(curve)
    _plot(curve, os.path.join(args.out, "curve.png"))
    result = {"train_steps": args.steps, "train_wall_s": round(train_s, 1), "envs": args.envs,
              "mode": args.mode, "normalize_actions": args.normalize,
              "episodes": len(curve), "success_ppo": ppo, "success_random": rnd,
              "held_out_seeds": [int(held_out[0]), int(held_out[-1])], "model": path}
    with open(os.path.join(args.out, "result.json"), "w") as f:
        json.dump(result, f, indent=2)
    print(json.dumps(result, indent=2))
    return 0


def _plot(curve, path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 3.5))
    if curve:
        steps, ret, ok = (np.array(c, float) for c in zip(*curve))
        k = max(1, len(ret) // 20)
        smooth = np.convolve(ret, np.ones(k) / k, mode="valid")
        ax.plot(steps, ret, ".", alpha=0.3, label="episode return")
        ax.plot(steps[k - 1:], smooth, label=f"mean of {k}")
        ax2 = ax.twinx()
        ax2.plot(steps[k - 1:], np.convolve(ok, np.ones(k) / k, mode="valid"), "g-",
                 label="success rate")
        ax2.set_ylim(0, 1)
        ax2.set_ylabel("success rate")
    ax.set_xlabel("training env steps")
    ax.set_ylabel("episode return")
    ax.set_title("PPO (Stable-Baselines3) on diffbot/Avoid-v0")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
