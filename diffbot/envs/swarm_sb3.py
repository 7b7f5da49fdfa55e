"""The swarm's batched worlds as a Stable-Baselines3 ``VecEnv`` of W x N agents (the ``sb3``
extra), what SuperSuit's ``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1`` make of
W ``parallel_env``, one policy for every robot:

    from diffbot.envs.swarm_sb3 import SwarmVecEnv
    from stable_baselines3 import PPO
    venv = SwarmVecEnv(8, n_robots=4, mode="kinematic", robot="avoid", normalize_actions=True)
    venv.seed(0)
    model = PPO("MultiInputPolicy", venv).learn(100_000)

:class:`SwarmVecEnv` drives :class:`diffbot.envs.swarm_vector.SwarmVectorEnv` in its
same-step autoreset mode. Its env k is robot ``k % N`` of world ``k // N`` (world after
world, as SuperSuit concatenates them); one agent's spaces are its spaces. Per agent:

- the step that ends the robot's episode (its goal, a contact, the step limit) gives
  ``done``, its last observation as ``info["terminal_observation"]``,
  ``"TimeLimit.truncated"`` (truncated and not terminated) and ``"episode"``: ``{"r": the
  robot's return, "l": its steps, "t": seconds since the env was made}``, as ``Monitor``
  writes it; its row of the observation is zeros;
- until its world's episode ends (every robot's has) its rows are zeros, reward 0, not
  done (SuperSuit's "black death"): the robots stand still, their worlds go on;
- when its world resets (in the step that ended the last robot), its row is the new
  episode's first observation and its reset info goes to ``reset_infos[k]``.

``reset()`` takes no seed: ``seed(s)`` sets world i's next reset seed to ``s + i`` (world i
is then ``swarm_v0.parallel_env`` after ``reset(seed=s + i)``, to the bit), used once;
``seed`` returns each agent's world's seed. Stable-Baselines3 is imported only here and in
:mod:`diffbot.envs.sb3`.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from gymnasium.vector import AutoresetMode

from .sb3 import BatchVecEnv
from .swarm_vector import SwarmVectorEnv

#: the per-robot info keys a step gives (``infos`` arrays (W, N, ...) of the batch)
_SKIP = ("active", "plant", "final_obs", "_final_obs", "final_info", "_final_info")


class SwarmVecEnv(BatchVecEnv):
    """``num_worlds`` swarm worlds as an SB3 VecEnv of ``num_worlds * n_robots`` agents
    (module docstring); ``kwargs`` are :func:`diffbot.envs.swarm_v0.parallel_env`'s.
    ``episode_stats=False`` leaves out the ``"episode"`` infos."""

    _unit = "agent"
    _what = "the swarm's VecEnv"

    def __init__(self, num_worlds: int = 8, episode_stats: bool = True, **kwargs) -> None:
        if "autoreset_mode" in kwargs:
            raise ValueError("SB3 resets an ended episode in the step that ends it: the "
                             "adapter's autoreset_mode is SAME_STEP, not an option")
        self.venv = SwarmVectorEnv(num_worlds, AutoresetMode.SAME_STEP, **kwargs)
        self.num_worlds, self.n_robots = self.venv.num_worlds, self.venv.n_robots
        self.episode_stats = bool(episode_stats)
        self._start(self.venv.num_agents, self.venv.single_observation_space,
                    self.venv.single_action_space)
        self._world_seeds: list[int | None] = [None] * self.num_worlds

    def _flat(self, obs: dict) -> dict:
        return {k: a.reshape(self.num_envs, *a.shape[2:]) for k, a in obs.items()}

    def _infos(self, infos: dict) -> list[dict]:
        """One dict per agent: its robot's info (rows ``active``), the world's episode."""
        active = infos["active"].reshape(-1)
        out: list[dict] = [{} for _ in range(self.num_envs)]
        cols = {k: v.reshape(self.num_envs, *v.shape[2:]) for k, v in infos.items()
                if k not in _SKIP}
        for k in np.flatnonzero(active).tolist():
            row = out[k]
            for key, col in cols.items():
                v = col[k]
                row[key] = v.copy() if v.ndim else v.item()
            row["plant"] = infos["plant"][k // self.n_robots]
        return out

    # ------------------------------------------------------------------ stepping
    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """World i's next reset seed ``seed + i`` (None: one drawn); each agent's world's."""
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._world_seeds = [seed + i for i in range(self.num_worlds)]
        self._seeds = [self._world_seeds[k // self.n_robots] for k in range(self.num_envs)]
        return self._seeds

    def reset(self):
        if any(self._options):
            raise ValueError("the swarm env takes no reset options (set_options)")
        seeds = None if all(s is None for s in self._world_seeds) else list(self._world_seeds)
        obs, infos = self.venv.reset(seed=seeds)
        self.reset_infos = self._infos(infos)
        self._world_seeds = [None] * self.num_worlds
        self._reset_seeds()
        self._reset_options()
        self._restart_tallies()
        return self._flat(obs)

    def step_wait(self):
        actions = self._take_actions()
        w, n = self.num_worlds, self.n_robots
        obs, rew, term, trunc, infos = self.venv.step(
            np.asarray(actions).reshape(w, n, *np.shape(actions)[1:]))
        obs = self._flat(obs)
        term, trunc, rew = term.reshape(-1), trunc.reshape(-1), rew.reshape(-1)
        dones = term | trunc
        world_ended = np.repeat(infos["_final_obs"], n)
        acted = (np.repeat(infos["_final_info"], n)
                 & infos["final_info"]["active"].reshape(-1)) | \
            (~world_ended & infos["active"].reshape(-1))
        self._returns += rew
        self._lengths += acted
        out = self._infos(infos)
        if world_ended.any():     # a reset world's rows: the reset's infos, the step's own
            final = self._infos(infos["final_info"])
            for k in np.flatnonzero(world_ended).tolist():
                self.reset_infos[k], out[k] = out[k], final[k]
        now = self._now()
        for k in np.flatnonzero(dones).tolist():
            i, j = divmod(k, n)
            info = out[k]
            if world_ended[k]:
                info["terminal_observation"] = {key: a[j].copy() for key, a
                                                in infos["final_obs"][i].items()}
            else:          # the world goes on: the robot's row is zeros from now on
                info["terminal_observation"] = {key: a[k].copy() for key, a in obs.items()}
                for a in obs.values():
                    a[k] = 0
            self._end_episode(info, k, bool(trunc[k] and not term[k]), now)
        for k in np.flatnonzero(~dones).tolist():
            out[k]["TimeLimit.truncated"] = False
        return obs, rew.astype(np.float32), dones, out

    # ------------------------------------------------------------------ the rest
    def get_images(self) -> Sequence[np.ndarray | None]:
        """A world's frame for each of its agents."""
        frames = self.venv.render()
        if frames is None:
            return [None] * self.num_envs
        return [frames[k // self.n_robots] for k in range(self.num_envs)]
