"""Bridges from the bus to other tools: the ROS 2 bridge (ros2.py), the live Foxglove view
(view.py). Third-party clients (rclpy, foxglove-sdk) are imported only here, lazily."""
