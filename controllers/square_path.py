"""Drive a square closed-loop on odometry, then stop.

Straight legs hold the heading the leg started with (proportional steering) and
slow down before the corner; corners turn in place to the next multiple of 90
degrees from the start heading. Everything is measured on ``<robot>/odom``.
"""
from __future__ import annotations

import argparse
import math
import sys

from bus import codec
from bus.cliargs import positive_float, positive_int
from bus.controller import Twist
from bus.node import node_arg_parser, run_controller


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


class SquarePath:
    name = "square_path"
    inputs = ["odom"]

    def __init__(self, side_m: float = 1.5, speed_mps: float = 0.2, turn_radps: float = 0.5,
                 direction: str = "ccw", laps: int = 1) -> None:
        if side_m <= 0 or speed_mps <= 0 or turn_radps <= 0 or laps < 1:
            raise ValueError("side, speed, turn rate and laps must be positive")
        if direction not in ("ccw", "cw"):
            raise ValueError("direction must be 'ccw' (left turns) or 'cw' (right turns)")
        self.side = side_m
        self.speed = speed_mps
        self.turn_rate = turn_radps
        self.sign = 1.0 if direction == "ccw" else -1.0
        self.legs = 4 * laps
        self.leg = 0
        self.phase = "straight"
        self.start = None            # (x, y) where the current leg began
        self.heading0 = None         # heading at the very start
        self.done = False

    def heading(self, leg: int) -> float:
        return self.heading0 + self.sign * leg * math.pi / 2

    def step(self, obs):
        odom = obs["odom"]
        if odom is None:
            return Twist()
        x, y, th = codec.pose_2d(odom)
        if self.heading0 is None:
            self.heading0 = th
            self.start = (x, y)
        if self.phase == "straight":
            travelled = math.hypot(x - self.start[0], y - self.start[1])
            remaining = self.side - travelled
            if remaining <= 0.0005:
                self.phase = "turn"
                if self.leg == self.legs - 1:
                    self.done = True
                return Twist()
            v = min(self.speed, max(0.02, 1.5 * remaining))
            w = 2.0 * wrap(self.heading(self.leg) - th)
            return Twist(v, w)
        err = wrap(self.heading(self.leg + 1) - th)
        if abs(err) < 0.001:
            self.leg += 1
            self.phase = "straight"
            self.start = (x, y)
            return Twist()
        w = math.copysign(min(self.turn_rate, max(0.05, 2.0 * abs(err))), err)
        return Twist(0.0, w)


def main(argv=None) -> int:
    p: argparse.ArgumentParser = node_arg_parser("Drive a square on odometry, then stop.")
    p.add_argument("--side", type=positive_float, default=1.5, help="side length, m (default 1.5)")
    p.add_argument("--speed", type=positive_float, default=0.2, help="forward speed, m/s (default 0.2)")
    p.add_argument("--turn-rate", type=positive_float, default=0.5, help="turn rate, rad/s (default 0.5)")
    p.add_argument("--direction", choices=("ccw", "cw"), default="ccw")
    p.add_argument("--laps", type=positive_int, default=1)
    args = p.parse_args(argv)
    return run_controller(lambda: SquarePath(args.side, args.speed, args.turn_rate,
                                             args.direction, args.laps), args, "square_path")


if __name__ == "__main__":
    sys.exit(main())
