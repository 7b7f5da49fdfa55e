"""The Python odometry node: joint_states in, ``<robot>/odom`` out, in lockstep.

The reference implementation of what the odometry FMU node does; the pose is in
the world frame, starting from the robot's start pose (so it overlays GPS).
"""
from __future__ import annotations

import sys

from bus import codec
from bus.node import run_node

from .odometry import Odometry


class OdometryNode:
    name = "odometry"
    inputs = ["joint_states"]

    def __init__(self) -> None:
        self.odo: Odometry | None = None

    def configure(self, info: dict, robot: str) -> None:
        r = info["robots"][robot]
        self.odo = Odometry(r["wheel_radius_m"], r["wheel_separation_m"], tuple(r["pose"]))

    def step(self, obs):
        js = obs["joint_states"]
        if js is None or len(js.position) < 2:
            return None
        x, y, th = self.odo.update(float(js.position[0]), float(js.position[1]), obs.t)
        return {"odom": codec.odometry(obs.t_ns, x, y, th, self.odo.v, self.odo.w,
                                       frame_id="world")}


def main(argv=None) -> int:
    return run_node(OdometryNode(), argv=argv)


if __name__ == "__main__":
    sys.exit(main())
