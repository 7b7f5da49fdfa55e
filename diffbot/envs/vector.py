"""``diffbot/Avoid-v0`` batched: N independent worlds stepped together in one process.

    envs = gym.make_vec("diffbot/Avoid-v0", num_envs=64, vectorization_mode="vector_entry_point")

Each of the N envs is an :class:`diffbot.envs.avoid.AvoidTask` on its own world
(:class:`plant.tick.Tick`, its own noise streams): env i after ``reset(seed=s)`` is the
single env after ``reset(seed=s + i)`` (a list of seeds: one each), step for step, to the
bit, whatever the world mode (``overrides=("world.mode=kinematic",)`` or the world's
dynamic one). Each control tick goes through every world in three passes: the commands
of each and the step of all (:func:`plant.tick.step_ticks`: a kinematic world's robots,
:mod:`plant.kinematic`, all worlds' in one call), then every world's sensor messages
(:func:`plant.tick.messages_of`: every world's lidars cast in one call of the kernel),
then each env's observation.

Autoreset is Gymnasium 1.x's next-step mode (``metadata["autoreset_mode"]``): the step that
ends env i's episode (terminated, or truncated at ``max_episode_steps``, 300 as registered)
returns its last observation; the next ``step`` ignores env i's action, resets it (its own
seed stream, as the single env's ``reset()`` without a seed) and returns the new
episode's first observation with reward 0 and both flags False.
"""
from __future__ import annotations

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from bus.controller import Twist
from plant.tick import messages_of, step_ticks

from .avoid import AvoidTask


class AvoidVectorEnv(VectorEnv):
    """N ``diffbot/Avoid-v0`` worlds in one process (module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10,
                "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = 300,
                 world: str = "living_room", action_repeat: int = 5,
                 goal_radius_m: float = 0.3, overrides: tuple[str, ...] = (),
                 normalize_actions: bool = False, render_mode: str | None = None,
                 transport: str = "inproc") -> None:
        if transport != "inproc":
            raise ValueError("vector_entry_point batches in-process worlds; for plants over "
                             "the bus use vectorization_mode='async' (one plant per worker)")
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.num_envs = int(num_envs)
        self.render_mode = render_mode
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.tasks: list[AvoidTask] = []
        try:
            for _ in range(self.num_envs):
                self.tasks.append(AvoidTask(world, "inproc", None, action_repeat, None,
                                            goal_radius_m, tuple(overrides), normalize_actions))
        except BaseException:
            self.close()
            raise
        first = self.tasks[0]
        if len(first.robots) != 1:
            self.close()
            raise ValueError(f"{world} has {len(first.robots)} robots; Avoid-v0 drives one")
        self.robot = first.robots[0]
        self.dt = first.dt
        self.metadata = {**type(self).metadata, "render_fps": round(1.0 / self.dt)}
        self.single_observation_space = first.observation_space(self.robot)
        self.single_action_space = first.action_space(self.robot)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._steps = np.zeros(self.num_envs, np.int64)
        self._needs_reset = np.zeros(self.num_envs, bool)

    # ---------------------------------------------------------------- episodes
    def _reset_one(self, i: int, seed: int | None) -> tuple[dict, dict]:
        """As :meth:`AvoidEnv.reset` (Env.reset's seeding rules, then the task's)."""
        if seed is not None or self._rngs[i] is None:
            self._rngs[i], _ = seeding.np_random(seed)
        task = self.tasks[i]
        obs, info = task.reset(self._rngs[i])
        task.episode.seed = seed
        self._steps[i] = 0
        self._needs_reset[i] = False
        return obs[self.robot], info[self.robot]

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        super().reset(seed=seed if isinstance(seed, int) else None)
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, int):
            seeds = [seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"{len(seeds)} seeds for {self.num_envs} envs")
        obs, infos = [], {}
        for i, s in enumerate(seeds):
            o, info = self._reset_one(i, s)
            obs.append(o)
            infos = self._add_info(infos, info, i)
        return self._stack(obs), infos

    def step(self, actions):
        actions = np.asarray(actions)
        if actions.shape[:1] != (self.num_envs,):
            raise ValueError(f"actions must have shape ({self.num_envs}, 2), got {actions.shape}")
        n = self.num_envs
        obs: list = [None] * n
        rew = np.zeros(n, np.float64)
        term = np.zeros(n, bool)
        trunc = np.zeros(n, bool)
        infos: dict = {}
        resets = np.flatnonzero(self._needs_reset)
        live = [i for i in range(n) if not self._needs_reset[i]]
        cmds = {i: self.tasks[i].begin_step({self.robot: actions[i]}) for i in live}
        self._advance(live, cmds)
        for i in live:
            o, r, te, tr, info = self.tasks[i].end_step()
            self._steps[i] += 1
            obs[i], rew[i], term[i] = o[self.robot], r[self.robot], te[self.robot]
            trunc[i] = (self.max_episode_steps is not None
                        and self._steps[i] >= self.max_episode_steps)   # as TimeLimit
            infos = self._add_info(infos, info[self.robot], i)
        for i in resets:
            obs[i], info = self._reset_one(int(i), None)
            infos = self._add_info(infos, info, int(i))
        self._needs_reset = term | trunc
        return self._stack(obs), rew, term, trunc, infos

    def _advance(self, live: list[int], cmds: dict) -> None:
        """Every live env's ``action_repeat`` ticks, tick by tick across the worlds; per
        world exactly :meth:`diffbot.envs.transport.InProc.advance`."""
        if not live:
            return
        transports = [self.tasks[i].transport for i in live]
        ticks = [tr.tick for tr in transports]
        for _ in range(self.tasks[0].action_repeat):
            for i, tick in zip(live, ticks):
                c = cmds[i]
                for name in tick.sim.robots:
                    tick.drive(name, Twist(*c.get(name, (0.0, 0.0))))
            step_ticks(ticks)
            wanted = [tr.wanted for tr in transports]
            ended = []
            for i, tr, msgs in zip(live, transports, messages_of(ticks, wanted)):
                tr.take(msgs)
                if self.tasks[i]._observe(tr.tick.t_ns, tr.latest, judge=False):
                    ended.append(self.tasks[i])
            if ended:                    # every world's contacts in one call
                geo = ended[0].geo
                for task, touched in zip(ended, geo.contacts_of([t.centres() for t in ended])):
                    task.touched = touched

    def _stack(self, obs: list[dict]) -> dict:
        return {k: np.stack([o[k] for o in obs]) for k in self.single_observation_space}

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        return tuple(t.render() for t in self.tasks)

    def close_extras(self, **kwargs) -> None:
        for t in self.tasks:
            t.close()
        self.tasks = []

