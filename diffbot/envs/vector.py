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
message path, the oracle ``tests/test_envs_vector.py`` compares them with).

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
(default: the CPUs this process may use divided by K; 1 in a Ray actor); the same bits
whatever T.
"""
from __future__ import annotations

import math

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from bus.controller import Twist
from plant.footprint import footprint_centres
from plant.tick import messages_of, step_ticks

from .actions import check_action
from .avoid import AvoidTask, step_rewards
from .episode import next_seed
from .kinbatch import ArrayTicks
from .results import Out, merge, reset_mask
from .results import autoreset_mode as autoreset_mode_of
from .workers import _Worker, cpus


class Worlds:
    """``n`` envs of a batch (a contiguous chunk of it): their tasks, episodes and stepping
    (the module docstring), in this process or in a worker's (:func:`_serve`). Each call
    returns one result per env, in order."""

    def __init__(self, n: int, max_episode_steps: int | None, world: str, action_repeat: int,
                 goal_radius_m: float, overrides: tuple[str, ...],
                 normalize_actions: bool, threads: int = 1,
                 autoreset_mode: AutoresetMode = AutoresetMode.NEXT_STEP) -> None:
        self.n = int(n)
        self.max_episode_steps = max_episode_steps
        self.autoreset_mode = autoreset_mode
        self.tasks: list[AvoidTask] = []
        try:
            for _ in range(self.n):
                self.tasks.append(AvoidTask(world, "inproc", None, action_repeat, None,
                                            goal_radius_m, tuple(overrides), normalize_actions))
        except BaseException:
            self.close()
            raise
        self.robot = self.tasks[0].robots[0]
        self._obs_space = self.tasks[0].observation_space(self.robot)
        self._rngs: list[np.random.Generator | None] = [None] * self.n
        self._steps = np.zeros(self.n, np.int64)
        self._needs_reset = np.zeros(self.n, bool)
        #: kinematic worlds ticked as arrays (:mod:`diffbot.envs.kinbatch`; None: every
        #: world through its messages, the path the arrays are tested against)
        self.arrays: ArrayTicks | None = ArrayTicks(self.n, threads)
        # Kept from step to step until the env is reset: ArrayTicks.eligible's answer for
        # the env's task; and (``_kept``) its goal distance where the last array step left
        # it, with its objects and state in ``arrays`` (ArrayTicks.advance's rows).
        self._eligible = np.zeros(self.n, bool)
        self._dist = np.zeros(self.n)
        self._kept = np.zeros(self.n, bool)

    def spaces(self):
        t = self.tasks[0]
        return (len(t.robots), t.dt, t.observation_space(self.robot), t.action_space(self.robot))

    def _reset_one(self, i: int, seed: int | None) -> tuple[dict, dict]:
        """As :meth:`AvoidEnv.reset` (Env.reset's seeding rules, a seed drawn when none is
        given: :func:`diffbot.envs.episode.next_seed`; then the task's)."""
        if seed is None:
            if self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(None)
            seed = next_seed(self._rngs[i])
        self._rngs[i], _ = seeding.np_random(seed)
        if self.arrays is not None:
            self.arrays.flush(np.array([i]))
        task = self.tasks[i]
        obs, info = task.reset(self._rngs[i])
        task.episode.seed = seed
        self._steps[i] = 0
        self._needs_reset[i] = False
        self._eligible[i] = self._kept[i] = False
        return obs[self.robot], info[self.robot]

    def reset(self, seeds: list[int | None], mask: np.ndarray | None = None
              ) -> list[tuple[dict, dict]]:
        """Each env's reset (``mask``: only those where it is True), in order."""
        return [self._reset_one(i, s) for i, s in enumerate(seeds)
                if mask is None or mask[i]]

    def step(self, actions: np.ndarray) -> tuple:
        """(obs {key: (n, ...)}, reward (n,), terminated (n,), truncated (n,), infos) of
        the chunk's envs, ``infos`` batched as Gymnasium's vector envs batch them (each key
        with its ``_key`` mask)."""
        out = Out(self.n, self._obs_space)
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            resets = np.flatnonzero(self._needs_reset)
            live = np.flatnonzero(~self._needs_reset)
        else:          # (DISABLED: AvoidVectorEnv.step refused a step of an ended episode)
            resets, live = np.zeros(0, np.int64), np.arange(self.n)
        tasks = [self.tasks[i] for i in live]
        if live.size and self._arrays_for(live):
            self._step_arrays(live, tasks, np.asarray(actions)[live], out)
        elif live.size:
            if self.arrays is not None:
                self.arrays.flush(live)
            self._kept[live] = False
            cmds = {i: self.tasks[i].begin_step({self.robot: actions[i]}) for i in live}
            self._advance(live.tolist(), cmds)
            for i in live:
                o, r, te, tr, info = self.tasks[i].end_step()
                self._steps[i] += 1
                te = te[self.robot]
                tr = (self.max_episode_steps is not None
                      and self._steps[i] >= self.max_episode_steps)     # as TimeLimit
                out.put(i, o[self.robot], r[self.robot], te, tr, info[self.robot])
        for i in resets:
            o, info = self._reset_one(int(i), None)
            out.put(i, o, 0.0, False, False, info)
        self._needs_reset = out.term | out.trunc
        if self.autoreset_mode == AutoresetMode.SAME_STEP and self._needs_reset.any():
            self._reset_ended(out)
        return out.obs, out.rew, out.term, out.trunc, out.infos

    def _reset_ended(self, out: "Out") -> None:
        """Same-step autoreset, as Gymnasium's ``SyncVectorEnv`` does it: each env whose
        episode this step ended is reset at once; its last observation goes to
        ``infos["final_obs"]`` (an object array of single observations), its step's info to
        ``infos["final_info"]`` (batched, with masks), and the new episode's first
        observation and reset info take its row."""
        ended = np.flatnonzero(self._needs_reset)
        final_obs = np.full(self.n, None, dtype=object)
        final = Out(self.n, None)
        for i in ended.tolist():
            final_obs[i] = {k: a[i].copy() for k, a in out.obs.items()}
            final.put_info(i, out.info_of(i))
        for i in ended.tolist():
            o, info = self._reset_one(i, None)
            out.put(i, o, out.rew[i], out.term[i], out.trunc[i], info)
        mask = np.zeros(self.n, np.bool_)
        mask[ended] = True
        out.infos.update({"final_obs": final_obs, "_final_obs": mask,
                          "final_info": final.infos, "_final_info": mask.copy()})
        self._needs_reset[:] = False

    def _arrays_for(self, live: np.ndarray) -> bool:
        """Whether the ``live`` envs step as arrays (ArrayTicks.eligible, asked of an env's
        task once after each of its resets: nothing else changes its world's make-up)."""
        if self.arrays is None:
            return False
        unknown = live[~self._eligible[live]]
        if unknown.size:
            if not self.arrays.eligible([self.tasks[i] for i in unknown]):
                return False
            self._eligible[unknown] = True
        return True

    def _step_arrays(self, live: np.ndarray, tasks: list[AvoidTask], actions: np.ndarray,
                     out: "Out") -> None:
        """The live envs' step as arrays (:mod:`diffbot.envs.kinbatch`): each task's
        ``begin_step``, ticks and ``end_step`` for all at once, the same numbers."""
        robot, first = self.robot, tasks[0]
        twists = first.drives[robot].commands(actions)
        before = self._dist[live]                  # where the last step left each robot
        fresh = ~self._kept[live]
        for j in np.flatnonzero(fresh).tolist():
            before[j] = tasks[j]._distance(robot)
        made = self.arrays.advance(tasks, twists, live, fresh)
        contact = first.geo.touching(footprint_centres(*made.truth.T))
        goals = np.array([t.goals[robot] for t in tasks], float).reshape(-1, 2)
        # AvoidTask._distance of each, by the truth advance left
        d = np.array([math.hypot(gx - x, gy - y) for (gx, gy), (x, y, _)
                      in zip(goals.tolist(), made.truth.tolist())])
        self._dist[live], self._kept[live] = d, True
        success = d < first.goal_radius
        rew = step_rewards(before, d, success, contact)
        term = success | contact
        self._steps[live] += 1
        trunc = (np.zeros(live.size, bool) if self.max_episode_steps is None
                 else self._steps[live] >= self.max_episode_steps)        # as TimeLimit
        for t, hit, ended in zip(tasks, contact.tolist(), term.tolist()):
            t.steps += 1
            t.touched = {robot} if hit else set()
            if ended:
                t.active.discard(robot)
        out.put_rows(live, made.obs, rew, term, trunc, {
            "pose": made.truth, "goal": goals, "distance": d,
            "is_success": success & ~contact, "contact": contact, "t": made.t_ns * 1e-9,
            "plant": [t.episode for t in tasks]})

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
            self._judge(ended)

    @staticmethod
    def _judge(ended: list[AvoidTask]) -> None:
        """The contacts of the worlds whose step ended, all in one call."""
        if ended:
            geo = ended[0].geo
            for task, touched in zip(ended, geo.contacts_of([t.centres() for t in ended])):
                task.touched = touched

    def sync(self) -> list[AvoidTask]:
        """The tasks, their objects brought up to date with the array steps' state (which
        writes it back only when asked: :meth:`ArrayTicks.flush`)."""
        if self.arrays is not None:
            self.arrays.flush()
        return self.tasks

    def render(self) -> list:
        return [t.render() for t in self.sync()]

    def close(self) -> None:
        for t in self.tasks:
            t.close()
        self.tasks = []


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
        if threads is None:       # the CPUs this process may use, shared among the processes
            threads = 1 if engine == "ray" else max(1, cpus() // int(workers))
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
