"""Wander without touching the walls: a plain rclpy node (no import of diffbot-cosim).

Reads /<robot>/scan and /<robot>/odom, answers each odometry message with one
geometry_msgs/TwistStamped on /<robot>/cmd_vel stamped with the odometry's stamp (so it runs
in realtime and, through `diffbot ros2 --lockstep`, in lockstep), and commands nothing before
its first scan. Needs only what `make setup` installs (the `ros2` extra's PyPI wheels).

Run:  diffbot run sim --ros2          (or --mode lockstep --ros2), then in another shell
      python examples/ros2/wall_avoider.py [--robot robot1] [--seconds 20]
"""
import argparse
import math

import rclpy
import rclpy.parameter
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import LaserScan


class WallAvoider:
    def __init__(self, node, robot, seconds, speed_mps=0.25, clearance_m=0.6):
        self.node, self.seconds, self.speed, self.clearance = node, seconds, speed_mps, clearance_m
        self.front = None                    # nearest return within +-30 degrees, m
        self.t0 = None
        self.done = False
        self.commands = 0
        self.pub = node.create_publisher(TwistStamped, f"/{robot}/cmd_vel",
                                         QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        node.create_subscription(LaserScan, f"/{robot}/scan", self.on_scan, qos_profile_sensor_data)
        node.create_subscription(Odometry, f"/{robot}/odom", self.on_odom, qos_profile_sensor_data)

    def on_scan(self, m):
        near = [r for i, r in enumerate(m.ranges)
                if abs(m.angle_min + i * m.angle_increment) < math.radians(30) and math.isfinite(r)]
        self.front = min(near, default=math.inf)

    def on_odom(self, m):
        if self.front is None:               # no scan yet: say nothing (lockstep waits)
            return
        t = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
        self.t0 = t if self.t0 is None else self.t0
        self.done = t - self.t0 >= self.seconds
        cmd = TwistStamped()
        cmd.header.stamp, cmd.header.frame_id = m.header.stamp, m.child_frame_id
        if not self.done:
            blocked = self.front < self.clearance
            cmd.twist.linear.x = 0.0 if blocked else self.speed
            cmd.twist.angular.z = 1.0 if blocked else 0.0
        self.pub.publish(cmd)
        self.commands += 1


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robot", default="robot1")
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated seconds to drive")
    args, ros_args = ap.parse_known_args()
    rclpy.init(args=ros_args)
    node = rclpy.create_node(f"wall_avoider_{args.robot}", parameter_overrides=[
        rclpy.parameter.Parameter("use_sim_time", value=True)])
    me = WallAvoider(node, args.robot, args.seconds)
    try:
        while rclpy.ok() and not me.done:
            rclpy.spin_once(node, timeout_sec=0.1)
        for _ in range(3):                   # the last answer, then leave the graph
            rclpy.spin_once(node, timeout_sec=0.05)
    except KeyboardInterrupt:
        pass
    print(f"wall_avoider: {me.commands} commands, nearest return ahead {me.front} m", flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()
