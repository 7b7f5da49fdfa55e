"""The leader's route: a smooth loop around the living room, at 0.1-0.2 m/s.

Pure pursuit along an ellipse through the free middle of the room (clear of the
furniture by the robot's footprint), speed varying smoothly between the two limits
so a follower has something to do. The leader is a scripted actor: it steers on
``ground_truth`` so its route never drifts, however long the run.
"""
from __future__ import annotations

import math
import sys

import numpy as np

from bus import codec
from bus.cliargs import positive_float
from bus.controller import Twist
from bus.node import node_arg_parser, run_controller

#: points a search from the last nearest point walks before the whole route is searched
#: (the leader moves under one point, 5.7 mm, a tick)
_WALK = 24


class Wander:
    name = "wander"
    inputs = ["ground_truth"]

    def __init__(self, center=(-0.1, -0.15), semi_axes=(1.5, 1.1), speed_range=(0.1, 0.2),
                 lookahead_m: float = 0.5, clockwise: bool = False) -> None:
        if not (0 < speed_range[0] <= speed_range[1]):
            raise ValueError("speed range must be positive and ordered")
        self.cx, self.cy = center
        self.a, self.b = semi_axes
        self.vmin, self.vmax = speed_range
        self.lookahead = lookahead_m
        self.sign = -1.0 if clockwise else 1.0
        self.params = np.linspace(0.0, 2 * math.pi, 1440, endpoint=False)
        self.points = np.stack([self.cx + self.a * np.cos(self.params),
                                self.cy + self.b * np.sin(self.params)], axis=1)
        seg = np.linalg.norm(np.diff(np.vstack([self.points, self.points[:1]]), axis=0), axis=1)
        self.step_len = float(seg.mean())
        self.done = False
        # the route's coordinates as two contiguous arrays (point's arithmetic, a quarter of
        # the time of the (N, 2) form's) and as Python floats (step's scalar arithmetic)
        self._xs = np.ascontiguousarray(self.points[:, 0])
        self._ys = np.ascontiguousarray(self.points[:, 1])
        self._route = [tuple(p) for p in self.points.tolist()]
        self._phases = self.params.tolist()
        self._dx, self._dy = np.empty_like(self._xs), np.empty_like(self._ys)
        # the ellipse's evolute (its centres of curvature) is an astroid, (a |u|)^(2/3) +
        # (b |v|)^(2/3) = |a^2 - b^2|^(2/3) round the centre: a point outside it lies on
        # exactly two normals of the ellipse (through its nearest and farthest points).
        # The astroid lies within the diamond a |u| + b |v| = |a^2 - b^2|: beyond it, by
        # 1 %, is outside the astroid (the room's route clears it: a^2 < 2 b^2).
        self._outside = 1.01 * abs(self.a * self.a - self.b * self.b) + 1e-9
        self._last: int | None = None      # the last nearest point
        self.full_searches = 0             # points searched over the whole route

    def point(self, x: float, y: float) -> int:
        """The index of the route's point nearest to (x, y) (the first of equals).

        Searched from the last answer, one point at a time downhill, where that gives the
        whole route's answer: outside the ellipse's evolute the squared distance to a point
        of the ellipse has one minimum and one maximum over the parameter (exactly two
        normals pass through the point), so its samples fall to one point or a pair of
        equals from anywhere on the route (differences of sampled values there are far
        above rounding: the test keeps a margin outside the astroid). Elsewhere, or after
        ``_WALK`` steps, the whole route is searched."""
        last = self._last
        if last is not None:
            if abs(self.a * (x - self.cx)) + abs(self.b * (y - self.cy)) > self._outside:
                got = self._walk(x, y, last)
                if got is not None:
                    self._last = got
                    return got
        self._last = got = self._search(x, y)
        self.full_searches += 1
        return got

    def _walk(self, x: float, y: float, i: int) -> int | None:
        """The nearest point downhill of point ``i`` (the first of equals), or None if it
        lies more than ``_WALK`` points away. Each squared distance is the full search's
        arithmetic, in the same order (Python floats are the same doubles)."""
        route, n = self._route, len(self._route)
        px, py = route[i - 1]                  # (-1: the last point)
        lo = (px - x) * (px - x) + (py - y) * (py - y)
        px, py = route[i]
        mid = (px - x) * (px - x) + (py - y) * (py - y)
        px, py = route[(i + 1) % n]
        hi = (px - x) * (px - x) + (py - y) * (py - y)
        if hi < mid or lo < mid:               # downhill: on while the next point is nearer
            step = 1 if hi < mid else -1
            nxt = hi if step == 1 else lo
            for _ in range(_WALK):
                i = (i + step) % n
                px, py = route[(i + step) % n]
                far, mid, nxt = mid, nxt, (px - x) * (px - x) + (py - y) * (py - y)
                if not nxt < mid:
                    break
            else:
                return None
            lo, hi = (far, nxt) if step == 1 else (nxt, far)
        # a minimum: neither neighbour is nearer; of equals, the lowest index (argmin's)
        first = i
        if lo == mid and (i - 1) % n < first:
            first = (i - 1) % n
        if hi == mid and (i + 1) % n < first:
            first = (i + 1) % n
        return first

    def _search(self, x: float, y: float) -> int:
        """The nearest point over the whole route (the first of equals)."""
        # dx * dx + dy * dy, the same operations into buffers kept for them (a quarter
        # of the time went to making the arrays)
        dx, dy = self._dx, self._dy
        np.subtract(self._xs, x, out=dx)
        np.subtract(self._ys, y, out=dy)
        np.multiply(dx, dx, out=dx)
        np.multiply(dy, dy, out=dy)
        return int(np.add(dx, dy, out=dx).argmin())

    def step(self, obs):
        gt = obs["ground_truth"]
        if gt is None:
            return Twist()
        x, y, yaw = codec.pose_2d(gt)
        i = self.point(x, y)
        j = (i + int(self.sign * self.lookahead / self.step_len)) % len(self.points)
        tx, ty = self._route[j]
        dx, dy = tx - x, ty - y
        alpha = math.atan2(dy, dx) - yaw
        alpha = (alpha + math.pi) % (2 * math.pi) - math.pi
        dist = math.hypot(dx, dy)
        # Speed: slow and fast stretches, twice round the loop.
        phase = self._phases[i]
        v = self.vmin + (self.vmax - self.vmin) * 0.5 * (1 + math.sin(2 * phase))
        if abs(alpha) > math.pi / 2:          # far off the route (start-up): turn first
            return Twist(0.0, math.copysign(0.6, alpha))
        w = 2.0 * v * math.sin(alpha) / max(dist, 1e-3)
        return Twist(v, w)


def main(argv=None) -> int:
    p = node_arg_parser("Drive a smooth loop around the living room (the follow task's leader).")
    p.set_defaults(robot="leader")
    p.add_argument("--clockwise", action="store_true")
    p.add_argument("--min-speed", type=positive_float, default=0.1, help="m/s (default 0.1)")
    p.add_argument("--max-speed", type=positive_float, default=0.2, help="m/s (default 0.2)")
    args = p.parse_args(argv)
    return run_controller(lambda: Wander(speed_range=(args.min_speed, args.max_speed),
                                         clockwise=args.clockwise), args, "wander")


if __name__ == "__main__":
    sys.exit(main())
