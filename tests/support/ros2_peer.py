"""The ROS 2 side of the bridge's tests: a plain rclpy node on a DDS domain of the test's
own (rclpy is imported only when one is made, so importing this needs no rclpy)."""
from __future__ import annotations

import os
import threading

import pytest


def domain_id(k: int) -> int:
    """A DDS domain of this test run (0-101 are safe with Fast DDS's ports); ``k`` is the
    test's own number (tests/bridges/test_ros2_bridge.py 0-6,
    tests/bridges/test_one_naming_scheme.py 7, tests/bridges/test_ros2_tf.py 8-9)."""
    return 1 + (os.getpid() * 4 + k) % 100


class Peer:
    """An rclpy node in its own context, spun by a thread. An exception in the spin (a
    subscription callback of the test that raised) stops the spin and is raised again in
    the test's thread by ``check`` and by ``close`` (the fixture's teardown)."""

    def __init__(self, domain: int) -> None:
        import rclpy
        import rclpy.context
        import rclpy.executors
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node("test_peer", context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.error: BaseException | None = None
        self.closing = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            while self.context.ok() and not self.closing:
                self.executor.spin_once(timeout_sec=0.05)
        except Exception as exc:
            if not self.closing and self.context.ok():    # not the shutdown of close()
                self.error = exc

    def check(self) -> None:
        if self.error is not None:
            raise AssertionError(f"the rclpy peer's spin failed: {self.error!r}") \
                from self.error

    def close(self) -> None:
        self.closing = True
        self.thread.join(2.0)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()
        self.check()


@pytest.fixture
def peer_factory():
    peers = []

    def make(domain: int) -> Peer:
        peers.append(Peer(domain))
        return peers[-1]
    yield make
    errors = []
    for p in peers:
        try:
            p.close()
        except AssertionError as exc:
            errors.append(exc)
    if errors:
        raise errors[0]


def latched():
    """Reliable, transient local, keep last 1: robot_description, /tf_static."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
