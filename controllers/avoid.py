"""Reactive obstacle avoidance on the lidar alone (the swarm scenario's controller).

Each tick it looks at the latest scan: the free distance straight ahead (the rays within
``front_half_angle_rad`` of the heading) sets the speed, from ``max_speed_mps`` when the
way is clear beyond ``slow_m`` down to zero at ``stop_m``; the robot steers away from
the nearest return in front of it (a repulsion that grows as it comes closer), and when
the front is blocked it turns on the spot toward the side with more room, keeping that
side until the front clears (no dithering between left and right). Walls, obstacles and
other robots are all just returns: no map, no ground truth, no communication.

One object drives every robot of its node: :meth:`Avoid.step_many` steps them all with numpy
in one call, giving to the bit the commands :meth:`Avoid.step` gives robot by robot.
"""
from __future__ import annotations

import math
from operator import attrgetter

import numpy as np

from bus.cliargs import positive_float
from bus.controller import Twist
from bus.node import node_arg_parser, run_node_args
from controllers.rowsum import masked_row_sums

#: what scans must share to be stepped as one array (besides their number of rays)
_RAYS = attrgetter("angle_min", "angle_increment", "range_min", "range_max")


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
        ``{robot: Twist}`` out): the scans that share their rays as one array, stepped with
        numpy; each robot's turning side kept in an array by robot (``turning_of``)."""
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
            r = np.array(ranges if len(groups) == 1 else [ranges[i] for i in rows],
                         dtype=float).reshape(-1, n)
            # inf and NaN (no return) and returns under the minimum range read as the maximum
            np.fmin(r, rmax, out=r)
            r[r < rmin] = rmax
            every = len(rows) == len(robots)
            vg, wg, tg = self.commands(self._angles(n, a0, da), r,
                                       self._turning if every else self._turning[rows])
            if every:
                v, w, self._turning = vg, wg, tg
            else:
                v[rows], w[rows], self._turning[rows] = vg, wg, tg
        # (tolist: the same Python floats as float() of each element, in one call)
        return dict(zip(robots, map(Twist, v.tolist(), w.tolist())))

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

    def commands(self, angles: np.ndarray, ranges: np.ndarray, turning: np.ndarray):
        """:meth:`command` for a batch of scans sharing ``angles``: ``ranges`` (robots, rays),
        ``turning`` per robot; (speeds, yaw rates, turning sides after), the same values
        :meth:`command` gives each row (its sums and means taken in numpy's order)."""
        ahead, pos, neg, side, toward = self._rays_of(angles)
        front = ranges[:, ahead].min(axis=1) if ahead is not None else ranges.min(axis=1)
        blocked = (front < self.stop_m) | ((turning != 0) & (front < self.stop_m * 1.3))
        new = blocked & (turning == 0)
        if new.any():
            rows = ranges[new]
            left = rows[:, pos].mean(axis=1) if pos is not None else np.zeros(len(rows))
            right = rows[:, neg].mean(axis=1) if neg is not None else np.zeros(len(rows))
            turning = turning.copy()
            turning[new] = np.where(left >= right, 1.0, -1.0)
        turning = np.where(blocked, turning, 0.0)
        v = self.v_max * np.minimum(1.0, (front - self.stop_m) / (self.slow_m - self.stop_m))
        near = side & (ranges < self.slow_m)
        terms = toward[0] * (self.slow_m - ranges) / self.slow_m * toward[1]
        w = np.clip(1.5 * masked_row_sums(terms, near), -self.w_turn, self.w_turn)
        return (np.where(blocked, 0.0, v), np.where(blocked, turning * self.w_turn, w),
                turning)

    def _rays_of(self, angles: np.ndarray) -> tuple:
        """What :meth:`commands` needs of the rays alone, once per set of angles: the rays
        ahead, left and right (None where there are none), those within +-90 deg, and the
        factors of each ray's push (-sign, cos: the per-robot step's factors, in its order)."""
        key = (self.front, angles.tobytes())
        got = self._rays.get(key)
        if got is None:
            ahead, pos, neg = np.abs(angles) <= self.front, angles > 0, angles < 0
            got = self._rays[key] = tuple(m if m.any() else None for m in (ahead, pos, neg)) \
                + (np.abs(angles) <= math.pi / 2, (-np.sign(angles), np.cos(angles)))
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
