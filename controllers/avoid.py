"""Reactive obstacle avoidance on the lidar alone (the swarm scenario's controller).

Each tick it looks at the latest scan: the free distance straight ahead (the rays within
``front_half_angle_rad`` of the heading) sets the speed, from ``max_speed_mps`` when the
way is clear beyond ``slow_m`` down to zero at ``stop_m``; the robot steers away from
the nearest return in front of it (a repulsion that grows as it comes closer), and when
the front is blocked it turns on the spot toward the side with more room, keeping that
side until the front clears (no dithering between left and right). Walls, obstacles and
other robots are all just returns: no map, no ground truth, no communication.

One object drives every robot of its node: :meth:`Avoid.step_many` steps them all in one
call of the controllers' C kernels (controllers/kernels/avoid.c), giving to the bit the commands
:meth:`Avoid.step` gives robot by robot (its numpy code is the reference).
"""
from __future__ import annotations

import math
from operator import attrgetter

import numpy as np

from bus.cliargs import positive_float
from bus.controller import Twist
from bus.node import node_arg_parser, run_node_args
from controllers.kernels import function

#: what scans must share to be stepped as one array (besides their number of rays)
_RAYS = attrgetter("angle_min", "angle_increment", "range_min", "range_max")


def _kernel():
    """controllers/kernels/avoid.c's batch of commands."""
    return function("controller_avoid_commands", ("controller_avoid_abi", 1), 12)


class Avoid:
    name = "avoid"
    inputs = ["scan"]

    def __init__(self, max_speed_mps: float = 0.3, turn_radps: float = 1.2,
                 stop_m: float = 0.7, slow_m: float = 1.6,
                 front_half_angle_rad: float = 0.7) -> None:
        if not (0 < stop_m < slow_m):
            raise ValueError("need 0 < stop distance < slow-down distance")
        self.v_max = max_speed_mps
        self.w_turn = turn_radps
        self.stop_m = stop_m
        self.slow_m = slow_m
        self.front = front_half_angle_rad
        self.turning = 0.0            # +1 left, -1 right while escaping, 0 when free
        # step_many: the same per robot, by index in the robots of its last call (the
        # rest by name), and what it computes once per lidar model
        self._robots: tuple = ()
        self._turning = np.zeros(0)
        self._others: dict[str, float] = {}
        self._geometry: dict[tuple, np.ndarray] = {}
        self._rays: dict[tuple, tuple] = {}
        self._buffers: dict[tuple, tuple] = {}     # (robots, rays) -> _every's arrays

    def step(self, obs):
        scan = obs["scan"]
        if scan is None:
            return Twist()
        ranges = np.asarray(scan.ranges, dtype=float)
        angles = scan.angle_min + scan.angle_increment * np.arange(len(ranges))
        bad = ~np.isfinite(ranges) | (ranges < scan.range_min)
        ranges = np.where(bad, scan.range_max, np.minimum(ranges, scan.range_max))
        return self.command(angles, ranges)

    def step_many(self, observations: dict) -> dict:
        """Every robot's :class:`Twist` at once (``{robot: Observation}`` in,
        ``{robot: Twist}`` out): the scans that share their rays as one array, stepped in one
        kernel call (:meth:`commands`); each robot's turning side kept in an array by robot
        (``turning_of``)."""
        robots = tuple(observations)
        if robots != self._robots:
            self._track(robots)
        scans = [obs["scan"] for obs in observations.values()]
        have = [i for i, s in enumerate(scans) if s is not None]
        if len(have) < len(scans):
            scans = [scans[i] for i in have]
        ranges = [s.ranges for s in scans]
        rays = list(zip(map(len, ranges), map(_RAYS, scans)))
        v, w = np.zeros(len(robots)), np.zeros(len(robots))
        if rays and rays.count(rays[0]) == len(rays):      # (the usual: one lidar model)
            groups = {rays[0]: have}
        else:
            groups = {}
            for i, key in zip(have, rays):
                groups.setdefault(key, []).append(i)
            ranges = dict(zip(have, ranges))
        for (n, (a0, da, rmin, rmax)), rows in groups.items():
            every = len(rows) == len(robots)
            if every:                   # (the usual: every robot in one group, buffers kept)
                v, w = self._every(self._angles(n, a0, da), ranges, rmin, rmax)
                continue
            r = np.array(ranges if len(groups) == 1 else [ranges[i] for i in rows],
                         dtype=float).reshape(-1, n)
            vg, wg, tg = self.commands(self._angles(n, a0, da), r, self._turning[rows],
                                       rmin, rmax)
            v[rows], w[rows], self._turning[rows] = vg, wg, tg
        # (tolist: the same Python floats as float() of each element, in one call)
        return dict(zip(robots, map(Twist, v.tolist(), w.tolist())))

    def step_scans(self, scans) -> tuple:
        """:meth:`step_many` of scans handed as one array (:class:`bus.rows.Scans`, a composed
        member's: one row per robot), the commands as arrays (linear, angular) in the
        robots' order: the same values, in one kernel call, with no message per robot."""
        robots = scans.robots
        if robots != self._robots:
            self._track(robots)
        if scans.ranges is None or not robots:             # (no scan yet, or stale: stop)
            return np.zeros(len(robots)), np.zeros(len(robots))
        angles = self._angles(scans.ranges.shape[1], scans.angle_min, scans.angle_increment)
        return self._every(angles, scans.ranges, scans.range_min, scans.range_max)

    def _every(self, angles: np.ndarray, ranges: list, range_min: float, range_max: float):
        """:meth:`commands` of every robot's scan (``ranges``: one row each, in the robots'
        order), the turning sides kept in place: the same kernel call on buffers kept per
        shape, their addresses taken once (a call's arrays and addresses cost as much as
        the kernel does for a few robots). (speeds, yaw rates)."""
        rows, n = len(ranges), len(ranges[0])
        got = self._buffers.get((rows, n))
        if got is None:
            r, out = np.empty((rows, n)), np.empty(3 * rows + n)
            got = self._buffers[(rows, n)] = (r, out, r.ctypes.data, out.ctypes.data)
        r, out, at_r, at = got
        r[:] = ranges
        rays = self._rays_of(angles)
        params = rays["params"]
        if params[4] != range_min or params[5] != range_max:
            params[4:] = range_min, range_max
        out[:rows] = self._turning
        _kernel()(rows, n, at_r, at, *rays["at"], at + 24 * rows, at + 8 * rows,
                  at + 16 * rows)
        self._turning[:] = out[:rows]
        return out[rows:2 * rows], out[2 * rows:3 * rows]

    @property
    def turning_of(self) -> dict[str, float]:
        """``step_many``: each robot's turning side (as ``turning``), by name."""
        kept = dict(self._others)
        kept.update(zip(self._robots, self._turning.tolist()))
        return kept

    def _track(self, robots: tuple) -> None:
        """``step_many`` for another set of robots: their turning sides by index in the new
        order (a robot left out keeps its side for when it comes back)."""
        kept = self.turning_of
        self._robots = robots
        self._turning = np.array([kept.pop(r, 0.0) for r in robots], dtype=float)
        self._others = kept

    def _angles(self, n: int, a0: float, da: float) -> np.ndarray:
        key = (n, a0, da)
        if key not in self._geometry:
            self._geometry[key] = a0 + da * np.arange(n)
        return self._geometry[key]

    def commands(self, angles: np.ndarray, ranges: np.ndarray, turning: np.ndarray,
                 range_min: float = -math.inf, range_max: float = math.inf):
        """:meth:`command` for a batch of scans sharing ``angles``, in one call of the
        controllers' C kernels (controllers/kernels/avoid.c): ``ranges`` (robots, rays) as
        :meth:`step` reads a scan's (inf, NaN and returns under ``range_min`` read as
        ``range_max``; float64, the array overwritten with those), ``turning`` per robot; (speeds, yaw rates, turning
        sides after), the values :meth:`command` gives each row, to the bit (its means and
        sums taken in numpy's order, its other operations the same, in the same order)."""
        rays = self._rays_of(angles)
        rows, n = ranges.shape
        ranges = np.ascontiguousarray(ranges, dtype=np.float64)
        params = rays["params"]
        if params[4] != range_min or params[5] != range_max:
            params[4:] = range_min, range_max
        out = np.empty(3 * rows + n)            # turning, v, w, then the kernel's scratch
        out[:rows] = turning
        at = out.ctypes.data
        if rows:
            _kernel()(rows, n, ranges.ctypes.data, at, *rays["at"], at + 24 * rows,
                      at + 8 * rows, at + 16 * rows)
        return out[rows:2 * rows], out[2 * rows:3 * rows], out[:rows]

    def _rays_of(self, angles: np.ndarray) -> dict:
        """What :meth:`commands` needs of the rays alone, once per set of angles: each ray's
        flags (ahead, left, right, within +-90 deg), the factors of its push (-sign, cos: the
        per-robot step's factors, computed by numpy as it computes them), whether any ray
        is ahead, left, right, and the parameters (the last two the range limits, set per
        call): the arrays, kept alive, and their addresses for the kernel, taken once."""
        key = (self.front, angles.tobytes())
        got = self._rays.get(key)
        if got is None:
            flags = ((np.abs(angles) <= self.front) * 1 + (angles > 0) * 2 + (angles < 0) * 4
                     + (np.abs(angles) <= math.pi / 2) * 8).astype(np.uint8)
            toward = (np.ascontiguousarray(-np.sign(angles), dtype=np.float64),
                      np.ascontiguousarray(np.cos(angles), dtype=np.float64))
            has = np.array([(flags & b).any() for b in (1, 2, 4)], np.int64)
            params = np.array([self.stop_m, self.slow_m, self.v_max, self.w_turn,
                               -math.inf, math.inf])
            arrays = (flags, *toward, params, has)
            got = self._rays[key] = {"arrays": arrays, "params": params,
                                     "at": tuple(a.ctypes.data for a in arrays)}
        return got

    def command(self, angles: np.ndarray, ranges: np.ndarray) -> Twist:
        """Twist from a scan given as ray angles (rad, 0 = ahead, + left) and ranges (m)."""
        ahead = np.abs(angles) <= self.front
        front = float(ranges[ahead].min()) if ahead.any() else float(ranges.min())
        if front < self.stop_m or (self.turning and front < self.stop_m * 1.3):
            if not self.turning:
                left = ranges[angles > 0].mean() if (angles > 0).any() else 0.0
                right = ranges[angles < 0].mean() if (angles < 0).any() else 0.0
                self.turning = 1.0 if left >= right else -1.0
            return Twist(0.0, self.turning * self.w_turn)
        self.turning = 0.0
        v = self.v_max * min(1.0, (front - self.stop_m) / (self.slow_m - self.stop_m))
        # Repulsion: each close return within +-90 deg pushes the heading away from it.
        near = (np.abs(angles) <= math.pi / 2) & (ranges < self.slow_m)
        push = np.sum(-np.sign(angles[near]) * (self.slow_m - ranges[near]) / self.slow_m
                      * np.cos(angles[near]))
        w = float(np.clip(1.5 * push, -self.w_turn, self.w_turn))
        return Twist(v, w)


def main(argv=None) -> int:
    p = node_arg_parser("Wander and avoid walls, obstacles and other robots on the lidar.")
    p.add_argument("--max-speed", type=positive_float, default=0.3, help="m/s (default 0.3)")
    args = p.parse_args(argv)
    return run_node_args(Avoid(max_speed_mps=args.max_speed), args,
                         args.name or f"avoid_{args.robot}")
