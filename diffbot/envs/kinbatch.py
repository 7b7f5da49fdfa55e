"""One-robot Avoid worlds ticked as arrays: the batch's fast path, and the single env's.

:class:`ArrayTicks` steps every world of a batch at once when each is in this process (no
physics process) with one robot, a lidar and no camera, each to the bit what the message
path gives (:func:`plant.tick.messages_of`, then :meth:`diffbot.envs.avoid.AvoidTask._observe`;
``tests/envs/test_envs_vector.py`` runs both side by side). A step's ticks are calls of
plant/kernels/ticks.c (:class:`_TickPlan`), which does what the plant's tick does, in its
order: the commands through the drive limiter with the motion noise (the plant's own kernel,
plant/kernels/drive.c's plant_drive_commands), the step, the
encoders with their noise (sense.c's noise law) and the dead reckoning; a kinematic world's
ticks in one call up to where a lidar comes due, a DART world's in two halves, DART stepping
between them. The lidars due are cast together, and their noise is the plant's kernel's
(plant/kernels/sense.c's plant_lidar_noise: a reading is a function of its key and tick),
every world's drawn at its own tick, with the observation's clip, in one call of ticks.c.
Every noise here is the core's code, drawn in C. The batch's state is the core's: a
:class:`plant.core.model.Model` of its W worlds (each robot's drive limits, motion noise std,
noise laws, lidar period) and their :class:`plant.core.data.Data` (every robot's limiter,
commands, targets, noise keys and dead reckoning, every world's steps, time and tick, as
(W, R, ...) arrays), which ticks.c steps in place and reads from between steps; what only
the environment keeps (each row's objects to write back to, the observers' scans, the
ground truth) is :mod:`diffbot.envs.writeback`'s. The observation and the ground truth are
:mod:`diffbot.envs.obsmath`'s. A world that diverges is an error here (FloatingPointError),
where the message path rebuilds it at t = 0. A world of several robots (a swarm's,
:mod:`diffbot.envs.swarm_arrays`) is a row per robot, its robots in order: the kinematic
step tests them against each other, a DART world is stepped once a tick, and their lidars
see each other (:meth:`_TickPlan._cast_worlds`).
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from plant import kernels, kinematic
from plant import lidar as lid
from plant.core.data import Data
from plant.core.model import Model
from plant.raycast import Scene

from .batchworlds import Dart, Diverged, Kinematic
from .obsmath import observation
from .transport import InProc
from .writeback import WriteBack


class Made(NamedTuple):
    """A batch step's observations ({key: (W, ...)}, :meth:`AvoidObserver.observation`'s),
    the robots' true (x, y, yaw) (W, 3) and the worlds' times (W,) ns at its end."""
    obs: dict
    truth: np.ndarray
    t_ns: np.ndarray


#: the core's data a row of the batch has (a robot of a world), as ticks.c reads it:
#: (group of :class:`~plant.core.data.Data`, its array)
_ROW_DATA = {"lim_v": ("drive", "v"), "lim_w": ("drive", "w"), "wheels": ("drive", "wheels"),
             "kind": ("drive", "kind"), "cmd": ("drive", "cmd"),
             "targets": ("drive", "targets"), "motion_keys": ("drive", "keys"),
             "pose": ("odometry", "pose"), "vel": ("odometry", "vel"),
             "last": ("odometry", "last"), "last_t": ("odometry", "last_t"),
             "r": ("odometry", "r"), "d": ("odometry", "d"),
             "enc_keys": ("keys", "encoders"), "lid_keys": ("keys", "lidar")}
#: a row's arrays a step changes (a plan's copies written back: :meth:`_TickPlan.step`),
#: the observers' scans among them (:class:`~.writeback.WriteBack`'s), and a world's
_STEPPED = ("lim_v", "lim_w", "wheels", "kind", "cmd", "targets", "pose", "vel", "last",
            "last_t", "scans")
_CLOCKS = ("steps", "t_ns", "tick")


class ArrayTicks:
    """The fast path for a batch of ``n`` rows (module docstring), a robot each: ``robots``
    robots a world, world after world (one: the Avoid envs); :meth:`eligible` says when.
    Its lidars are cast on up to ``threads`` threads (:func:`plant.lidar.scan_many`: the
    same bits whatever their number). Its state is :attr:`data` of :attr:`model` (made
    when the first tasks are read: the batch's worlds are copies of their world)."""

    def __init__(self, n: int, threads: int = 1, robots: int = 1) -> None:
        self.threads, self.robots = int(threads), int(robots)
        if n % self.robots:
            raise ValueError(f"{n} rows are not worlds of {self.robots} robots")
        self.model: Model | None = None
        self.data: Data | None = None
        self._back = WriteBack(n, self.robots)  # each row's objects, from step to step
        self._scene: Scene | None = None
        self._scene_of = None
        self._plan: _TickPlan | None = None     # the last step's calls, kept

    @staticmethod
    def eligible(tasks: Sequence) -> bool:
        """One-robot worlds in this process (kinematic, or DART without a physics process),
        no camera, every world the same spec (a batch's are: one world file, one set of
        overrides)."""
        for t in tasks:
            tr = t.transport
            if not isinstance(tr, InProc) or tr.tick is None or len(t.robots) != 1:
                return False
            tick = tr.tick
            if tick.physics is not None:
                return False
            s = tick.sensors[t.robots[0]]
            if s.camera is not None or s.lidar is None:
                return False
        return True

    def _static_scene(self, sim) -> Scene:
        """The room without its robot (:meth:`plant.sim.Simulation.room_scene`), one for
        the batch: every world of the batch has the same room."""
        if self._scene is None or self._scene_of != sim.spec.name:
            self._scene = sim.room_scene()
            self._scene_of = sim.spec.name
        return self._scene

    def flush(self, rows: np.ndarray | None = None) -> None:
        """Rows ``rows``' (None: every row's) objects brought up to date with the state the
        steps left in the core's data (:class:`~.writeback.WriteBack`): to be called before
        anything reads or changes a task's objects (its observer, odometry, limiter, world,
        truth, scans)."""
        k = self._back
        k.flush(np.flatnonzero(k.dirty) if rows is None else np.asarray(rows, np.int64))

    def bind(self, spec) -> None:
        """The batch's model (its worlds copies of ``spec``'s) and data, laid out for ticks.c
        (the data's arrays as a row per robot: :meth:`plant.core.data.Data.flat`)."""
        k = self._back
        self.model = model = Model([spec] * (k.n // self.robots))
        if model.robots != tuple(r.name for r in spec.robots) or len(model.robots) != self.robots:
            raise ValueError(f"a batch of {self.robots}-robot worlds got world "
                             f"{spec.name!r} of {len(model.robots)}")
        self.data = data = Data(model)
        flat = {g: data.flat(getattr(data, g)) for g in ("drive", "odometry", "keys")}
        k.bind({f: flat[g][a] for f, (g, a) in _ROW_DATA.items()},
               {f: getattr(data, f) for f in _CLOCKS})
        self._made_of = _make_up(spec)

    def _read(self, at: np.ndarray, tasks: Sequence, names: Sequence | None) -> None:
        """Rows ``at`` read from ``tasks``' objects (:meth:`WriteBack.read`), the model made
        at the first; every world a copy of the model's (its robots, their drive and sensors)."""
        if self.model is None:
            self.bind(tasks[0].spec)
        for t in {id(t): t for t in tasks}.values():       # (a world's task once)
            if _make_up(t.spec) != self._made_of:
                raise ValueError("a batch's worlds differ in their robots (their drive or "
                                 "sensors): one spec expected")
        self._back.read(at, tasks, names)

    def advance(self, tasks: Sequence, cmds: np.ndarray, rows: np.ndarray,
                fresh: np.ndarray, names: Sequence | None = None) -> Made:
        """``action_repeat`` ticks of every task in ``tasks`` with its command (``cmds``,
        (W, 2): v m/s, w rad/s each), each task's state left as its own ``_observe`` at the
        step's last tick leaves it (its contacts not judged: the caller's, all at once).

        ``rows`` (W,) are the tasks' indices in the batch: each task's state is the core's
        data (:attr:`data`) from this step to its next, written back to the objects by
        :meth:`flush` (:class:`~.writeback.WriteBack`); ``fresh`` (W,) bool marks the tasks
        whose objects may have changed since their last step here (a reset, or no step
        yet; flushed before it): those are read again. ``names``: the robot of each row,
        when a world has several (:mod:`diffbot.envs.swarm_arrays`: ``tasks`` then holds a
        world's task once per robot, its robots in order, as the kinematic batch lays them
        out)."""
        k, at = self._back, np.asarray(rows, np.int64)
        stale = np.flatnonzero(fresh)
        if stale.size:
            if k.dirty[at[stale]].any():
                raise RuntimeError("an env's objects were changed before its state was "
                                   "written back (ArrayTicks.flush)")
            self._read(at[stale], [tasks[j] for j in stale.tolist()],
                       None if names is None else [names[j] for j in stale.tolist()])
        plan = self._plan
        if plan is None or not plan.fits(at) or (stale.size and not plan.refresh(self, stale)):
            self._plan = plan = _TickPlan(self, at, tasks[0].action_repeat)
        return plan.step(self, cmds)


def _make_up(spec) -> tuple:
    """What the batch's model takes of a world's robots: their names, drives and sensors
    (not their start poses, which an episode's reset draws)."""
    return tuple((r.name, r.drive, r.sensors) for r in spec.robots)


#: plant/kernels/ticks.c's slots (its enums), in order
_SLOTS = ("v w lim_wheels kind cmd targets limits std keys tick "
          "radius separation world pose wheels speeds vel pairs "
          "nbox box_c box_cos box_sin box_half ncirc circ_c circ_r half "
          "enc_keys enc_laws "
          "odo_pose odo_vel last last_t odo_r odo_d pos t "
          "steps t_ns due sub step_ns tick_ns period "
          "lid_keys lid_laws lid_work raw scans new_scan rays robots").split()
_PARAMS = "tick_s foot_r centre_x lid_lo lid_hi lid_q scan_max".split()


class _TickPlan:
    """An Avoid step of rows ``at`` of the batch (whole worlds, in order): its ticks in calls
    of plant/kernels/ticks.c (a kinematic world's whole ticks; a DART world's two halves of
    each tick, DART stepping it between them), the lidars cast where due between them,
    with everything the calls read laid out once: the rows' and worlds' state (views of the
    core's data when ``at`` is a run of rows, else copies written back each step), the
    model's drive limits and noise laws, the addresses. Kept from step to step while the
    same worlds step (:meth:`fits`); a kinematic world reset since is read again in place
    (:meth:`refresh`), a DART world's reset makes a new plan."""

    def __init__(self, owner: ArrayTicks, at: np.ndarray, repeat: int) -> None:
        k, R = owner._back, owner.robots
        self.at, self.repeat = at.copy(), int(repeat)
        w = len(at)
        self.R, self.wat = R, at[::R] // R            # (each world's index in the data)
        if not np.array_equal(at, (self.wat[:, None] * R + np.arange(R)).ravel()):
            raise ValueError("a batch steps whole worlds, their robots in order")
        roster = [k.roster[i] for i in at.tolist()]
        ticks, names, sensors, sims, obs = (list(c) for c in zip(*[r[:5] for r in roster]))
        self.sims = sims
        self.kinematic = sims[0].kin is not None
        #: rows of worlds with several robots (a swarm's): each row's world among them
        worlds = {id(s): k for k, s in reversed(list(enumerate(sims)))}
        self.shared = len(worlds) < len(sims)
        if self.shared:
            self.names = names
            self.world_of = np.array([worlds[id(s)] for s in sims], np.int64)
        self.worlds = Kinematic(sims) if self.kinematic else Dart(sims, names)
        lo = int(at[0])
        self.run = bool(np.array_equal(at, np.arange(lo, lo + w)))
        self.rows = slice(lo, lo + w) if self.run else at      # (a slice: views)
        self.worlds_at = slice(lo // R, (lo + w) // R) if self.run else self.wat
        self.state: dict[str, np.ndarray] = {}
        self._gather(k, self.state)
        #: the calls' scratch: the encoders' readings and their time, each world's lidars due
        self.pos, self.t = np.zeros((w, 2)), np.zeros(w)
        self.due = np.zeros(len(self.wat), np.int64)
        self.cfg = cfg = sensors[0].lidar
        self.raw = np.zeros((w, cfg.num_rays), np.float32)
        self.new_scan = np.zeros(w, bool)
        self.goal = np.array([o.goal for o in obs], float).reshape(w, 2)
        self.max_range = obs[0].max_range
        self.sub = sims[0].spec.substeps
        self.tick_ns = ticks[0].tick_ns
        self.wheels = np.zeros((w, 2))        # a DART world's wheel angles, each tick
        self._lid_work = np.zeros(cfg.num_rays)   # (the lidar noise's scratch)
        self._lay_out(owner.model, sims[0].spec)
        self._addr = (kernels.ptr(self.slots), kernels.ptr(self.params))
        self._key = self.at.tobytes()
        self._first_kin = sims[0].kin
        self.fans: lid.Fans | None = None                  # the lidars' casts (_scan)
        self.scenes: lid.WorldScenes | None = None         # several robots' worlds' casts
        self._base = np.zeros((1, 4, 4))                   # one robot's pose (_transforms)
        self._base[0, 2, 2], self._base[0, 3, 3] = 1.0, 1.0
        if self.kinematic:
            self._base[0, 2, 3] = float(self.worlds.batch.radius[0])

    def refresh(self, owner: ArrayTicks, stale: np.ndarray) -> bool:
        """Rows ``stale`` (indices in :attr:`at`) read again after their worlds' reset, in
        place: a kinematic world restarts in place (:meth:`plant.sim.Simulation.restart`:
        the same objects and arrays), so only its noise streams, goal and state are new
        (the state read by :meth:`WriteBack.read` already). False when the plan cannot keep
        them (a DART world is built anew): the plan is made again."""
        if not self.kinematic:
            return False
        k, batch = owner._back, self.worlds.batch
        roster = [k.roster[i] for i in self.at[stale].tolist()]
        if any(r[3] is not self.sims[j] or (r[3].kin.batch or r[3].kin) is not batch
               for j, r in zip(stale.tolist(), roster)):
            return False
        obs = [r[4] for r in roster]
        self.goal[stale] = np.array([o.goal for o in obs], float).reshape(-1, 2)
        if not self.run:                       # (the state's copies: WriteBack.read's rows)
            got: dict[str, np.ndarray] = {}
            self._gather(k, got)
            worlds = np.unique(stale // self.R)
            for f, a in got.items():
                self.state[f][worlds if f in _CLOCKS else stale] = a[
                    worlds if f in _CLOCKS else stale]    # (in place: the addresses stay)
        return True

    def _gather(self, back: WriteBack, into: dict) -> None:
        """The plan's rows' and worlds' state from the core's data (views when the rows are
        a run, else copies)."""
        for f, a in back.rows.items():
            into[f] = a[self.rows]
        for f, a in back.clocks.items():
            into[f] = a[self.worlds_at]

    def put_back(self, back: WriteBack) -> None:
        """A step's copies (rows not a run) written back to the core's data."""
        if not self.run:
            for f in _STEPPED:
                back.rows[f][self.rows] = self.state[f]
            for f in _CLOCKS:
                back.clocks[f][self.wat] = self.state[f]

    def _lay_out(self, model: Model, sim_spec) -> None:
        """The addresses of every block plant/kernels/ticks.c reads (its slots, in
        :data:`_SLOTS`' order) and its parameters (:data:`_PARAMS`): the state's, the
        ``model``'s (a robot's drive limits, motion noise std, noise laws, lidar period),
        ``sim_spec`` the world's (its physics step)."""
        st = self.state
        dt = sim_spec.control_tick_s
        if self.kinematic:
            robots, pairs = kinematic.kernel_state(self.worlds.batch)
            statics = self.worlds.batch.foot.kernel_args()
            tick_s = self.worlds.batch.tick_s
        else:
            robots = (0, 0, 0, 0, self.wheels, 0, 0)      # (what ticks.c's after reads)
            statics, pairs, tick_s = (0,) * 9, False, dt
        # the model's per robot (R, ...): plant_drive_commands' limits and std, the noise
        # laws (a law of zeros leaves a value as it is: plant_noise_values); the owner keeps
        # the model, so their addresses stay
        periods = model.periods["scan"]
        assert (periods == periods[0]).all() and self.cmd.dtype == np.float64
        slots = {
            "v": st["lim_v"], "w": st["lim_w"], "lim_wheels": st["wheels"],
            "kind": st["kind"], "cmd": self.cmd, "targets": st["targets"],
            "limits": model.drive_limits, "std": model.motion_std, "keys": st["motion_keys"],
            "tick": st["tick"],
            "pairs": int(pairs), "enc_keys": st["enc_keys"], "enc_laws": model.noise["encoders"],
            "odo_pose": st["pose"], "odo_vel": st["vel"], "last": st["last"],
            "last_t": st["last_t"], "odo_r": st["r"], "odo_d": st["d"], "pos": self.pos,
            "t": self.t, "steps": st["steps"], "t_ns": st["t_ns"], "due": self.due,
            "sub": sim_spec.substeps, "step_ns": int(round(sim_spec.physics_step_s * 1e9)),
            "tick_ns": self.tick_ns, "period": int(periods[0]),
            "lid_keys": st["lid_keys"], "lid_laws": model.noise["lidar"],
            "lid_work": self._lid_work, "raw": self.raw, "scans": st["scans"],
            "new_scan": self.new_scan.view(np.uint8), "rays": self.cfg.num_rays,
            "robots": self.R}
        assert st["scans"].dtype == np.float32 and self.raw.dtype == np.float32
        slots.update(zip(_SLOTS[_SLOTS.index("radius"):], robots))
        slots.update(zip(_SLOTS[_SLOTS.index("nbox"):], statics))
        self.slots = np.array([kernels.ptr(slots[n]) for n in _SLOTS], np.int64)
        cfg = self.cfg
        params = {"tick_s": tick_s, "foot_r": kinematic.FOOTPRINT_RADIUS_M,
                  "centre_x": kinematic.CHASSIS_CENTRE_X_M, "lid_lo": cfg.min_range_m,
                  "lid_hi": cfg.max_range_m, "lid_q": cfg.resolution_m,
                  "scan_max": self.max_range}
        self.params = np.array([params[n] for n in _PARAMS], float)
        if kernels.library().plant_ticks_count() != len(_SLOTS) * 1000 + len(_PARAMS):
            raise kernels.KernelsMissing("plant/kernels/ticks.c's blocks are not the ones "
                                         "diffbot/envs/kinbatch.py lays out: rebuild the "
                                         "kernels (make setup)")

    def _transforms(self) -> np.ndarray:
        """Every row's robot base -> world (W, 4, 4) (one kinematic robot: in Python floats,
        as :meth:`plant.sim.Simulation.kin_state` makes it)."""
        if not self.kinematic:
            return self.worlds.transforms(np.arange(len(self.at)))
        kin = self.worlds.batch
        if len(kin.pose) != 1:
            return kin.transforms()
        x, y, yaw = kin.pose[0].tolist()
        c, s = math.cos(yaw), math.sin(yaw)
        tf = self._base[0]
        tf[0, 0], tf[0, 1], tf[0, 3] = c, -s, x
        tf[1, 0], tf[1, 1], tf[1, 3] = s, c, y
        return self._base

    def fits(self, at: np.ndarray) -> bool:
        """Whether this plan steps rows ``at`` (none of them reset since it was made)."""
        return ((not self.kinematic
                 or (self._first_kin.batch or self._first_kin) is self.worlds.batch)
                and len(at) == len(self.at) and at.tobytes() == self._key)

    @property
    def cmd(self) -> np.ndarray:
        """The rows' commands (n, 2) as plant_drive_commands reads them (the data's)."""
        return self.state["cmd"]

    def step(self, owner: ArrayTicks, cmds: np.ndarray) -> Made:
        """:meth:`ArrayTicks.advance` of the plan's rows with ``cmds`` (W, 2)."""
        st, w = self.state, len(self.at)
        st["cmd"][:] = cmds                     # (clamped to the limits by the kernel)
        self.new_scan[:] = False
        if self.kinematic:
            done = 0
            while done < self.repeat:
                done += kernels.ticks(w, self.repeat - done, *self._addr)
                if self.due.any():
                    self._scan(owner, np.flatnonzero(self.due))
        else:
            worlds, targets = self.worlds, st["targets"]
            for _ in range(self.repeat):
                kernels.tick_part(w, 0, *self._addr)
                worlds.step(targets)
                worlds.read_wheels(self.wheels)
                if kernels.tick_part(w, 1, *self._addr):
                    self._scan(owner, np.flatnonzero(self.due))
        try:
            self.worlds.finish()
        except Diverged as e:
            envs = [int(self.at[j]) for j in e.worlds]
            err = FloatingPointError(
                f"the world of env {', '.join(map(str, envs))} diverged (not finite) in this "
                "step: reset() it (in-process a world that diverges ends the episode here; a "
                "plant over the bus rebuilds it at t = 0 and goes on)")
            err.rows = envs                    # (a swarm's caller names its worlds)
            raise err from None
        truth = self.worlds.truth()
        self.put_back(owner._back)
        owner._back.keep(self, truth)
        t_ns = st["t_ns"].copy() if self.R == 1 else np.repeat(st["t_ns"], self.R)
        return Made(observation(st["pose"], st["vel"], self.goal, st["scans"]), truth, t_ns)

    def _scan(self, owner: ArrayTicks, worlds: np.ndarray) -> None:
        """The lidars of the robots of ``worlds`` (indices in the plan's; the robots where
        the last tick left them)."""
        R = self.R
        due = worlds if R == 1 else (worlds[:, None] * R + np.arange(R)).ravel()
        exact = self._cast_worlds(due) if self.shared else self._cast(owner, due)
        # their noise, each at its world's tick, and the observation's clip: one kernel call
        kernels.ticks_scans(due, np.ascontiguousarray(exact, float), *self._addr)

    def _cast(self, owner: ArrayTicks, due: np.ndarray) -> np.ndarray:
        """The exact ranges of one-robot worlds' rows ``due`` (the room alone: a lidar skips
        its own robot)."""
        cfg, scene = self.cfg, owner._static_scene(self.sims[0])
        if self.fans is None or self.fans.scene is not scene:
            self.fans = lid.Fans(cfg, scene, len(self.at), owner.threads)
        if due.size == len(self.at):
            exact = self.fans.scan(self._transforms())
        else:
            exact = lid.scan_many(cfg, self.worlds.transforms(due), self.fans.scene,
                                  [None] * due.size, owner.threads)
        return exact

    def _cast_worlds(self, due: np.ndarray) -> np.ndarray:
        """The exact ranges of rows ``due`` in worlds of several robots, as
        :func:`plant.tick.messages_of` casts them: each world's scene with its robots where
        the last tick left them, a lidar skipping its own robot, every world in one call.
        The worlds' scenes are laid out once for the plan (:class:`plant.lidar.WorldScenes`):
        a cast writes the robots' parts in place (a kinematic batch's all in one matmul) and
        casts, the same bits as the worlds' scenes built afresh."""
        if self.scenes is None:
            self._lay_out_scenes()
        if self.kinematic:
            tfs = self.worlds.batch.transforms()
            self.scenes.move(np.matmul(tfs[self._part_robot], self._part_rel))
            return self.scenes.scan(tfs[due], due)
        self.scenes.move(np.concatenate([self.sims[k].part_transforms()
                                         for k in self._world_rows.tolist()]))
        return self.scenes.scan(self.worlds.transforms(due), due)

    def _lay_out_scenes(self) -> None:
        """:attr:`scenes`: every world's scene (:meth:`plant.sim.Simulation.scene_layout`),
        its robots' parts moving; in a kinematic batch, each part's row (its robot's) in the
        batch and its pose on that robot's base."""
        self._world_rows = firsts = np.unique(self.world_of)     # each world's first row
        layouts = [self.sims[k].scene_layout() for k in firsts.tolist()]
        self.scenes = lid.WorldScenes(self.cfg, [lay[0] for lay in layouts], self.names,
                                      np.searchsorted(firsts, self.world_of),
                                      [(lay[1], lay[2]) for lay in layouts])
        if self.kinematic:
            self._part_robot = np.concatenate([k + lay[3] for k, lay in
                                               zip(firsts.tolist(), layouts)])
            self._part_rel = np.concatenate([lay[4] for lay in layouts])
