"""``diffbot.envs.swarm_v0``: the swarm scenario as a PettingZoo ParallelEnv.

One agent per robot of the swarm world (:mod:`plant.swarm_world`, laid out from
``n_robots`` and ``layout_seed``), each with the Avoid observation, action and reward
(:class:`diffbot.envs.avoid.AvoidTask`): every robot gets its own goal, and touching a
wall, an obstacle or another robot ends that robot's episode (it then stands still while
the others go on). ``state()`` is the global state (``state_space``): every robot's true
x, y, yaw and its goal's x, y in ``world``, robot after robot in ``possible_agents``
order. ``robot="avoid"`` gives the robots ``diffbot/Avoid-v0``'s action and observation
spaces (its drive limits and lidar rays, :func:`plant.swarm_world.swarm_world_text`), so a
policy trained on Avoid drives each of them; ``mode="kinematic"`` steps every robot in one
numpy call (:mod:`plant.kinematic`), as the batched Avoid does (``"dynamic"``, the
default: DART). ``layout_seed`` picks the generated world (room, obstacles, start area),
fixed for the env's life; ``reset(seed=)`` draws the poses, goals and noise. Every
``info[agent]["plant"]`` is the episode's :class:`diffbot.envs.episode.Episode` with the
reset seed (drawn from the env's stream when none is given) and the world's own text, so
two envs made alike play the same episodes (PettingZoo's ``parallel_seed_test``) and
``reset(seed=ep.seed)`` plays one again. :func:`vector_env` steps W such worlds together,
arrays shaped (worlds, robots, ...) (:mod:`diffbot.envs.swarm_vector`;
:mod:`diffbot.envs.swarm_sb3`: as a Stable-Baselines3 VecEnv of W x N agents). Same two
transports as the Gymnasium environments::

    from diffbot.envs import swarm_v0
    env = swarm_v0.parallel_env(n_robots=4)               # or transport="bus"
    obs, infos = env.reset(seed=0)
    while env.agents:
        obs, rew, term, trunc, infos = env.step(
            {a: env.action_space(a).sample() for a in env.agents})
"""
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


def parallel_env(**kwargs) -> SwarmEnv:
    return SwarmEnv(**kwargs)


def vector_env(num_worlds: int = 1, **kwargs):
    """``num_worlds`` swarm worlds stepped together, arrays shaped (worlds, robots, ...):
    :class:`diffbot.envs.swarm_vector.SwarmVectorEnv` (``kwargs``: :func:`parallel_env`'s,
    and ``autoreset_mode``)."""
    from .swarm_vector import SwarmVectorEnv
    return SwarmVectorEnv(num_worlds, **kwargs)


def env(**kwargs):
    """The AEC form (PettingZoo's conversion of :func:`parallel_env`)."""
    from pettingzoo.utils.conversions import parallel_to_aec
    return parallel_to_aec(parallel_env(**kwargs))
