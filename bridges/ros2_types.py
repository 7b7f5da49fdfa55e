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

#: what the bridge takes in: ROS 2 name under /<robot>/ -> (message class attribute of
#: ros_modules(), its type name); one type per topic (docs/ros2.md)
IN_TOPICS = {
    "cmd_vel": ("TwistStamped", "geometry_msgs/msg/TwistStamped"),
    "cmd_vel_unstamped": ("Twist", "geometry_msgs/msg/Twist"),
    "wheel_cmd": ("JointState", "sensor_msgs/msg/JointState"),
}


def ros_modules() -> types.SimpleNamespace:
    """rclpy, the message classes and the QoS profiles (ImportError without rclpy).
    ``TFMessage`` is None when ``tf2_msgs`` is not importable (no wheel: ``make setup``
    generates it, bridges/ros2_msgs.py), ``tf2_msgs_error`` then says why."""
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
    try:
        from tf2_msgs.msg import TFMessage
        tf_error = None
    except ImportError as exc:
        TFMessage, tf_error = None, str(exc)
    return types.SimpleNamespace(
        rclpy=rclpy, SignalHandlerOptions=SignalHandlerOptions,
        Clock=Clock, Twist=Twist, TwistStamped=TwistStamped, PointStamped=PointStamped,
        Odometry=Odometry, CameraInfo=CameraInfo, Image=Image, JointState=JointState,
        LaserScan=LaserScan, String=String, Empty=Empty,
        TFMessage=TFMessage, tf2_msgs_error=tf_error,
        # sensors as ROS 2 drivers publish them: best effort, keep last 5
        qos_sensor=qos_profile_sensor_data,
        # /clock: reliable keep-last-1 matches both reliable and best-effort subscribers
        qos_clock=QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE),
        # commands: reliable
        qos_cmd=QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
        # /tf: tf2_ros's dynamic broadcaster (reliable, volatile, keep last 100)
        qos_tf=QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE),
        # robot_description, /tf_static: latched, as robot_state_publisher publishes it
        qos_latched=QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                               durability=DurabilityPolicy.TRANSIENT_LOCAL),
    )
