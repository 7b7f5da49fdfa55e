"""The swarm's vector env stepped as arrays: every robot of every world in one set of arrays.

:class:`SwarmArrays` is to :class:`diffbot.envs.swarm_vector.SwarmVectorEnv` what
:class:`diffbot.envs.kinbatch.ArrayTicks` is to the batched Avoid env, and it is that same
code: each robot of each world is a row of an :class:`ArrayTicks` of N robots a world
(world after world, each world's robots in order, as :func:`plant.kinematic.join` lays
out their kinematic arrays), whose calls of plant/kernels/ticks.c tick them all (drive
limiters, motion noise, the kinematic step with its robot-robot test inside each world,
encoders and their noise, dead reckoning; a DART world's robots in the two halves of each
tick, DART stepping each world once between them), whose lidars are cast where due (each
world's scene with its robots where the tick left them, a lidar skipping its own robot,
every world in one call, as :func:`plant.tick.messages_of` casts them) with the plant's
noise kernel, and whose observations and ground truth are :mod:`diffbot.envs.obsmath`'s.
The rewards, flags and infos of all robots are then made here at once
(:func:`diffbot.envs.avoid.step_rewards`, the contacts of all worlds at once:
:func:`contacts`).
No message is built: the numbers are to the bit those of the message path
(:func:`diffbot.envs.worlds.advance_together`, then each task's ``end_step``;
``tests/envs/test_swarm_arrays.py`` runs both side by side).

Which worlds (:meth:`SwarmArrays.eligible`): worlds in this process (kinematic, or DART
without a physics process), every robot with a lidar and no camera, every robot the same
drive limits, motion noise and lidar (the ``robot=`` of
:func:`plant.swarm_world.swarm_world_text` gives them that); the others take the message
path, as does ``SwarmVectorEnv(arrays=False)``. Between steps the state stays in
the core's data (:attr:`ArrayTicks.data`: a :class:`plant.core.data.Data` of the W worlds of
N robots, (W, N, ...) arrays); :meth:`SwarmArrays.flush` writes it back to the tasks'
objects (before a reset, ``state()``, ``render()``). A world that diverges is an error
here (FloatingPointError).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from plant.footprint import CONTACT_MARGIN_M, FOOTPRINT_RADIUS_M, footprint_centres

from .avoid import step_rewards
from .kinbatch import ArrayTicks
from .transport import InProc


class SwarmArrays:
    """``w`` swarm worlds of ``names`` (their robots, in order) as rows of one
    :class:`ArrayTicks` (module docstring)."""

    def __init__(self, w: int, names: Sequence[str], threads: int = 1) -> None:
        self.w, self.names = int(w), list(names)
        self.n = len(self.names)
        self.ticks = ArrayTicks(self.w * self.n, threads, robots=self.n)
        #: per world, until its next reset: ``eligible``'s answer was asked (``_asked``) and
        #: yes (``_ok``); its state is in the arrays (``_kept``), the robots' goal
        #: distances where its last step left them (``_dist``)
        self._asked = np.zeros(self.w, bool)
        self._ok = np.zeros(self.w, bool)
        self._kept = np.zeros(self.w, bool)
        self._dist = np.zeros((self.w, self.n))
        self._goals = np.zeros((self.w, self.n, 2))     # (read with the distances)
        self._cols = np.arange(self.n)

    @staticmethod
    def eligible(task) -> bool:
        """Whether ``task``'s world steps as arrays (module docstring)."""
        tr = task.transport
        if not isinstance(tr, InProc) or tr.tick is None or tr.tick.physics is not None:
            return False
        tick = tr.tick
        kin = tick.sim.kin                 # (the rows' order: the world's robots')
        if list(tick.sim.robots if kin is None else kin.names) != list(task.robots):
            return False
        robots = [task.spec.robot(n) for n in task.robots]
        first = robots[0]
        for r in robots:
            s = tick.sensors[r.name]
            if s.camera is not None or s.lidar is None or s.lidar != tick.sensors[first.name].lidar:
                return False
            if (r.drive != first.drive or s.periods != tick.sensors[first.name].periods
                    or task.drives[r.name].space != task.drives[first.name].space):
                return False
        return True

    def _rows(self, worlds: np.ndarray) -> np.ndarray:
        return (worlds[:, None] * self.n + self._cols).ravel()

    def flush(self, worlds: Sequence[int] | None = None) -> None:
        """The state of ``worlds`` (None: all) written back to their tasks' objects."""
        if worlds is None:
            self.ticks.flush()
        else:
            self.ticks.flush(self._rows(np.asarray(worlds, np.int64).reshape(-1)))

    def forget(self, i: int) -> None:
        """World ``i``'s objects up to date and its rows to be read again: before a reset."""
        self.flush([i])
        self._asked[i] = self._ok[i] = self._kept[i] = False

    def fits(self, tasks: Sequence, worlds: Sequence[int]) -> bool:
        """Whether every world of ``worlds`` (their ``tasks``) steps as arrays (asked of a
        world once after each of its resets: nothing else changes its make-up)."""
        for i, t in zip(worlds, tasks):
            if not self._asked[i]:
                self._ok[i], self._asked[i] = self.eligible(t), True
            if not self._ok[i]:
                return False
        return True

    def step(self, tasks: Sequence, worlds: Sequence[int], actions: np.ndarray,
             live: np.ndarray) -> tuple:
        """One step of ``worlds`` (their ``tasks``), ``actions`` (K, N, 2) each world's rows,
        ``live`` (K, N) bool the robots in their episode (the others stand still):
        (obs {key: (K, N, ...)}, rewards, terminated, truncated (K, N), infos
        {key: (K, N, ...)}, ``plant``: (K,)), what each task's ``end_step`` gives for its
        live robots, and each task's state (steps, contacts, active robots) as it leaves
        it."""
        at = np.asarray(worlds, np.int64)
        k, n, names = len(at), self.n, self.names
        first = tasks[0]
        twists = first.drives[names[0]].commands(actions.reshape(-1, 2)).reshape(k, n, 2)
        twists[~live] = 0.0                       # as advance_together drives them
        before = self._dist[at]
        for j in np.flatnonzero(~self._kept[at]).tolist():
            before[j] = [tasks[j]._distance(a) for a in names]
            self._goals[at[j]] = [tasks[j].goals[a] for a in names]
        try:
            made = self.ticks.advance([t for t in tasks for _ in names], twists.reshape(-1, 2),
                                      self._rows(at), np.repeat(~self._kept[at], n), names * k)
        except FloatingPointError as e:
            bad = sorted({r // n for r in getattr(e, "rows", ())})
            raise FloatingPointError(
                f"swarm world {', '.join(map(str, bad))} diverged (not finite) in this step: "
                "reset it (reset(options={'reset_mask': ...}))") from None
        truth = made.truth
        centres = footprint_centres(*truth.T).reshape(k, n, 2)
        contact = contacts(first.geo, centres)
        goals = self._goals[at]
        flat = goals.reshape(-1, 2)
        # AvoidTask._distance of each robot, by the truth the step left (math.hypot's bits)
        d = np.array(list(map(math.hypot, (flat[:, 0] - truth[:, 0]).tolist(),
                              (flat[:, 1] - truth[:, 1]).tolist()))).reshape(k, n)
        self._dist[at], self._kept[at] = d, True
        success = d < first.goal_radius
        rew = step_rewards(before, d, success, contact)
        term = success | contact
        steps = np.empty(k, np.int64)
        for j, (t, hit) in enumerate(zip(tasks, contact.tolist())):
            t.steps += 1
            steps[j] = t.steps
            t.touched = {a for a, h in zip(names, hit) if h}
        trunc = (np.zeros((k, n), bool) if first.max_steps is None
                 else ~term & (steps >= first.max_steps)[:, None])
        for t, ended in zip(tasks, (live & (term | trunc)).tolist()):
            for a, e in zip(names, ended):
                if e:
                    t.active.discard(a)
        obs = {key: a.reshape(k, n, *a.shape[1:]) for key, a in made.obs.items()}
        infos = {"pose": truth.reshape(k, n, 3), "goal": goals, "distance": d,
                 "is_success": success & ~contact, "contact": contact,
                 "t": made.t_ns.reshape(k, n) * 1e-9,
                 "plant": [t.episode for t in tasks]}
        return obs, rew, term, trunc, infos


def contacts(geo, centres: np.ndarray) -> np.ndarray:
    """:meth:`diffbot.envs.geometry.Footprints.contacts_of` of K worlds' N robots at the
    footprint centres ``centres`` (K, N, 2), as (K, N) bool: the static test of all in one
    call, the robots' distances in each world as arrays (``np.hypot`` of each pair's
    difference, the same bits)."""
    k, n, _ = centres.shape
    hit = geo.touching(centres.reshape(-1, 2)).reshape(k, n)
    if n > 1:
        diff = centres[:, :, None, :] - centres[:, None, :, :]
        near = np.hypot(diff[..., 0], diff[..., 1]) < 2 * FOOTPRINT_RADIUS_M + CONTACT_MARGIN_M
        near[:, np.arange(n), np.arange(n)] = False
        hit |= near.any(2)
    return hit
