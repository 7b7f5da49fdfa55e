"""What a batch of one-robot Avoid worlds ticked as arrays keeps between steps
(:class:`Kept`): each env's state as arrays, read from its objects once after a reset and
written back to them only when something reads them (:meth:`Kept.flush`)."""
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


class Kept:
    """A batch's tasks by index, as :meth:`diffbot.envs.kinbatch.ArrayTicks.advance` left
    them: each one's objects (``roster``: tick, robot name, sensors, simulation, observer,
    its odometry, its world's drive arrays (:class:`plant.core.drive.WorldDrive`: the
    limiter, the wheel targets), the robot's index there, task) and its state (the odometry's pose, velocity, last encoder angles
    and their time, wheel radius and separation, the observer's scan, the world's step
    count, the limiter's v, w and wheel speeds; the robot's wheel targets, the task's time
    and ground truth, its last scan as sent), so a step reads the arrays, not every task's
    objects (a task reset since is read again: :meth:`read`). ``dirty``: the rows whose
    objects are behind the arrays (:meth:`ArrayTicks.flush` writes them back);
    ``new_scan``: those with a scan since their last write-back."""

    #: the arrays a step changes (a step's plan steps them in place, or copies)
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
            self.scan_fields = Scan.fields(objs[0][2].lidar)
        self.scans[at] = scans
        self.steps[at] = [r[3].steps for r in objs]
        lims = [r[6].limiter(r[7]) for r in objs]
        self.lim_v[at] = [v for v, _, _ in lims]
        self.lim_w[at] = [w for _, w, _ in lims]
        self.wheels[at] = [wh for _, _, wh in lims]

    def keep(self, plan, truth: np.ndarray) -> None:
        """What a step's plan (:class:`diffbot.envs.kinbatch._TickPlan`) left of its rows
        (their objects now behind: ``dirty``)."""
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
        (:class:`Scan`, what :meth:`AvoidTask.render` draws)."""
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
