"""``diffbot/Avoid-v0`` batched: N independent worlds stepped together, in one process or K.

    envs = gym.make_vec("diffbot/Avoid-v0", num_envs=64, vectorization_mode="vector_entry_point")

Each of the N envs is an :class:`diffbot.envs.avoid.AvoidTask` on its own world
(:class:`plant.tick.Tick`, its own noise streams): env i after ``reset(seed=s)`` is the
single env after ``reset(seed=s + i)`` (a list of seeds: one each), step for step, to the
bit, whatever the world mode (``overrides=("world.mode=kinematic",)`` or the world's
dynamic one). Each control tick goes through every world in three passes: the commands
of each and the step of all (:func:`plant.tick.step_ticks`: a kinematic world's robots,
:mod:`plant.kinematic`, all worlds' in one call), then every world's sensor messages
(:func:`plant.tick.messages_of`: every world's lidars cast in one call of the kernel),
then each env's observation. One-robot worlds (no camera: Avoid's) skip the messages:
:mod:`diffbot.envs.kinbatch` makes their commands, ticks, observations, rewards and
``info`` as arrays, the same numbers to the bit (``Worlds.arrays = None`` takes the
message path, the oracle ``tests/envs/test_envs_vector.py`` compares them with).

Autoreset is Gymnasium 1.x's, ``autoreset_mode=`` (``metadata["autoreset_mode"]``), as
``gymnasium.vector.SyncVectorEnv`` over single envs gives it, to the bit:

- ``NEXT_STEP`` (the default): the step that ends env i's episode (terminated, or
  truncated at ``max_episode_steps``, 300 as registered) returns its last observation; the
  next ``step`` ignores env i's action, resets it and returns the new episode's first
  observation with reward 0 and both flags False;
- ``SAME_STEP``: the step that ends it resets it at once and returns the new episode's
  first observation, the last one in ``infos["final_obs"]`` and its info in
  ``infos["final_info"]`` (each with its ``_`` mask);
- ``DISABLED``: a step of an ended episode is refused (RuntimeError); reset those envs with
  ``reset(options={"reset_mask": terminated | truncated})``.

``reset(options={"reset_mask": m})`` resets only the envs where ``m`` is True, in any mode.
An autoreset, like the single env's ``reset()`` without a seed, draws the episode's seed
from the env's own stream (:func:`diffbot.envs.episode.next_seed`): ``info["plant"].seed``.

``workers=K`` (default 1) splits the N worlds into K contiguous chunks: the first steps in
this process, each other in a worker process of its own (a fresh interpreter), all at
once, so a batch uses K cores; env i is the same env, to the bit, whatever K. A worker
ends with :meth:`AvoidVectorEnv.close`, or by itself when this process is gone.
``engine="ray"`` puts every chunk in a Ray actor instead, spread over a cluster's nodes
(``address=``, or a private instance on this machine: :mod:`diffbot.envs.ray_workers`);
the same envs, to the bit. ``threads=T`` casts a process's lidars on up to T threads
(default 1: worth raising only where cores stand idle); the same bits whatever T.
"""
from __future__ import annotations

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .actions import check_action
from .avoid import AvoidTask
from .results import merge, reset_mask
from .results import autoreset_mode as autoreset_mode_of
from .workers import _Worker
from .worlds import Worlds


class AvoidVectorEnv(VectorEnv):
    """N ``diffbot/Avoid-v0`` worlds in one process, or in ``workers`` (module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10,
                "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = 300,
                 world: str = "living_room", action_repeat: int = 5,
                 goal_radius_m: float = 0.3, overrides: tuple[str, ...] = (),
                 normalize_actions: bool = False, render_mode: str | None = None,
                 transport: str = "inproc", workers: int = 1, threads: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 engine: str = "processes", address: str | None = None) -> None:
        autoreset_mode = autoreset_mode_of(autoreset_mode)
        if engine not in ("processes", "ray"):
            raise ValueError(f"engine must be 'processes' or 'ray', got {engine!r}")
        if address is not None and engine != "ray":
            raise ValueError("address= is a Ray cluster's: engine='ray'")
        if transport != "inproc":
            raise ValueError("vector_entry_point batches in-process worlds; for plants over "
                             "the bus use vectorization_mode='async' (one plant per worker)")
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs!r}")
        if not 1 <= int(workers) <= int(num_envs):
            raise ValueError(f"workers must be between 1 and num_envs ({num_envs}), "
                             f"got {workers!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if threads is None:       # one: on a busy machine a second casting thread saved no
            threads = 1           # wall time and cost CPU (docs/benchmarks.md)
        elif int(threads) < 1:
            raise ValueError(f"threads must be >= 1, got {threads!r}")
        self.num_envs = int(num_envs)
        self.render_mode = render_mode
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        kw = dict(max_episode_steps=self.max_episode_steps, world=world,
                  action_repeat=action_repeat, goal_radius_m=goal_radius_m,
                  overrides=tuple(overrides), normalize_actions=normalize_actions,
                  threads=int(threads), autoreset_mode=autoreset_mode)
        k = int(workers)
        sizes = [self.num_envs // k + (1 if j < self.num_envs % k else 0) for j in range(k)]
        self.chunks: list = []
        self._ray = None
        try:
            if engine == "ray":                    # every chunk an actor (ray_workers)
                from .ray_workers import Session
                self._ray = Session(address)
                for size in sizes:
                    self.chunks.append(self._ray.chunk(size, kw))
                spaces = [c.result() for c in self.chunks]
            else:
                for size in sizes[1:]:             # the workers start while ours is built
                    self.chunks.append(_Worker(size, kw))
                self.chunks.insert(0, Worlds(sizes[0], **kw))
                spaces = [self.chunks[0].spaces()] + [w.result() for w in self.chunks[1:]]
        except BaseException:
            self.close_extras()
            raise
        robots, self.dt, obs_space, act_space = spaces[0]
        if robots != 1:
            self.close_extras()
            raise ValueError(f"{world} has {robots} robots; Avoid-v0 drives one")
        self.metadata = {**type(self).metadata, "render_fps": round(1.0 / self.dt),
                         "autoreset_mode": autoreset_mode}
        self.autoreset_mode = autoreset_mode
        self.single_observation_space = obs_space
        self.single_action_space = act_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._bounds = np.concatenate([[0], np.cumsum(sizes)])
        self._needs_reset = np.zeros(self.num_envs, bool)   # as each chunk's (autoreset)
        self._obs: dict | None = None                       # the last observations

    @property
    def tasks(self) -> list[AvoidTask]:
        """The tasks of the worlds in this process (all of them with ``workers=1``), up to
        date."""
        return self.chunks[0].sync() if self.chunks and isinstance(self.chunks[0], Worlds) else []

    def _all(self, method: str, per_chunk: list) -> list:
        """``method`` of every chunk with its argument, the remote ones' (worker processes,
        Ray actors) sent first, so they run while this process does its own; each chunk's
        result, in env order. Every remote chunk's answer is read even when a chunk fails
        (the first error is raised after), so the next call reads its own answers."""
        local = [isinstance(c, Worlds) for c in self.chunks]
        for c, arg, here in zip(self.chunks, per_chunk, local):
            if not here:
                c.send(method, *arg)
        out: list = [None] * len(self.chunks)
        error = None
        for j, (c, arg, here) in enumerate(zip(self.chunks, per_chunk, local)):
            if here:
                try:
                    out[j] = getattr(c, method)(*arg)
                except Exception as exc:
                    error = error or exc
        for j, (c, here) in enumerate(zip(self.chunks, local)):
            if not here:
                try:
                    out[j] = c.result()
                except Exception as exc:
                    error = error or exc
        if error is not None:
            raise error
        return out

    def _split(self, values) -> list:
        return [(values[lo:hi],) for lo, hi in zip(self._bounds[:-1], self._bounds[1:])]

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """All envs, or with ``options={"reset_mask": m}`` (a bool array, one per env, at
        least one True) only envs i where ``m[i]``: the others keep their episodes, their
        rows of the observation are their last, and ``infos`` holds the reset envs' only
        (as Gymnasium's vector envs do). ``seed``: None, an int (env i: ``seed + i``) or a
        list of one per env (a masked reset reads the masked envs' only)."""
        super().reset(seed=seed if isinstance(seed, int) else None)
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, int):
            seeds = [seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"{len(seeds)} seeds for {self.num_envs} envs")
        mask = reset_mask(options, self.num_envs)
        if mask is not None and self._obs is None:
            raise RuntimeError("reset_mask resets some envs of a running batch: call reset() "
                               "without it first")
        parts = self._all("reset", [(s, m) for (s,), (m,) in zip(
            self._split(seeds), self._split(mask) if mask is not None
            else [(None,)] * len(self.chunks))])
        which = np.arange(self.num_envs) if mask is None else np.flatnonzero(mask)
        obs, infos = [], {}
        for i, (o, info) in zip(which.tolist(), (r for part in parts for r in part)):
            obs.append(o)
            infos = self._add_info(infos, info, i)
        if mask is None:
            self._needs_reset[:] = False
            self._obs = self._stack(obs)
        else:
            self._needs_reset[mask] = False
            self._obs = {k: a.copy() for k, a in self._obs.items()}
            for k, a in self._obs.items():
                a[mask] = np.stack([o[k] for o in obs])
        return self._obs, infos

    def step(self, actions):
        actions = np.asarray(actions)
        if actions.shape[:1] != (self.num_envs,):
            raise ValueError(f"actions must have shape ({self.num_envs}, 2), got {actions.shape}")
        if self._obs is None:
            raise RuntimeError("call reset() before step()")
        if self.autoreset_mode == AutoresetMode.DISABLED and self._needs_reset.any():
            ended = np.flatnonzero(self._needs_reset).tolist()
            raise RuntimeError(
                f"the episodes of env {', '.join(map(str, ended))} are over and "
                "autoreset_mode is DISABLED: reset them first, "
                "reset(options={'reset_mask': terminated | truncated})")
        # checked before any world steps (a reset's action is ignored): check_action's
        # error for the first bad one
        live = ~self._needs_reset
        try:
            a = np.asarray(actions, dtype=np.float32)
            ok = a.ndim == 2 and a.shape[1] == 2 and bool(np.isfinite(a[live]).all())
        except (TypeError, ValueError):
            ok = False
        if not ok:
            for i in np.flatnonzero(live):
                check_action(actions[i], f"env {i}")
        obs, rew, term, trunc, infos = merge(self._all("step", self._split(actions)))
        # (same-step autoreset: every env's episode goes on)
        self._needs_reset = ((term | trunc) if self.autoreset_mode != AutoresetMode.SAME_STEP
                             else np.zeros(self.num_envs, bool))
        self._obs = obs
        return obs, rew, term, trunc, infos

    def _stack(self, obs: list[dict]) -> dict:
        return {k: np.stack([o[k] for o in obs]) for k in self.single_observation_space}

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        return tuple(f for part in self._all("render", [()] * len(self.chunks)) for f in part)

    def close_extras(self, **kwargs) -> None:
        for c in getattr(self, "chunks", []):
            c.close()
        self.chunks = []
        if getattr(self, "_ray", None) is not None:
            self._ray.close()
            self._ray = None
