"""Bridges from the bus to other middleware (ROS 2). Third-party clients are imported only here."""
