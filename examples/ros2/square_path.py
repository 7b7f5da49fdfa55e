"""Drive a 1.5 m square on odometry: a plain rclpy node (no import of diffbot-cosim).

Each /<robot>/odom gets one geometry_msgs/TwistStamped on /<robot>/cmd_vel, stamped with
the odometry's stamp: that is what `diffbot ros2 --lockstep` waits for each tick.
Run:  python square_path.py [--robot robot1] [--side 1.5]   (see README.md here)
"""
import argparse
import math

import rclpy
import rclpy.parameter
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


class Square:
    def __init__(self, node, robot, side_m, speed_mps=0.2, turn_radps=0.5):
        self.node, self.side, self.speed, self.turn = node, side_m, speed_mps, turn_radps
        self.leg, self.phase, self.start, self.h0, self.done = 0, "straight", None, None, False
        self.last = (None, (0.0, 0.0))          # (stamp, command): a re-sent odom gets the same
        self.pub = node.create_publisher(TwistStamped, f"/{robot}/cmd_vel",
                                         QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        node.create_subscription(Odometry, f"/{robot}/odom", self.on_odom, qos_profile_sensor_data)

    def control(self, x, y, th):
        if self.h0 is None:
            self.h0, self.start = th, (x, y)
        if self.phase == "straight":
            remaining = self.side - math.hypot(x - self.start[0], y - self.start[1])
            if remaining <= 0.0005:
                self.phase, self.done = "turn", self.leg == 3
                return 0.0, 0.0
            return min(self.speed, max(0.02, 1.5 * remaining)), 2.0 * wrap(self.h0 + self.leg * math.pi / 2 - th)
        err = wrap(self.h0 + (self.leg + 1) * math.pi / 2 - th)
        if abs(err) < 0.001:
            self.leg, self.phase, self.start = self.leg + 1, "straight", (x, y)
            return 0.0, 0.0
        return 0.0, math.copysign(min(self.turn, max(0.05, 2.0 * abs(err))), err)

    def on_odom(self, m):
        stamp = (m.header.stamp.sec, m.header.stamp.nanosec)
        if stamp != self.last[0]:
            p, q = m.pose.pose.position, m.pose.pose.orientation
            th = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
            self.last = (stamp, (0.0, 0.0) if self.done else self.control(p.x, p.y, th))
        cmd = TwistStamped()
        cmd.header.stamp, cmd.header.frame_id = m.header.stamp, m.child_frame_id
        cmd.twist.linear.x, cmd.twist.angular.z = self.last[1]
        self.pub.publish(cmd)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robot", default="robot1")
    ap.add_argument("--side", type=float, default=1.5, help="m")
    args, ros_args = ap.parse_known_args()
    rclpy.init(args=ros_args)
    node = rclpy.create_node(f"square_path_{args.robot}",
                             parameter_overrides=[rclpy.parameter.Parameter("use_sim_time", value=True)])
    square = Square(node, args.robot, args.side)
    try:
        while rclpy.ok() and not square.done:
            rclpy.spin_once(node, timeout_sec=0.1)
        for _ in range(3):                      # the last answer, then leave the graph
            rclpy.spin_once(node, timeout_sec=0.05)
    except KeyboardInterrupt:
        pass
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()
