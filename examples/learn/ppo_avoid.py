"""PPO from Stable-Baselines3 on diffbot/Avoid-v0, then the trained model as a bus node.

    pip install -e '.[sb3]'        # stable-baselines3 (and torch: a CPU build is enough)
    .venv/bin/python examples/learn/ppo_avoid.py --out out/ppo --steps 100000
    .venv/bin/python examples/learn/ppo_avoid.py --out out/ppo --quick     # a smoke run

It trains ``MultiInputPolicy`` (the Dict observation as it is) on normalised actions
(``normalize_actions=True``: the unit box PPO's Gaussian policy expects), ``--envs`` envs
in this process (SB3's DummyVecEnv), then scores the deterministic policy and random
actions on ``--eval`` held-out seeds (goal reached without contact), and writes
``OUT/model.zip``, ``OUT/curve.csv`` (episode return and success by training step),
``OUT/curve.png`` and ``OUT/result.json``.

The model deploys with no code of ours beyond this file's :class:`SB3Policy` (any class
would do)::

    diffbot controller examples/learn/ppo_avoid.py:SB3Policy --arg model=out/ppo/model.zip \\
        --arg 'goal=(1.2, -0.5)' --robot robot1
    python -m diffbot.envs.deploy --seed 3 \\
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
    normalised action scaled to the drive limits as the environment does. Done when its
    odometry puts it within ``goal_radius_m`` of ``goal`` (world, m)."""
    inputs = ["joint_states", "scan"]

    def __init__(self, model: str, goal=(0.0, 0.0), goal_radius_m: float = 0.3,
                 action_repeat: int = 5, world: str = "living_room") -> None:
        from stable_baselines3 import PPO
        from diffbot.envs.actions import Drive
        from plant.world import load_world
        self.model = PPO.load(model, device="cpu")
        self.goal = (float(goal[0]), float(goal[1]))
        self.goal_radius = float(goal_radius_m)
        self.action_repeat = int(action_repeat)
        self.world = world
        self._drive_of = lambda robot: load_world(world).robot(robot).drive
        self.Drive = Drive
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
        d = self._drive_of(robot)
        self.drive = self.Drive(d.max_linear_mps, d.max_angular_radps, normalize=True)

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


def make_env(seed: int):
    def thunk():
        import gymnasium as gym
        import diffbot.envs  # noqa: F401
        from stable_baselines3.common.monitor import Monitor
        env = Monitor(gym.make("diffbot/Avoid-v0", normalize_actions=True),
                      info_keywords=("is_success",))
        env.reset(seed=seed)
        return env
    return thunk


def evaluate(act, seeds) -> float:
    import gymnasium as gym
    import diffbot.envs  # noqa: F401
    env = gym.make("diffbot/Avoid-v0", normalize_actions=True)
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
    p.add_argument("--quick", action="store_true", help="a smoke run: 512 steps, 2 episodes")
    args = p.parse_args(argv)
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv
    if args.quick:
        args.steps, args.envs, args.eval = 512, 2, 2
    os.makedirs(args.out, exist_ok=True)
    venv = DummyVecEnv([make_env(args.seed * 1000 + i) for i in range(args.envs)])
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
    held_out = np.arange(10_000, 10_000 + args.eval)
    ppo = evaluate(lambda env, o: model.predict(o, deterministic=True)[0], held_out)
    rnd = evaluate(lambda env, o: env.action_space.sample(), held_out)
    with open(os.path.join(args.out, "curve.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "episode_return", "success"])
        w.writerows(curve)
    _plot(curve, os.path.join(args.out, "curve.png"))
    result = {"train_steps": args.steps, "train_wall_s": round(train_s, 1), "envs": args.envs,
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
