"""The bridge as a lockstep member: each robot's controller is a ROS 2 node.

``diffbot ros2 --lockstep`` runs a bus.runtime.NodeRunner whose controllers are
:class:`RosController`: each tick hands the ROS 2 node its trigger input and ``/clock`` and
waits (``Bridge.command_for``) for its TwistStamped stamped with the trigger's stamp.
rclpy is not imported here: the bridge hands over its node and message classes.
"""
from __future__ import annotations

import threading

from bus import codec

from .ros2_types import OUT_TOPICS


class RosController:
    """A bus.node controller whose step is answered by a ROS 2 node."""
    sync = True
    check_inputs = True

    def __init__(self, bridge, robot: str) -> None:
        self.bridge = bridge
        self.robot = robot
        self.inputs = [bridge.trigger]
        self.done = False
        ros_name, msg = OUT_TOPICS[bridge.trigger]
        # reliable: a best-effort subscriber (qos_profile_sensor_data) matches it as well
        self.pub = bridge.node.create_publisher(getattr(bridge.ros, msg), f"/{robot}/{ros_name}",
                                                bridge.ros.qos_cmd)
        self.stop = threading.Event()

    def step(self, obs):
        b = self.bridge
        trig = obs[b.trigger]
        if trig is None:
            return None
        stamp = codec.stamp_ns(trig.header.stamp)
        clock, data = codec.encode(codec.clock(obs.t_ns)), codec.encode(trig)

        def hand_over() -> None:
            b._publish(b.clock_pub, clock)
            b._publish(self.pub, data)
        hand_over()
        data = b.command_for(self.robot, stamp, self.stop, hand_over)
        if data is None:
            self.done = True
            return None
        cmd = codec.decode(data, "geometry_msgs/msg/TwistStamped")
        # on the bus a command carries the tick it answers (the plant files it by stamp)
        cmd.header.stamp = codec.time_msg(obs.t_ns)
        return {"cmd_vel": cmd}


def relay_stop(stop: threading.Event, ctrls: dict) -> None:
    stop.wait()
    for c in ctrls.values():
        c.stop.set()
