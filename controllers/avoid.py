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

import numpy as np

from bus.cliargs import positive_float
from bus.controller import Twist
from bus.node import node_arg_parser, run_node_args
from controllers.rowsum import masked_row_sums


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
        self.turning_of: dict[str, float] = {}    # step_many: the same, per robot

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
        numpy; each robot's turning side kept in ``turning_of``."""
        out = {r: Twist() for r, obs in observations.items() if obs["scan"] is None}
        groups: dict[tuple, list] = {}
        for robot, obs in observations.items():
            scan = obs["scan"]
            if scan is not None:
                rays = (len(scan.ranges), scan.angle_min, scan.angle_increment,
                        scan.range_min, scan.range_max)
                groups.setdefault(rays, []).append((robot, scan))
        for (n, a0, da, rmin, rmax), members in groups.items():
            robots = [r for r, _ in members]
            ranges = np.array([s.ranges for _, s in members], dtype=float).reshape(-1, n)
            bad = ~np.isfinite(ranges) | (ranges < rmin)
            ranges = np.where(bad, rmax, np.minimum(ranges, rmax))
            angles = a0 + da * np.arange(n)
            turning_of = self.turning_of
            turning = np.array([turning_of.get(r, 0.0) for r in robots])
            v, w, turning = self.commands(angles, ranges, turning)
            # (tolist: the same Python floats as float() of each element, in one call)
            for r, vi, wi, ti in zip(robots, v.tolist(), w.tolist(), turning.tolist()):
                turning_of[r] = ti
                out[r] = Twist(vi, wi)
        return {r: out[r] for r in observations}

    def commands(self, angles: np.ndarray, ranges: np.ndarray, turning: np.ndarray):
        """:meth:`command` for a batch of scans sharing ``angles``: ``ranges`` (robots, rays),
        ``turning`` per robot; (speeds, yaw rates, turning sides after), the same values
        :meth:`command` gives each row (its sums and means taken in numpy's order)."""
        ahead = np.abs(angles) <= self.front
        front = ranges[:, ahead].min(axis=1) if ahead.any() else ranges.min(axis=1)
        blocked = (front < self.stop_m) | ((turning != 0) & (front < self.stop_m * 1.3))
        new = blocked & (turning == 0)
        if new.any():
            pos, neg = angles > 0, angles < 0
            left = ranges[new][:, pos].mean(axis=1) if pos.any() else np.zeros(new.sum())
            right = ranges[new][:, neg].mean(axis=1) if neg.any() else np.zeros(new.sum())
            turning = turning.copy()
            turning[new] = np.where(left >= right, 1.0, -1.0)
        turning = np.where(blocked, turning, 0.0)
        v = self.v_max * np.minimum(1.0, (front - self.stop_m) / (self.slow_m - self.stop_m))
        near = (np.abs(angles) <= math.pi / 2) & (ranges < self.slow_m)
        terms = -np.sign(angles) * (self.slow_m - ranges) / self.slow_m * np.cos(angles)
        w = np.clip(1.5 * masked_row_sums(terms, near), -self.w_turn, self.w_turn)
        return (np.where(blocked, 0.0, v), np.where(blocked, turning * self.w_turn, w),
                turning)

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
