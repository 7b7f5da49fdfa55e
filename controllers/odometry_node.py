"""The Python odometry node: joint_states in, ``<robot>/odom`` out, in lockstep.

The reference implementation of what the odometry FMU node does; the pose is in the
robot's odometry frame ``<robot>/odom`` (REP 105: it starts at the origin, where the robot
starts; ``world -> <robot>/odom`` is the start pose, :func:`bridges.scene.to_world`).
"""
from __future__ import annotations

import sys

from bus import codec
from bus.keys import frame
from bus.node import run_node

from .odometry import Odometry


class OdometryNode:
    name = "odometry"
    inputs = ["joint_states"]

    def __init__(self) -> None:
        self.odo: Odometry | None = None

    def configure(self, info: dict, robot: str) -> None:
        r = info["robots"][robot]
        self.odo = Odometry(r["wheel_radius_m"], r["wheel_separation_m"], (0.0, 0.0, 0.0))
        self.frames = frame(robot, "odom"), frame(robot, "base_link")

    def step(self, obs):
        js = obs["joint_states"]
        if js is None or len(js.position) < 2:
            return None
        x, y, th = self.odo.update(float(js.position[0]), float(js.position[1]), obs.t)
        return {"odom": codec.odometry(obs.t_ns, x, y, th, self.odo.v, self.odo.w,
                                       frame_id=self.frames[0], child_frame_id=self.frames[1])}


def main(argv=None) -> int:
    return run_node(OdometryNode(), argv=argv)


if __name__ == "__main__":
    sys.exit(main())
