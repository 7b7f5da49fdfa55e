"""The swarm's PettingZoo ParallelEnv, :class:`SwarmEnv`: one world of N robots, each an Avoid
agent. Made through :mod:`diffbot.envs.swarm_v0` (``parallel_env``, ``env``,
``vector_env``), whose docstring is the user's description."""
from __future__ import annotations

import os
import shutil
import tempfile
import weakref

import math

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from plant.swarm_world import swarm_world_text

from .avoid import AvoidTask
from .episode import next_seed


class SwarmEnv(ParallelEnv):
    metadata = {"name": "diffbot_swarm_v0", "render_modes": ["rgb_array"], "render_fps": 10,
                "is_parallelizable": True}

    def __init__(self, n_robots: int = 4, transport: str = "inproc", endpoint: str | None = None,
                 layout_seed: int = 0, action_repeat: int = 5, max_steps: int = 300,
                 goal_radius_m: float = 0.3, normalize_actions: bool = False,
                 render_mode: str | None = None, robot: str = "swarm",
                 mode: str = "dynamic") -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self._tmp = tempfile.mkdtemp(prefix="diffbot-swarm-")
        self._cleanup = weakref.finalize(self, shutil.rmtree, self._tmp, True)
        text = swarm_world_text(int(n_robots), int(layout_seed), mode, robot)
        world = os.path.join(self._tmp, "swarm.toml")
        with open(world, "w") as f:
            f.write(text)
        self.task = AvoidTask(world, transport, endpoint, action_repeat, max_steps,
                              goal_radius_m, (), normalize_actions)
        # the episodes carry the world itself (this file goes with the env)
        self.task.world, self.task.world_toml = "swarm", text
        self.possible_agents = list(self.task.robots)
        self.agents: list[str] = []
        self._obs_spaces = {a: self.task.observation_space(a) for a in self.possible_agents}
        self._act_spaces = {a: self.task.action_space(a) for a in self.possible_agents}
        self.dt = self.task.dt
        self.metadata = {**type(self).metadata, "render_fps": round(1.0 / self.dt)}
        hx, hy = (float(v) / 2 for v in self.task.spec.floor_size_m)
        high = np.tile(np.array([hx, hy, math.pi, hx, hy], np.float32),
                       len(self.possible_agents))
        self.state_space = spaces.Box(-high, high, dtype=np.float32)
        self._rng: np.random.Generator | None = None

    def observation_space(self, agent: str):
        return self._obs_spaces[agent]

    def action_space(self, agent: str):
        return self._act_spaces[agent]

    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is None:                # the next seed of the stream (episode.next_seed)
            seed = next_seed(self._rng or np.random.default_rng())
        self._rng = np.random.default_rng(seed)
        obs, infos = self.task.reset(self._rng)
        self.task.episode.seed = seed
        self.agents = list(self.possible_agents)
        return obs, infos

    def step(self, actions: dict):
        live = list(self.agents)
        return self.ended(live, *self.task.step(actions))

    def ended(self, live: list[str], obs: dict, rew: dict, term: dict, trunc: dict,
              infos: dict) -> tuple:
        """A step's results as :meth:`step` returns them, from the task's (``live``: the
        agents at the step's start), the agents it ended out of ``agents``; a batch of
        worlds (:mod:`diffbot.envs.swarm_vector`) steps their tasks together and ends each
        step here."""
        self.agents = [a for a in live if not (term[a] or trunc[a])]
        return ({a: obs[a] for a in live}, rew, term, trunc, infos)

    def state(self) -> np.ndarray:
        """Every robot's true x, y, yaw and goal x, y (world), in ``possible_agents`` order."""
        if not hasattr(self.task, "goals"):
            raise RuntimeError("call reset() before state()")
        rows = [(*self.task.truth[a], *self.task.goals[a]) for a in self.possible_agents]
        s = np.array(rows, np.float32).reshape(-1)
        return np.clip(s, self.state_space.low, self.state_space.high)

    def render(self):
        """``rgb_array``: the top-down view, every robot (its own colour), its goal (a ring
        of that colour) and its lidar rays (:mod:`diffbot.envs.render`)."""
        if self.render_mode == "rgb_array":
            return self.task.render()
        return None

    def close(self) -> None:
        self.task.close()
        self._cleanup()
