"""One-robot Avoid worlds ticked as arrays (the batch's fast path, and the single env's).

:class:`diffbot.envs.worlds.Worlds` ticks its worlds through the plant's messages
(:func:`plant.tick.messages_of`, then each env's :meth:`diffbot.envs.avoid.AvoidTask._observe`
reads them; the tasks this module steps are :class:`~diffbot.envs.avoid.AvoidTask` s):
a hundred microseconds of Python per world and tick, most of it building and reading
message objects. When every world of the batch is in this process (no physics process)
with one robot and no camera, :class:`ArrayTicks` makes the same numbers for all of them
at once, each to the bit what the message path gives (``tests/envs/test_envs_vector.py`` runs
both side by side, noise on, in both world modes; ``tests/envs/test_envs_identity.py`` the
single env against a plant over the bus). :class:`diffbot.envs.avoid.AvoidEnv` steps its
one world the same way.

A step's ticks are calls of plant/kernels/ticks.c (:class:`_TickPlan`): in a kinematic
world all of a step's ticks in one call, stopping where a lidar comes due; a DART world's
ticks in two halves each, DART stepping it between them (:meth:`plant.sim.Simulation.step_tick`).
A tick is what the plant's tick does, in its order, to the bit:

- the commands: each world's :class:`plant.drive.DriveLimiter` and the motion noise of a
  robot that moves (:meth:`plant.sim.Simulation.command_twist`), plant/kernels/drive.c:
  the Python code's operations in its order with libm's ``sin`` and ``cos``, which are
  what ``math`` calls;
- the kinematic step (plant/kernels/kinematic.c, :mod:`plant.kinematic`), or DART's;
- encoders: the wheel angles plus the encoder noise of :class:`plant.noise.NoiseModel`;
  then the dead reckoning (:meth:`controllers.odometry.Odometry.update`, drive.c);
- lidar, where due: every robot due cast in one kernel call against the room without the
  robot (a one-robot world's lidar skips its own parts, so that is what it sees), then
  noise, clip and quantisation as :func:`plant.lidar.apply_noise`, all rows at once.

The noise is the plant's (:mod:`plant.noise`): each world's streams have their keys, a
reading is a function of the key and the tick, and the readings of every world are drawn
in one call of :func:`plant.noise.normals`: the command and encoder noise of a step's
ticks before its kernel calls (:class:`_Noise`), the lidar noise of the rows due with
:func:`plant.lidar.apply_noise` itself. After the ticks, in numpy for many worlds and in
Python floats for one (what the message path computes with):

- the observer: the scan as :meth:`controllers.learned.AvoidObserver.feed` keeps it, the
  observation as :meth:`AvoidObserver.observation` makes it (numpy 2.4's ``+ - * /``,
  ``sqrt``, ``sin``, ``cos``, ``%`` give Python's bits, which the oracle test would
  catch otherwise; ``atan2`` and ``hypot`` do not, so those are ``math``'s, robot by
  robot);
- the ground truth at the step's end, as the ``ground_truth`` message and
  :func:`bus.codec.pose_2d` give it (:func:`truths`).

A world that diverges (not finite) is an error here (FloatingPointError), where the
message path rebuilds it at t = 0 and goes on. What the env never reads is not made (the
GPS and its noise; the ground truth before a step's end). Between steps the batch
keeps each env's state as arrays (:class:`_Kept`: read from an env's objects once after
its reset), and writes it back to the env's observer, odometry, limiter, world and task
only when something is to read them (:meth:`ArrayTicks.flush`: a render, a reset, the
message path, :attr:`AvoidVectorEnv.tasks`, :attr:`AvoidEnv.task`), so rendering and
resets are the task's own code; the rewards, flags and ``info`` of all worlds are
:meth:`diffbot.envs.worlds.Worlds._step_arrays`'.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from bus.codec import yaw_of
from controllers.learned import GOAL_LIMIT_M, ODOM_HIGH, in_frame, wrap
from plant import kernels, kinematic
from plant import lidar as lid
from plant.noise import NoiseModel, normals
from plant.raycast import Scene
from plant.sim import rotation_to_quaternion

from .transport import InProc

class Made(NamedTuple):
    """A batch step's observations ({key: (W, ...)}, :meth:`AvoidObserver.observation`'s),
    the robots' true (x, y, yaw) (W, 3) and the worlds' times (W,) ns at its end."""
    obs: dict
    truth: np.ndarray
    t_ns: np.ndarray


class _Scan:
    """What a task keeps of its last scan for :meth:`AvoidTask.render`: the fields of the
    ``LaserScan`` message (:func:`bus.codec.laser_scan`) the view reads, with its values."""

    __slots__ = ("ranges", "range_max", "angle_min", "angle_increment")

    def __init__(self, ranges: np.ndarray, range_max: float, angle_min: float,
                 angle_increment: float) -> None:
        self.ranges = ranges
        self.range_max, self.angle_min, self.angle_increment = range_max, angle_min, angle_increment

    @staticmethod
    def fields(cfg) -> tuple[float, float, float]:
        """The message's fields of lidar ``cfg``: (range_max, angle_min, angle_increment)."""
        return float(cfg.max_range_m), float(cfg.angle_min), float(cfg.angle_increment)


class _Noise:
    """A noise of every world of a batch laid out for plant/kernels/ticks.c, which reads it
    in place: ``buf`` (W, ticks, 2) row j's readings of a step's ticks (the normals of its
    key at each tick, :func:`plant.noise.normals`, times ``std``), ``next`` (W,) the next
    tick's reading (the kernel advances it), ``live`` (W,) int64 the rows with a stream
    (all). ``lag``: the first reading's tick after the step's first (the encoders are read
    after each tick's step, at the next tick)."""

    def __init__(self, keys: np.ndarray, std: float, lag: int, ticks: int) -> None:
        w = len(keys)
        self.std, self.lag = float(std), int(lag)
        self.keys = np.repeat(keys, ticks)
        self.offsets = np.arange(ticks, dtype=np.int64) + self.lag
        self.buf = np.zeros((w, ticks, 2))
        self.next = np.zeros(w, np.int64)
        self.live = np.ones(w, np.int64)

    def draw(self, tick: np.ndarray) -> None:
        """The readings of the ticks from ``tick`` (W,) on, all rows in one call."""
        normals(self.keys, (tick[:, None] + self.offsets).reshape(-1), 2,
                out=self.buf.reshape(-1, 2))
        self.buf *= self.std
        self.next[:] = 0


def _keys(models: list) -> np.ndarray:
    """The keys (W,) of one sensor's noise models, a world each (a batch's worlds share a
    spec: all have one, or none)."""
    if any(m is None for m in models):
        raise ValueError("a batch's worlds differ in their sensor noise (one spec expected)")
    return np.array([m.key for m in models], np.uint64)


class ArrayTicks:
    """The fast path for a batch of ``n`` tasks (module docstring); :meth:`eligible` says
    when. Its lidars are cast on up to ``threads`` threads (:func:`plant.lidar.scan_many`:
    the same bits whatever their number)."""

    def __init__(self, n: int, threads: int = 1) -> None:
        self.threads = int(threads)
        self._kept = _Kept(n)                   # advance's rows, from step to step
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
        steps left in the arrays (:class:`_Kept`): to be called before anything reads or
        changes a task's objects (its observer, odometry, limiter, world, truth, scans)."""
        k = self._kept
        k.flush(np.flatnonzero(k.dirty) if rows is None else np.asarray(rows, np.int64))

    def advance(self, tasks: Sequence, cmds: np.ndarray, rows: np.ndarray,
                fresh: np.ndarray) -> Made:
        """``action_repeat`` ticks of every task in ``tasks`` with its command (``cmds``,
        (W, 2): v m/s, w rad/s each), each task's state left as its own ``_observe`` at the
        step's last tick leaves it (its contacts not judged: the caller's, all at once).

        ``rows`` (W,) are the tasks' indices in the batch: each task's objects and state
        are kept (:class:`_Kept`) from this step to its next, and written back to the
        objects by :meth:`flush`; ``fresh`` (W,) bool marks the tasks whose objects may
        have changed since their last step here (a reset, or no step yet; flushed before
        it): those are read again."""
        w = len(tasks)
        k, at = self._kept, np.asarray(rows, np.int64)
        stale = np.flatnonzero(fresh)
        if stale.size:
            if k.dirty[at[stale]].any():
                raise RuntimeError("an env's objects were changed before its state was "
                                   "written back (ArrayTicks.flush)")
            k.read(at[stale], [tasks[j] for j in stale.tolist()])
        plan = self._plan
        if plan is None or stale.size or not plan.fits(at):
            self._plan = plan = _TickPlan(self, at, tasks[0].action_repeat)
        return plan.step(self, cmds)


#: plant/kernels/ticks.c's slots (its enums), in order
_SLOTS = ("v w lim_wheels v_target w_target targets cmd_buf cmd_next cmd_live cmd_len "
          "radius separation world pose wheels speeds vel pairs "
          "nbox box_c box_cos box_sin box_half ncirc circ_c circ_r half "
          "enc_have enc_buf enc_next enc_live enc_len "
          "odo_pose odo_vel last last_t odo_r odo_d pos t "
          "steps t_ns due sub step_ns tick_ns period").split()
_PARAMS = "dv dw r d m a tick_s foot_r centre_x enc_offset enc_res".split()


class _TickPlan:
    """An Avoid step of one-robot worlds ``at`` (rows of the batch): its ticks in calls of
    plant/kernels/ticks.c (a kinematic world's whole ticks; a DART world's two halves of
    each tick, DART stepping it between them), the lidars cast where due between them,
    with everything the calls read laid out once: the rows' state (views of the
    :class:`_Kept` arrays when ``at`` is a run of rows, else copies written back each
    step), the noise's readings (:class:`_Noise`), the addresses. Kept from step to
    step while the same worlds step and none was reset since (:meth:`fits`)."""

    def __init__(self, owner: ArrayTicks, at: np.ndarray, repeat: int) -> None:
        k = owner._kept
        self.at, self.repeat = at.copy(), int(repeat)
        w = len(at)
        roster = [k.roster[i] for i in at.tolist()]
        ticks, names, sensors, sims, obs = (list(c) for c in zip(*[r[:5] for r in roster]))
        self.sims = sims
        self.kinematic = sims[0].kin is not None
        self.worlds = (_Kinematic if self.kinematic else _Dart)(ticks, sims, names)
        lo = int(at[0])
        self.run = bool(np.array_equal(at, np.arange(lo, lo + w)))
        self.rows = slice(lo, lo + w) if self.run else at      # (a slice: views)
        self.state = {f: getattr(k, f)[self.rows] for f in _Kept.STATE}
        st = self.state
        self.v_target, self.w_target = np.zeros(w), np.zeros(w)
        self.pos, self.t, self.due = np.zeros((w, 2)), np.zeros(w), np.zeros(w, np.int64)
        self.cfg = cfg = sensors[0].lidar
        self.raw = np.zeros((w, cfg.num_rays), np.float32)
        self.new_scan = np.zeros(w, bool)
        self.goal = np.array([o.goal for o in obs], float).reshape(w, 2)
        self.max_range = obs[0].max_range
        # the noise: commands, encoders (each step's readings for the kernel), lidar
        spec = sims[0].limiters[names[0]].spec
        self.limits = (spec.max_linear_mps, spec.max_angular_radps)
        std = sims[0].robots[names[0]].spec.sensors.command_noise_std_radps
        self.cmd = None if std <= 0.0 else _Noise(
            _keys([s.motion_noise[n] for s, n in zip(sims, names)]), std, 0,
            self.repeat)
        models = [s.enc_noise for s in sensors]
        have = [m is not None for m in models]
        enc_cfg = next((m.config for m in models if m is not None), None)
        self.enc = None if enc_cfg is None or enc_cfg.std <= 0 else _Noise(
            _keys(models), enc_cfg.std, 1, self.repeat)      # read after each tick's step
        self.enc_have = np.array(have, np.int64)
        models = [s.lidar_noise for s in sensors]
        self.lid_noise = (None if models[0] is None
                          else NoiseModel(models[0].config, _keys(models)))
        self.noises = [g for g in (self.cmd, self.enc) if g is not None]
        self.sub = sims[0].spec.substeps
        self.tick_ns = ticks[0].tick_ns
        # the blocks
        dt = sims[0].spec.control_tick_s
        self.wheels = np.zeros((w, 2))        # a DART world's wheel angles, each tick
        if self.kinematic:
            robots, pairs = kinematic.kernel_state(self.worlds.batch)
            statics = self.worlds.batch.foot.kernel_args()
            tick_s = self.worlds.batch.tick_s
        else:
            robots = (0, 0, 0, 0, self.wheels, 0, 0)      # (what ticks.c's after reads)
            statics, pairs, tick_s = (0,) * 9, False, dt
        sim_spec = sims[0].spec
        slots = {
            "v": st["lim_v"], "w": st["lim_w"], "lim_wheels": st["wheels"],
            "v_target": self.v_target, "w_target": self.w_target, "targets": st["targets"],
            "pairs": int(pairs), "enc_have": self.enc_have if any(have) else 0,
            "odo_pose": st["pose"], "odo_vel": st["vel"], "last": st["last"],
            "last_t": st["last_t"], "odo_r": st["r"], "odo_d": st["d"], "pos": self.pos,
            "t": self.t, "steps": st["steps"], "t_ns": st["t_ns"], "due": self.due,
            "sub": sim_spec.substeps, "step_ns": int(round(sim_spec.physics_step_s * 1e9)),
            "tick_ns": ticks[0].tick_ns, "period": sensors[0].periods["scan"]}
        slots.update(zip(_SLOTS[_SLOTS.index("radius"):], robots))
        slots.update(zip(_SLOTS[_SLOTS.index("nbox"):], statics))
        for name, g in (("cmd", self.cmd), ("enc", self.enc)):
            slots.update({f"{name}_buf": g.buf, f"{name}_next": g.next, f"{name}_live": g.live,
                          f"{name}_len": g.buf.shape[1]} if g is not None else
                         {f"{name}_{x}": 0 for x in ("buf", "next", "live", "len")})
        self.slots = np.array([kernels.ptr(slots[n]) for n in _SLOTS], np.int64)
        params = {"dv": spec.max_linear_accel_mps2 * dt, "dw": spec.max_angular_accel_radps2 * dt,
                  "r": spec.wheel_radius_m, "d": spec.wheel_separation_m,
                  "m": spec.max_wheel_speed_radps, "a": spec.max_wheel_accel_radps2 * dt,
                  "tick_s": tick_s, "foot_r": kinematic.FOOTPRINT_RADIUS_M,
                  "centre_x": kinematic.CHASSIS_CENTRE_X_M,
                  "enc_offset": 0.0 if enc_cfg is None else enc_cfg.bias + enc_cfg.mean,
                  "enc_res": 0.0 if enc_cfg is None else float(enc_cfg.resolution)}
        self.params = np.array([params[n] for n in _PARAMS], float)
        if kernels.library().plant_ticks_count() != len(_SLOTS) * 1000 + len(_PARAMS):
            raise kernels.KernelsMissing("plant/kernels/ticks.c's blocks are not the ones "
                                         "diffbot/envs/kinbatch.py lays out: rebuild the "
                                         "kernels (make setup)")
        self._addr = (kernels.ptr(self.slots), kernels.ptr(self.params))
        self._key = self.at.tobytes()
        self._first_kin = sims[0].kin
        self.fans: lid.Fans | None = None                  # the lidars' casts (_scan)
        self._base = np.zeros((1, 4, 4))                   # one robot's pose (_transforms)
        self._base[0, 2, 2], self._base[0, 3, 3] = 1.0, 1.0
        if self.kinematic:
            self._base[0, 2, 3] = float(self.worlds.batch.radius[0])

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

    def step(self, owner: ArrayTicks, cmds: np.ndarray) -> Made:
        """:meth:`ArrayTicks.advance` of the plan's rows with ``cmds`` (W, 2)."""
        st, w = self.state, len(self.at)
        self.v_target[:] = _clamp(cmds[:, 0], self.limits[0])
        self.w_target[:] = _clamp(cmds[:, 1], self.limits[1])
        self.new_scan[:] = False
        tick = st["steps"] // self.sub           # each world's tick now
        for g in self.noises:                   # the readings of the step's ticks
            g.draw(tick)
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
            raise FloatingPointError(
                f"the world of env {', '.join(map(str, envs))} diverged (not finite) in this "
                "step: reset() it (in-process a world that diverges ends the episode here; a "
                "plant over the bus rebuilds it at t = 0 and goes on)") from None
        truth = self.worlds.truth()
        owner._kept.keep(self, truth)
        return Made(_observation(st["pose"], st["vel"], self.goal, st["scans"]), truth,
                    st["t_ns"].copy())

    def _scan(self, owner: ArrayTicks, due: np.ndarray) -> None:
        """The lidars of rows ``due`` (their robots where the last tick left them)."""
        cfg, scene = self.cfg, owner._static_scene(self.sims[0])
        if self.fans is None or self.fans.scene is not scene:
            self.fans = lid.Fans(cfg, scene, len(self.at), owner.threads)
        if due.size == len(self.at):
            exact = self.fans.scan(self._transforms())
        else:
            exact = lid.scan_many(cfg, self.worlds.transforms(due), self.fans.scene,
                                  [None] * due.size, owner.threads)
        noise = self.lid_noise
        if noise is not None and due.size != len(self.at):
            noise = noise.select(due)
        ranges = lid.apply_noise(cfg, exact, noise, self.state["t_ns"][due] // self.tick_ns)
        r32 = ranges.astype(np.float32)
        scans = np.where(np.isfinite(r32), _clip(r32, 0.0, self.max_range),
                         np.float32(self.max_range)).astype(np.float32)
        if due.size == len(self.at):
            self.raw[:], self.state["scans"][:], self.new_scan[:] = r32, scans, True
        else:
            self.raw[due], self.state["scans"][due], self.new_scan[due] = r32, scans, True


def _observation(pose: np.ndarray, vel: np.ndarray, goal: np.ndarray,
                 scans: np.ndarray) -> dict:
    """:meth:`AvoidObserver.observation` of every world at once (one world: with its own
    functions, Python floats, which numpy's arrays are slower at)."""
    if len(pose) == 1:
        x, y, th = pose[0].tolist()
        v, om = vel[0].tolist()
        gx, gy = goal[0].tolist()
        odom = np.array([[x, y, wrap(th), v, om]], np.float32)
        in_robot = np.array([in_frame((x, y, th), gx, gy)], np.float32)
        return {"scan": scans.copy(), "odom": _clip(odom, -ODOM_HIGH, ODOM_HIGH),
                "goal": _clip(in_robot, -GOAL_LIMIT_M, GOAL_LIMIT_M)}
    x, y, th = pose[:, 0], pose[:, 1], pose[:, 2]
    v, om = vel[:, 0], vel[:, 1]
    c, s = np.cos(th), np.sin(th)
    dx, dy = goal[:, 0] - x, goal[:, 1] - y
    in_robot = np.stack([dx * c + dy * s, -dx * s + dy * c], 1).astype(np.float32)
    odom = np.stack([x, y, (th + math.pi) % (2 * math.pi) - math.pi, v, om], 1
                    ).astype(np.float32)
    return {"scan": scans.copy(), "odom": _clip(odom, -ODOM_HIGH, ODOM_HIGH),
            "goal": _clip(in_robot, -GOAL_LIMIT_M, GOAL_LIMIT_M)}


class Diverged(Exception):
    """Worlds (their indices in a step) no longer finite."""

    def __init__(self, worlds: list[int]) -> None:
        super().__init__(worlds)
        self.worlds = worlds


class _Kinematic:
    """The worlds' robots as the kinematic batch's arrays (:mod:`plant.kinematic`): one
    call steps them all."""

    def __init__(self, ticks: list, sims: list, names: list[str]) -> None:
        self.sims = sims
        kins = [s.kin for s in sims]
        self.batch = kinematic.join(kins) if len(kins) > 1 else kins[0]

    def transforms(self, idx: np.ndarray) -> np.ndarray:
        return self.batch.transforms()[idx]

    def finish(self) -> None:
        """The step's end (the worlds' clocks, Simulation.steps: :meth:`ArrayTicks.flush`)."""
        b = self.batch
        if not b.finite():              # (not a number stays one: checked once a step)
            raise Diverged(np.flatnonzero(~(np.isfinite(b.pose).all(1)
                                            & np.isfinite(b.wheels).all(1))).tolist())

    def truth(self) -> np.ndarray:
        return truths(self.batch.pose)


class _Dart:
    """The worlds' robots in their DART worlds, stepped world by world
    (:meth:`plant.tick.Tick.step`, as the message path steps them), read back as arrays:
    wheel angles each tick, poses where a lidar is due and at the step's end."""

    def __init__(self, ticks: list, sims: list, names: list[str]) -> None:
        self.ticks, self.sims = ticks, sims
        self.robots = [s.robots[n] for s, n in zip(sims, names)]
        self._tfs: dict[int, np.ndarray] = {}    # the robots' poses since the last tick

    def step(self, targets: np.ndarray) -> None:
        """One tick of every world (:meth:`plant.tick.Tick.step` without its timing and
        its check, which :meth:`finish` makes once a step: not a number stays one)."""
        self._tfs.clear()
        for sim, robot, (wl, wr) in zip(self.sims, self.robots, targets.tolist()):
            robot.targets = (wl, wr)                 # as Simulation.command_twist sets them
            sim.step_tick()

    def _tf(self, j: int) -> np.ndarray:
        """Robot j's base -> world, asked of DART once a tick (the lidar's and the truth's
        at a step's last tick: ~10 us each)."""
        tf = self._tfs.get(j)
        if tf is None:
            tf = self._tfs[j] = self.robots[j].transform()
        return tf

    def read_wheels(self, out: np.ndarray) -> None:
        """The wheel angles (W, 2) into ``out``."""
        for j, r in enumerate(self.robots):
            out[j, 0], out[j, 1] = r.wheels[0].getPosition(0), r.wheels[1].getPosition(0)

    def transforms(self, idx: np.ndarray) -> np.ndarray:
        return np.array([self._tf(j) for j in idx.tolist()])

    def finish(self) -> None:
        bad = [j for j, sim in enumerate(self.sims) if not sim.is_finite()]
        if bad:
            raise Diverged(bad)

    def truth(self) -> np.ndarray:
        """As the ``ground_truth`` message read back gives it (codec.pose_2d)."""
        out = np.empty((len(self.robots), 3))
        for j in range(len(self.robots)):
            tf = self._tf(j)
            qx, qy, qz, qw = rotation_to_quaternion(tf[:3, :3])
            out[j] = (float(tf[0, 3]), float(tf[1, 3]), yaw_of(qx, qy, qz, qw))
        return out


class _Kept:
    """A batch's tasks by index, as :meth:`ArrayTicks.advance` left them: each one's objects
    (``roster``: tick, robot name, sensors, simulation, observer, its odometry, drive
    limiter, robot, task) and its state (the odometry's pose, velocity, last encoder angles
    and their time, wheel radius and separation, the observer's scan, the world's step
    count, the limiter's v, w and wheel speeds; the robot's wheel targets, the task's time
    and ground truth, its last scan as sent), so a step reads the arrays, not every task's
    objects (a task reset since is read again: :meth:`read`). ``dirty``: the rows whose
    objects are behind the arrays (:meth:`ArrayTicks.flush` writes them back);
    ``new_scan``: those with a scan since their last write-back."""

    #: the arrays a step changes (a :class:`_TickPlan` steps them in place, or copies)
    STATE = ("pose", "vel", "last", "last_t", "r", "d", "scans", "steps", "lim_v", "lim_w",
             "wheels", "targets", "t_ns")

    def __init__(self, n: int) -> None:
        self.roster: list = [None] * n
        self.pose, self.vel, self.last = np.zeros((n, 3)), np.zeros((n, 2)), np.zeros((n, 2))
        self.last_t, self.r, self.d = np.zeros(n), np.zeros(n), np.zeros(n)
        self.scans: np.ndarray | None = None
        self.raw: np.ndarray | None = None
        self.steps = np.zeros(n, np.int64)
        self.lim_v, self.lim_w, self.wheels = np.zeros(n), np.zeros(n), np.zeros((n, 2))
        self.targets, self.truth = np.zeros((n, 2)), np.zeros((n, 3))
        self.t_ns = np.zeros(n, np.int64)
        self.dirty, self.new_scan = np.zeros(n, bool), np.zeros(n, bool)
        self.scan_fields: tuple = ()

    def read(self, at: np.ndarray, tasks: Sequence) -> None:
        """Rows ``at`` from ``tasks``' objects (one task each, in order)."""
        for i, t in zip(at.tolist(), tasks):
            name = t.robots[0]
            tick = t.transport.tick
            sim, o = tick.sim, t.observers[name]
            self.roster[i] = (tick, name, tick.sensors[name], sim, o, o.odom,
                              sim.limiters[name], sim.robots[name], t)
        objs = [self.roster[i] for i in at.tolist()]
        odo = [r[5] for r in objs]
        self.pose[at] = [(o.x, o.y, o.theta) for o in odo]
        self.vel[at] = [(o.v, o.w) for o in odo]
        self.last[at] = [o._last for o in odo]
        self.last_t[at] = [o._last_t for o in odo]
        self.r[at] = [o.r for o in odo]
        self.d[at] = [o.d for o in odo]
        scans = np.array([r[4].scan for r in objs])
        if self.scans is None:        # (the first read: every row; one spec, one scan shape)
            self.scans = np.zeros((len(self.roster),) + scans.shape[1:], scans.dtype)
            self.raw = np.zeros((len(self.roster),) + scans.shape[1:], np.float32)
            self.scan_fields = _Scan.fields(objs[0][2].lidar)
        self.scans[at] = scans
        self.steps[at] = [r[3].steps for r in objs]
        lims = [r[6] for r in objs]
        self.lim_v[at] = [lim.v for lim in lims]
        self.lim_w[at] = [lim.w for lim in lims]
        self.wheels[at] = [lim.wheels for lim in lims]

    def keep(self, plan: _TickPlan, truth: np.ndarray) -> None:
        """What a :class:`_TickPlan`'s step left of its rows (their objects now behind:
        ``dirty``)."""
        rows = plan.rows
        if not plan.run:
            for f in self.STATE:
                getattr(self, f)[rows] = plan.state[f]
        self.truth[rows] = truth
        if plan.new_scan.all():
            self.raw[rows], self.new_scan[rows] = plan.raw, True
        else:
            got = plan.at[plan.new_scan]
            self.raw[got] = plan.raw[plan.new_scan]
            self.new_scan[got] = True
        self.dirty[rows] = True

    def flush(self, rows: np.ndarray) -> None:
        """Rows ``rows``' state written back to their objects, as the message path leaves
        them after a step: the odometry, the observer's scan (a copy), the limiter, the
        robot's wheel targets, the world's step count, the task's time, truth and last scan
        (:class:`_Scan`, what :meth:`AvoidTask.render` draws)."""
        rows = rows[self.dirty[rows]]
        if not rows.size:
            return
        at = rows.tolist()
        for i, p, u, e, te, n, v, w, wh, tg, t, tr in zip(
                at, self.pose[rows].tolist(), self.vel[rows].tolist(),
                self.last[rows].tolist(), self.last_t[rows].tolist(),
                self.steps[rows].tolist(), self.lim_v[rows].tolist(),
                self.lim_w[rows].tolist(), self.wheels[rows].tolist(),
                self.targets[rows].tolist(), self.t_ns[rows].tolist(),
                self.truth[rows].tolist()):
            _tick, name, _s, sim, _o, od, lim, robot, task = self.roster[i]
            od.x, od.y, od.theta = p
            od.v, od.w = u
            od._last = (e[0], e[1])
            od._last_t = te
            sim.advance((n - sim.steps) // sim.spec.substeps)   # the ticks the arrays ran
            lim.v, lim.w = v, w
            lim.wheels = (wh[0], wh[1])
            robot.targets = (tg[0], tg[1])
            task.t_ns = t
            task._ticks_left = 0
            task.truth = {name: tuple(tr)}
        for i in rows[self.new_scan[rows]].tolist():
            _tick, name, _s, _sim, o, _od, _lim, _robot, task = self.roster[i]
            o.scan = self.scans[i].copy()
            o._scan_msg = None
            task.scans[name] = _Scan(self.raw[i].copy(), *self.scan_fields)
        self.dirty[rows] = False
        self.new_scan[rows] = False


def _clamp(x: np.ndarray, lim: float) -> np.ndarray:
    """:func:`plant.drive._clamp` (``max(-lim, min(lim, x))``) element by element."""
    return np.maximum(-lim, np.minimum(lim, x))


def _clip(a: np.ndarray, lo, hi) -> np.ndarray:
    """``np.clip(a, lo, hi)``'s values (a NaN stays one) without its Python wrappers,
    which cost more than the clip of a row."""
    return np.minimum(np.maximum(a, lo), hi)


def truths(pose: np.ndarray) -> np.ndarray:
    """(x, y, yaw) (W, 3) of kinematic robots at ``pose`` (W, 3) as their ``ground_truth``
    messages give them: :meth:`plant.sim.Simulation.kin_state`'s rotation, its quaternion
    (:func:`plant.sim.rotation_to_quaternion`, both of its branches), back to a yaw
    (:func:`bus.codec.quaternion_to_yaw`, ``math.atan2``: numpy's differs in the last bit)."""
    if len(pose) == 1:
        return np.array([truth_of(*pose[0].tolist())])
    yaw = pose[:, 2]
    c, s = np.cos(yaw), np.sin(yaw)
    # the rotation [[c, -s, 0], [s, c, 0], [0, 0, 1]]: trace (m00 + m11) + m22
    tr = c + c + 1.0
    pos = tr > 0
    s1 = np.sqrt(np.where(pos, tr, 0.0) + 1.0) * 2              # tr > 0
    s2 = np.sqrt(np.where(pos, 1.0, 1.0 + 1.0 - c - c)) * 2     # else: the largest is m22
    zero = 0.0 / np.where(pos, s1, s2)                          # (m21 - m12) / s, ...
    qx = qy = zero
    qz = np.where(pos, (s - -s) / s1, 0.25 * s2)
    qw = np.where(pos, 0.25 * s1, (s - -s) / s2)
    num = 2.0 * (qw * qz + qx * qy)
    den = 1.0 - 2.0 * (qy * qy + qz * qz)
    out = np.empty_like(pose, dtype=float)
    out[:, :2] = pose[:, :2]
    out[:, 2] = [math.atan2(a, b) for a, b in zip(num.tolist(), den.tolist())]
    return out


def truth_of(x: float, y: float, yaw: float) -> tuple[float, float, float]:
    """:func:`truths` of one robot, in Python floats (``math``: what
    :meth:`plant.sim.Simulation.kin_state` and :func:`plant.sim.rotation_to_quaternion`
    compute with)."""
    c, s = math.cos(yaw), math.sin(yaw)
    tr = c + c + 1.0
    if tr > 0:
        s1 = math.sqrt(tr + 1.0) * 2
        qx = qy = 0.0 / s1
        qz, qw = (s - -s) / s1, 0.25 * s1
    else:
        s2 = math.sqrt(1.0 + 1.0 - c - c) * 2
        qx = qy = 0.0 / s2
        qz, qw = 0.25 * s2, (s - -s) / s2
    return x, y, yaw_of(qx, qy, qz, qw)
