"""Open-loop wheel-speed schedules, e.g. the study's drive test.

``--schedule "5:1,1;5:1,-1"`` means 5 s at left 1 / right 1 rad/s, then 5 s at
left 1 / right -1 rad/s; then the robot stops and the node exits.
"""
from __future__ import annotations

import sys

from bus.controller import WheelSpeeds
from bus.node import node_arg_parser, run_controller

DRIVE_TEST = "5:1,1;5:1,-1"


def parse_schedule(text: str) -> list[tuple[float, float, float]]:
    """[(duration_s, left_radps, right_radps), ...] from ``"5:1,1;5:1,-1"``."""
    out = []
    for part in filter(None, (p.strip() for p in text.split(";"))):
        try:
            dur, speeds = part.split(":")
            left, right = speeds.split(",")
            item = (float(dur), float(left), float(right))
        except ValueError:
            raise ValueError(f"bad schedule item {part!r}: expected SECONDS:LEFT,RIGHT") from None
        if item[0] <= 0:
            raise ValueError(f"bad schedule item {part!r}: duration must be > 0")
        out.append(item)
    if not out:
        raise ValueError("empty schedule")
    return out


class WheelSchedule:
    name = "wheel_schedule"
    inputs = ["joint_states"]

    def __init__(self, schedule: list[tuple[float, float, float]]) -> None:
        self.schedule = schedule
        self.t0: float | None = None
        self.done = False

    def step(self, obs):
        if self.t0 is None:
            self.t0 = obs.t
        elapsed = obs.t - self.t0
        for dur, left, right in self.schedule:
            if elapsed < dur - 1e-9:
                return WheelSpeeds(left, right)
            elapsed -= dur
        self.done = True
        return WheelSpeeds(0.0, 0.0)

    def stop_command(self):
        return WheelSpeeds(0.0, 0.0)


def main(argv=None) -> int:
    p = node_arg_parser("Play a wheel-speed schedule, then stop.")
    p.add_argument("--schedule", default=DRIVE_TEST,
                   help=f"SECONDS:LEFT,RIGHT items separated by ';' (default {DRIVE_TEST!r})")
    args = p.parse_args(argv)
    return run_controller(lambda: WheelSchedule(parse_schedule(args.schedule)), args,
                          "wheel_schedule")


if __name__ == "__main__":
    sys.exit(main())
