"""The ROS 2 side's names, types and QoS; rclpy is imported here (lazily), never in the core."""
from __future__ import annotations

import types

#: bus topic -> (ROS 2 name under /<robot>/, message class attribute of ros_modules())
OUT_TOPICS = {
    "scan": ("scan", "LaserScan"),
    "camera/image": ("camera/image_raw", "Image"),
    "camera/info": ("camera/camera_info", "CameraInfo"),
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
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import CameraInfo, Image, JointState, LaserScan
    return types.SimpleNamespace(
        rclpy=rclpy, SignalHandlerOptions=SignalHandlerOptions,
        Clock=Clock, Twist=Twist, TwistStamped=TwistStamped, PointStamped=PointStamped,
        Odometry=Odometry, CameraInfo=CameraInfo, Image=Image, JointState=JointState,
        LaserScan=LaserScan,
        # sensors as ROS 2 drivers publish them: best effort, keep last 5
        qos_sensor=qos_profile_sensor_data,
        # /clock: reliable keep-last-1 matches both reliable and best-effort subscribers
        qos_clock=QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE),
        # commands: reliable
        qos_cmd=QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
    )
