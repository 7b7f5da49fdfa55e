"""What a batch ticked as arrays (:class:`diffbot.envs.kinbatch.ArrayTicks`) holds besides the
core's data: each row's objects, to write the state back to (:class:`WriteBack`), and what
only the environment has (the observers' scans, the last scan as sent, the ground truth).

The state itself, every row's limiter, dead reckoning, noise keys and its world's clock, is
the core's :class:`plant.core.data.Data` of the batch's worlds, which the ticks step in place
(plant/kernels/ticks.c); it is read from a task's objects once after its reset
(:meth:`WriteBack.read`) and written back to them only when something reads them
(:meth:`WriteBack.flush`), so the message path finds them as it would have left them."""
from __future__ import annotations

from typing import Sequence

import numpy as np


class Scan:
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


class WriteBack:
    """A batch's ``n`` rows (a robot each, world after world, ``robots`` a world), their
    objects and what the environment keeps of them beside the core's data:

    - ``roster``: each row's objects (tick, robot name, sensors, simulation, observer, its
      odometry, its world's drive arrays (:class:`plant.core.drive.WorldDrive`: the
      limiter, the wheel targets), the robot's index there, task);
    - ``scans`` (n, rays) float32: each observer's scan, as the observation carries it
      (the ticks write it where a lidar is due); ``raw``: the last scan as sent, for
      :meth:`AvoidTask.render`; ``truth`` (n, 3): the ground truth of the last step;
    - ``dirty``: the rows whose objects are behind the data (:meth:`flush` writes them
      back); ``new_scan``: those with a scan since their last write-back.

    ``rows`` and ``clocks`` are the core's data as the ticks read it (:meth:`bind`): a row's
    arrays (n, ...) and a world's (n / robots,)."""

    def __init__(self, n: int, robots: int = 1) -> None:
        self.n, self.robots = int(n), int(robots)
        self.roster: list = [None] * n
        self.scans: np.ndarray | None = None
        self.raw: np.ndarray | None = None
        self.truth = np.zeros((n, 3))
        self.dirty, self.new_scan = np.zeros(n, bool), np.zeros(n, bool)
        self.scan_fields: tuple = ()
        self.rows: dict[str, np.ndarray] = {}
        self.clocks: dict[str, np.ndarray] = {}

    def bind(self, rows: dict[str, np.ndarray], clocks: dict[str, np.ndarray]) -> None:
        """The core's data to read into and write back from (views: :meth:`ArrayTicks.bind`)."""
        self.rows, self.clocks = rows, clocks

    def read(self, at: np.ndarray, tasks: Sequence, names: Sequence | None = None) -> None:
        """Rows ``at`` from ``tasks``' objects (one task each, in order): robot ``names[k]``
        of task k (None: each task's one robot; a swarm world's robots are a row each)."""
        for k, (i, t) in enumerate(zip(at.tolist(), tasks)):
            name = t.robots[0] if names is None else names[k]
            tick = t.transport.tick
            sim, o = tick.sim, t.observers[name]
            self.roster[i] = (tick, name, tick.sensors[name], sim, o, o.odom,
                              sim.drive, sim.drive.index[name], t)
        objs = [self.roster[i] for i in at.tolist()]
        odo = [r[5] for r in objs]
        rows, clocks = self.rows, self.clocks
        rows["pose"][at] = [(o.x, o.y, o.theta) for o in odo]
        rows["vel"][at] = [(o.v, o.w) for o in odo]
        rows["last"][at] = [o._last for o in odo]
        rows["last_t"][at] = [o._last_t for o in odo]
        rows["r"][at] = [o.r for o in odo]
        rows["d"][at] = [o.d for o in odo]
        lims = [r[6].limiter(r[7]) for r in objs]
        rows["lim_v"][at] = [v for v, _, _ in lims]
        rows["lim_w"][at] = [w for _, w, _ in lims]
        rows["wheels"][at] = [wh for _, _, wh in lims]
        # each noise stream's key (a row's law is the model's: its robot's): none, 0
        rows["motion_keys"][at] = [r[3].motion_noise[r[1]].key for r in objs]
        rows["enc_keys"][at] = [0 if r[2].enc_noise is None else r[2].enc_noise.key
                                for r in objs]
        rows["lid_keys"][at] = [0 if r[2].lidar_noise is None else r[2].lidar_noise.key
                                for r in objs]
        clocks["steps"][at // self.robots] = [r[3].steps for r in objs]
        scans = np.array([r[4].scan for r in objs])
        if self.scans is None:        # (the first read: every row; one spec, one scan shape)
            self.scans = np.zeros((self.n,) + scans.shape[1:], scans.dtype)
            self.raw = np.zeros((self.n,) + scans.shape[1:], np.float32)
            self.scan_fields = Scan.fields(objs[0][2].lidar)
            rows["scans"] = self.scans     # (a row's array the ticks write: the plan's too)
        self.scans[at] = scans

    def keep(self, plan, truth: np.ndarray) -> None:
        """What a step's plan (:class:`diffbot.envs.kinbatch._TickPlan`) left of its rows
        besides the core's data (their objects now behind: ``dirty``)."""
        rows = plan.rows
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
        (:class:`Scan`, what :meth:`AvoidTask.render` draws)."""
        rows = rows[self.dirty[rows]]
        if not rows.size:
            return
        at, world = rows.tolist(), rows // self.robots
        d, c = self.rows, self.clocks
        for i, p, u, e, te, n, v, w, wh, tg, t, tr in zip(
                at, d["pose"][rows].tolist(), d["vel"][rows].tolist(),
                d["last"][rows].tolist(), d["last_t"][rows].tolist(),
                c["steps"][world].tolist(), d["lim_v"][rows].tolist(),
                d["lim_w"][rows].tolist(), d["wheels"][rows].tolist(),
                d["targets"][rows].tolist(), c["t_ns"][world].tolist(),
                self.truth[rows].tolist()):
            _tick, name, _s, sim, _o, od, drive, j, task = self.roster[i]
            od.x, od.y, od.theta = p
            od.v, od.w = u
            od._last = (e[0], e[1])
            od._last_t = te
            ran = (n - sim.steps) // sim.spec.substeps      # the ticks the arrays ran
            if ran:                          # (a world's next robots: already moved on)
                sim.advance(ran)
            drive.set_limiter(j, v, w, wh)
            drive.targets[j] = tg
            task.t_ns = t
            task._ticks_left = 0
            task.truth = ({name: tuple(tr)} if len(task.robots) == 1
                          else {**task.truth, name: tuple(tr)})
        for i in rows[self.new_scan[rows]].tolist():
            _tick, name, _s, _sim, o, _od, _drive, _j, task = self.roster[i]
            o.scan = self.scans[i].copy()
            o._scan_msg = None
            task.scans[name] = Scan(self.raw[i].copy(), *self.scan_fields)
        self.dirty[rows] = False
        self.new_scan[rows] = False
