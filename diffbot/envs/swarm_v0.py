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

from .swarm import SwarmEnv
from .swarm_vector import SwarmVectorEnv

__all__ = ["SwarmEnv", "SwarmVectorEnv", "env", "parallel_env", "vector_env"]


def parallel_env(**kwargs) -> SwarmEnv:
    return SwarmEnv(**kwargs)


def vector_env(num_worlds: int = 1, **kwargs):
    """``num_worlds`` swarm worlds stepped together, arrays shaped (worlds, robots, ...):
    :class:`diffbot.envs.swarm_vector.SwarmVectorEnv` (``kwargs``: :func:`parallel_env`'s,
    and ``autoreset_mode``)."""
    return SwarmVectorEnv(num_worlds, **kwargs)


def env(**kwargs):
    """The AEC form (PettingZoo's conversion of :func:`parallel_env`)."""
    from pettingzoo.utils.conversions import parallel_to_aec
    return parallel_to_aec(parallel_env(**kwargs))
