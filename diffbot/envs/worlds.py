"""A chunk of the batched Avoid env: :class:`Worlds`, ``n`` envs stepped together, in the
process of :class:`diffbot.envs.vector.AvoidVectorEnv` or of one of its workers
(:mod:`diffbot.envs.workers`, :mod:`diffbot.envs.ray_workers`); the batch's design is
:mod:`diffbot.envs.vector`'s docstring.
"""
from __future__ import annotations

import math

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode

from bus.controller import Twist
from plant.footprint import footprint_centres
from plant.tick import messages_of, step_ticks

from .avoid import AvoidTask, step_rewards
from .episode import next_seed
from .kinbatch import ArrayTicks
from .results import Out


class Worlds:
    """``n`` envs of a batch (a contiguous chunk of it): their tasks, episodes and stepping
    (:mod:`diffbot.envs.vector`'s docstring), in this process or in a worker's
    (:func:`diffbot.envs.workers._serve`). Each call
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
        self.kinematic = self.tasks[0].transport.spec.mode == "kinematic"
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
        #: each env's goal (x, y) in the world and its episode, as its last reset drew them
        self._goals = np.zeros((self.n, 2))
        self._episodes = np.full(self.n, None, dtype=object)

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
        self._goals[i] = task.goals[self.robot]
        self._episodes[i] = task.episode
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
        if live.size and self._arrays_for(live):
            self._step_arrays(live, np.asarray(actions), out, resets)
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

    def _step_arrays(self, live: np.ndarray, actions: np.ndarray, out: "Out",
                     resets: np.ndarray) -> None:
        """The live envs' step as arrays (:mod:`diffbot.envs.kinbatch`): each task's
        ``begin_step``, ticks and ``end_step`` for all at once, the same numbers.

        In a kinematic batch whose every env steps as arrays, the envs whose reset follows
        (``resets``: their episodes ended last step) step too, standing (a command of 0),
        their results dropped: so the batch steps the same rows each step and keeps its
        plan (a kinematic world restarts in place, :meth:`ArrayTicks.advance` reads its new
        episode in). Nothing of theirs outlives the reset: it restarts the world (the
        robot's arrays these ticks moved), its sensors, observer and odometry, and the
        task's episode."""
        robot = self.robot
        rows, on = live, None
        if resets.size and self._eligible.all() and self.kinematic:
            rows, on = np.arange(self.n), ~self._needs_reset
        tasks = [self.tasks[i] for i in rows.tolist()]
        first = tasks[0]
        acts = np.asarray(actions, np.float32)[rows]
        if on is not None:
            acts[~on] = 0.0                        # (an ended env's action is ignored)
        twists = first.drives[robot].commands(acts)
        before = self._dist[rows]                  # where the last step left each robot
        fresh = ~self._kept[rows]
        for j in np.flatnonzero(fresh).tolist():
            before[j] = tasks[j]._distance(robot)
        made = self.arrays.advance(tasks, twists, rows, fresh)
        truth, obs, t_ns = made.truth, made.obs, made.t_ns
        if on is not None:                         # (the live envs' results only)
            tasks = [t for t, o in zip(tasks, on.tolist()) if o]
            truth, t_ns, before = truth[on], t_ns[on], before[on]
            obs = {key: a[on] for key, a in obs.items()}
        contact = first.geo.touching(footprint_centres(*truth.T))
        goals = self._goals[live]
        # AvoidTask._distance of each (math.hypot: numpy's differs in the last bit)
        d = np.array(list(map(math.hypot, (goals[:, 0] - truth[:, 0]).tolist(),
                              (goals[:, 1] - truth[:, 1]).tolist())))
        self._dist[live], self._kept[rows] = d, True
        success = d < first.goal_radius
        rew = step_rewards(before, d, success, contact)
        term = success | contact
        self._steps[live] += 1
        trunc = (np.zeros(live.size, bool) if self.max_episode_steps is None
                 else self._steps[live] >= self.max_episode_steps)        # as TimeLimit
        for t in tasks:
            t.steps += 1
            if t.touched:
                t.touched = set()
        for j in np.flatnonzero(contact).tolist():
            tasks[j].touched = {robot}
        for j in np.flatnonzero(term).tolist():
            tasks[j].active.discard(robot)
        out.put_rows(live, obs, rew, term, trunc, {
            "pose": truth, "goal": goals, "distance": d,
            "is_success": success & ~contact, "contact": contact, "t": t_ns * 1e-9,
            "plant": self._episodes[live]})

    def _advance(self, live: list[int], cmds: dict) -> None:
        """Every live env's ``action_repeat`` ticks (:func:`advance_together`)."""
        advance_together([self.tasks[i] for i in live], [cmds[i] for i in live])

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


def advance_together(tasks: list[AvoidTask], cmds: list[dict]) -> None:
    """In-process tasks' ``action_repeat`` ticks (their :meth:`AvoidTask.begin_step` done,
    ``cmds[k]`` task k's commands, {robot: (v, w)}: a robot without one stands still), tick
    by tick across their worlds: each world's commands, the step of all
    (:func:`plant.tick.step_ticks`), every world's messages (:func:`plant.tick.messages_of`)
    and each task's observation of them; at the last tick the contacts of every world in
    one call. Per world exactly :meth:`diffbot.envs.transport.InProc.advance`."""
    if not tasks:
        return
    transports = [t.transport for t in tasks]
    ticks = [tr.tick for tr in transports]
    for _ in range(tasks[0].action_repeat):
        for c, tick in zip(cmds, ticks):
            for name in tick.sim.robots:
                tick.drive(name, Twist(*c.get(name, (0.0, 0.0))))
        step_ticks(ticks)
        wanted = [tr.wanted for tr in transports]
        ended = []
        for task, tr, msgs in zip(tasks, transports, messages_of(ticks, wanted)):
            tr.take(msgs)
            if task._observe(tr.tick.t_ns, tr.latest, judge=False):
                ended.append(task)
        if ended:                    # the contacts of the worlds whose step ended
            geo = ended[0].geo
            for task, touched in zip(ended, geo.contacts_of([t.centres() for t in ended])):
                task.touched = touched
