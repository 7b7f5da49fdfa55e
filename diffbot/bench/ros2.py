"""Suite ``ros2``: the ROS 2 bridge's latency and throughput (bus -> ROS 2 subscriber), next
to a direct rclpy publisher -> subscriber.

The bench process is the bus's router (it answers ``sim/info`` as a plant would) and the
ROS 2 subscriber; ``diffbot ros2`` runs as its own process in between. Bridge path: Zenoh
put here -> bridge process -> DDS -> rclpy subscription here. Direct path: an rclpy
publisher here (its own DDS participant) -> the same kind of subscription. Both hand the
arrival to the timing thread through the same Event, so the wake-up cost is in both.
"""
from __future__ import annotations

import os
import shutil
import threading
import time

import numpy as np

from .common import private_endpoint, spawn, stop, tail
from .harness import Case, Context, Metric, Probe, Skip, suite

ROBOT = "robot1"
THROUGHPUT_S = 1.0


def _messages() -> dict[str, tuple[str, str, bytes]]:
    """label -> (bus topic, ROS 2 type name, CDR bytes) of a 180-ray scan and a 160x120 image."""
    from bus import codec
    T = codec.T
    scan = T["sensor_msgs/msg/LaserScan"](
        header=codec.header(1, "laser"), angle_min=-np.pi, angle_max=np.pi,
        angle_increment=2 * np.pi / 180, time_increment=0.0, scan_time=0.1, range_min=0.1,
        range_max=8.0, ranges=np.linspace(0.5, 5.0, 180, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32))
    img = T["sensor_msgs/msg/Image"](
        header=codec.header(1, "camera"), height=120, width=160, encoding="rgb8",
        is_bigendian=0, step=480, data=np.random.default_rng(0).integers(
            0, 255, 160 * 120 * 3, dtype=np.uint8))
    return {"scan 180 rays": ("scan", "LaserScan", codec.encode(scan)),
            "image 160x120 rgb8": ("camera/image_raw", "Image", codec.encode(img))}


class _Rx:
    """A raw rclpy subscription in its own context, counting arrivals."""

    def __init__(self, ros, domain: int, topic: str, msg) -> None:
        self.ctx = ros.rclpy.context.Context()
        ros.rclpy.init(context=self.ctx, domain_id=domain)
        self.node = ros.rclpy.create_node("bench_rx", context=self.ctx)
        self.n = 0
        self.got = threading.Event()
        self.node.create_subscription(msg, topic, self._on, ros.qos_sensor, raw=True)
        self.ex = ros.rclpy.executors.SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _on(self, data) -> None:
        self.n += 1
        self.got.set()

    def _spin(self) -> None:
        try:
            while self.ctx.ok():
                self.ex.spin_once(timeout_sec=0.05)
        except Exception:
            pass

    def close(self) -> None:
        self.ex.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.ctx.try_shutdown()
        self.thread.join(2.0)


def _latency(send, rx: _Rx):
    def timer(number: int) -> float:
        t0 = time.perf_counter()
        for _ in range(number):
            rx.got.clear()
            send()
            if not rx.got.wait(1.0):
                raise RuntimeError("a message did not arrive within 1 s")
        return time.perf_counter() - t0
    return timer


def _throughput(send, rx: _Rx) -> dict:
    """Publish back to back for THROUGHPUT_S: messages/s sent and received (best effort)."""
    time.sleep(0.2)
    n0 = rx.n
    sent = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < THROUGHPUT_S:
        send()
        sent += 1
    wall = time.perf_counter() - t0
    time.sleep(0.3)                                   # the tail still in flight
    return {"sent_hz": sent / wall, "received_hz": (rx.n - n0) / wall}


def _wait_matched(rx: _Rx, send, what: str, child=None, log: str = "") -> None:
    deadline = time.monotonic() + 30
    while not rx.got.is_set():
        if time.monotonic() > deadline or (child is not None and child.poll() is not None):
            raise RuntimeError(f"{what}: nothing arrived in ROS 2 {tail(log) if log else ''}")
        send()
        rx.got.wait(0.1)


@suite("ros2", "the ROS 2 bridge (bus -> rclpy subscriber) against a direct rclpy pub -> sub")
def ros2_suite(ctx: Context):
    try:
        from bridges.ros2_types import ros_modules
        ros = ros_modules()
    except ImportError as exc:
        raise Skip(f"rclpy is not importable ({exc}): pip install -e '.[ros2]'") from None
    from bus import codec, jsonio
    from bus.keys import Keys
    from bus.protocol import PROTOCOL_VERSION
    from bus.session import open_session
    domain = 1 + os.getpid() % 100
    d, endpoint = private_endpoint(ctx, "ros2")
    keys = Keys()
    info = {"protocol": PROTOCOL_VERSION, "mode": "realtime", "coupling": "sequential",
            "control_tick_s": 0.02, "robots": {ROBOT: {"topics": {}}}}
    session = open_session("plant", endpoint)
    queryable = session.declare_queryable(
        keys.info, lambda q: q.reply(keys.info, jsonio.dumps(info)))
    log = os.path.join(d, "bridge.log")
    child = spawn(["ros2", "--endpoint", endpoint, "--domain-id", str(domain), "--robots", ROBOT],
                  log)
    rxs: list[_Rx] = []
    ros_tx = []
    try:
        for label, (topic, tname, data) in _messages().items():
            msg = getattr(ros, tname)
            ros_name = f"/{ROBOT}/{topic}"        # the same name on the bus and over ROS 2
            key = keys.topic(ROBOT, topic)
            pub = session.declare_publisher(key)
            att = codec.attachment(0, 1)

            def via_bridge(pub=pub, data=data, att=att):
                pub.put(data, attachment=att)
            rx = _Rx(ros, domain, ros_name, msg)
            rxs.append(rx)
            ctx.progress(f"ros2: waiting for the bridge ({label})")
            _wait_matched(rx, via_bridge, "bridge", child, log)
            # the direct path: an rclpy publisher in its own participant, same subscriber type
            tx_ctx = ros.rclpy.context.Context()
            ros.rclpy.init(context=tx_ctx, domain_id=domain)
            tx_node = ros.rclpy.create_node("bench_tx", context=tx_ctx)
            ros_tx.append((tx_node, tx_ctx))
            direct_topic = f"/bench_direct/{topic.replace('/', '_')}"
            tx = tx_node.create_publisher(msg, direct_topic, ros.qos_sensor)
            drx = _Rx(ros, domain, direct_topic, msg)
            rxs.append(drx)

            def direct(tx=tx, data=data):
                tx.publish(data)
            _wait_matched(drx, direct, "direct rclpy")
            kb = f"{len(data) / 1000:.1f} KB"
            yield Case(f"bridge latency {label}", _latency(via_bridge, rx), timer=True,
                       notes=f"{kb} CDR: Zenoh put -> bridge process -> DDS -> rclpy callback")
            yield Case(f"direct latency {label}", _latency(direct, drx), timer=True,
                       notes=f"{kb} CDR: rclpy publish(bytes) -> DDS -> rclpy callback")
            for what, send, r in (("bridge", via_bridge, rx), ("direct", direct, drx)):
                name = f"{what} throughput {label}"
                yield Probe(name, lambda s=send, r=r: _throughput(s, r), [
                    Metric("sent_hz", f"{name}: sent", "Hz"),
                    Metric("received_hz", f"{name}: delivered", "Hz")],
                    repeats=1 if ctx.quick else 3,
                    notes="published back to back for 1 s, best effort: the delivered rate "
                          "is what the subscriber keeps up with; the rest is dropped")
    finally:
        for rx in rxs:
            rx.close()
        for node, c in ros_tx:
            node.destroy_node()
            c.try_shutdown()
        stop([child], grace_s=2.0)
        queryable.undeclare()
        session.close()
        shutil.rmtree(d, ignore_errors=True)
