"""The ROS 2 side's names, types and QoS; rclpy is imported here (lazily), never in the core."""
from __future__ import annotations

import types

#: bus topic -> (ROS 2 name under /<robot>/, message class attribute of ros_modules()):
#: the same names on both sides (docs/ros2.md)
OUT_TOPICS = {
    "scan": ("scan", "LaserScan"),
    "camera/image_raw": ("camera/image_raw", "Image"),
    "camera/camera_info": ("camera/camera_info", "CameraInfo"),
    "joint_states": ("joint_states", "JointState"),
    "odom": ("odom", "Odometry"),
    "ground_truth": ("ground_truth", "Odometry"),
    "gps": ("gps", "PointStamped"),
}


def ros_modules() -> types.SimpleNamespace:
    """rclpy, the message classes and the QoS profiles (ImportError without rclpy)."""
    import rclpy
    import rclpy.context
    import rclpy.executors
    from geometry_msgs.msg import PointStamped, Twist, TwistStamped
    from nav_msgs.msg import Odometry
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from rclpy.signals import SignalHandlerOptions
    from rclpy.qos import DurabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import CameraInfo, Image, JointState, LaserScan
    from std_msgs.msg import String
    from std_srvs.srv import Empty
    return types.SimpleNamespace(
        rclpy=rclpy, SignalHandlerOptions=SignalHandlerOptions,
        Clock=Clock, Twist=Twist, TwistStamped=TwistStamped, PointStamped=PointStamped,
        Odometry=Odometry, CameraInfo=CameraInfo, Image=Image, JointState=JointState,
        LaserScan=LaserScan, String=String, Empty=Empty,
        # sensors as ROS 2 drivers publish them: best effort, keep last 5
        qos_sensor=qos_profile_sensor_data,
        # /clock: reliable keep-last-1 matches both reliable and best-effort subscribers
        qos_clock=QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE),
        # commands: reliable
        qos_cmd=QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
        # robot_description: latched, as robot_state_publisher publishes it
        qos_latched=QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                               durability=DurabilityPolicy.TRANSIENT_LOCAL),
    )
