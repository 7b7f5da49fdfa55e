"""`diffbot ros2` against real rclpy (from PyPI, the `ros2` extra): no mocks.

The bridge runs as its own process; the ROS 2 side is an rclpy node in this test process
(or the example's own process), on a DDS domain id private to the test.
"""
from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from bus import codec
from bus.keys import Keys
from tests.conftest import ROOT, wait_for
# peer_factory is a fixture; Peer, domain_id, _latched are tests/bridges/test_one_naming_scheme.py's
from tests.support.ros2_peer import Peer, domain_id, latched, peer_factory  # noqa: F401
_latched = latched

rclpy = pytest.importorskip(
    "rclpy", reason="rclpy is not importable: `pip install -e '.[ros2]'` (make setup does)")

#: one xdist worker for the ROS 2 tests: their DDS domains are numbered per process
#: (ros2_peer); the worker that runs the session's square (conftest.square_seed0), which the
#: rclpy square is compared with
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("square_seed0")]

EXAMPLE = os.path.join(ROOT, "examples", "ros2", "square_path.py")


def test_clock_and_scan_reach_ros2_as_on_the_bus(procs, endpoint, bus, peer_factory):
    from rclpy.qos import qos_profile_sensor_data
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import LaserScan
    dom = domain_id(0)
    procs.diffbot("plant", "--world", "living_room", "--mode", "realtime", "--disable",
                  "camera", "--endpoint", endpoint, name="plant")
    s = bus()
    on_bus, on_ros, clock = {}, {}, []
    s.declare_subscriber(Keys().topic("robot1", "scan"), lambda smp: on_bus.setdefault(
        *_scan_item(codec.decode(smp.payload.to_bytes(), "sensor_msgs/msg/LaserScan"))))
    peer = peer_factory(dom)
    peer.node.create_subscription(Clock, "/clock", lambda m: clock.append(
        codec.stamp_ns(m.clock)), 10)
    peer.node.create_subscription(LaserScan, "/robot1/scan", lambda m: on_ros.setdefault(
        *_scan_item(m)), qos_profile_sensor_data)
    procs.diffbot("ros2", "--endpoint", endpoint, "--domain-id", str(dom), name="bridge")
    wait_for(lambda: len(set(on_bus) & set(on_ros)) >= 5, 40, what="scans on both sides")
    both = sorted(set(on_bus) & set(on_ros))
    for t in both:
        assert len(on_ros[t][0]) == 180
        assert on_ros[t] == on_bus[t], f"scan at t={t} differs"
    assert on_ros[both[0]][1] == "robot1/laser"    # the bus's frame id, unchanged
    wait_for(lambda: len(clock) > 10, 10, what="/clock")
    assert clock[-1] > clock[0] and all(b >= a for a, b in zip(clock, clock[1:]))


def _realtime_plant_and_truth(procs, endpoint, bus) -> list:
    """A realtime plant on the empty world; the list fills with robot1's ground truth."""
    procs.diffbot("plant", "--world", "empty", "--mode", "realtime", "--endpoint", endpoint,
                  name="plant")
    gt: list = []
    bus().declare_subscriber(Keys().topic("robot1", "ground_truth"), lambda smp: gt.append(
        codec.decode(smp.payload.to_bytes(), "nav_msgs/msg/Odometry")))
    return gt


def _scan_item(m):
    return codec.stamp_ns(m.header.stamp), (list(map(float, m.ranges)), m.header.frame_id)


def test_cmd_vel_twist_stamped_and_wheel_cmd_move_the_robot_garbage_is_counted(
        procs, endpoint, bus, peer_factory, tmp_path):
    from geometry_msgs.msg import Twist, TwistStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    dom = domain_id(1)
    gt = _realtime_plant_and_truth(procs, endpoint, bus)
    stats = str(tmp_path / "bridge.json")
    bridge = procs.diffbot("ros2", "--endpoint", endpoint, "--domain-id", str(dom),
                           "--stats", stats, name="bridge")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    # one type per topic: TwistStamped on cmd_vel, plain Twist on cmd_vel_unstamped
    peer = peer_factory(dom)
    twist = peer.node.create_publisher(Twist, "/robot1/cmd_vel_unstamped", qos)
    stamped = peer.node.create_publisher(TwistStamped, "/robot1/cmd_vel", qos)
    wait_for(lambda: gt and twist.get_subscription_count() and stamped.get_subscription_count(),
             40, what="the bridge's cmd_vel subscriptions")

    def drive(pub, make, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            pub.publish(make())
            time.sleep(0.05)

    x0 = gt[-1].pose.pose.position.x
    m = Twist()
    m.linear.x = 0.3
    drive(twist, lambda: m, 1.5)                           # plain Twist: forward
    x1 = gt[-1].pose.pose.position.x
    assert x1 - x0 > 0.1, f"Twist did not move the robot: {x0} -> {x1}"
    yaw0 = codec.quaternion_to_yaw(gt[-1].pose.pose.orientation)
    ts = TwistStamped()
    ts.twist.angular.z = 1.0                               # stamp 0 = "now"
    drive(stamped, lambda: ts, 1.0)                        # TwistStamped: turn
    yaw1 = codec.quaternion_to_yaw(gt[-1].pose.pose.orientation)
    assert abs(yaw1 - yaw0) > 0.3, f"TwistStamped did not turn the robot: {yaw0} -> {yaw1}"
    from sensor_msgs.msg import JointState
    wheels = peer_factory(dom).node.create_publisher(JointState, "/robot1/wheel_cmd", qos)
    wait_for(lambda: wheels.get_subscription_count(), 20, what="the bridge's wheel_cmd")
    js = JointState()
    js.name, js.velocity = ["left_wheel_joint", "right_wheel_joint"], [4.0, 4.0]
    p0 = gt[-1].pose.pose.position
    drive(wheels, lambda: js, 1.0)                         # wheel speeds: straight on
    p1 = gt[-1].pose.pose.position
    assert math.hypot(p1.x - p0.x, p1.y - p0.y) > 0.1, "wheel_cmd did not move the robot"
    bad = TwistStamped()
    bad.twist.linear.x = math.nan
    bad_t = Twist()
    bad_t.angular.z = math.inf
    for _ in range(3):
        stamped.publish(bad)
        twist.publish(bad_t)
        time.sleep(0.05)
    time.sleep(0.5)
    assert bridge.poll() is None, procs.log(bridge)
    bridge.send_signal(signal.SIGINT)
    assert bridge.wait(10) == 0, procs.log(bridge)
    st = json.load(open(stats))
    assert st["rejected_total"] == 6, st
    assert st["forwarded"]["/robot1/cmd_vel"] > 20 and st["forwarded"]["/robot1/wheel_cmd"] > 10, st


def test_killing_the_bridge_stops_the_robot_within_cmd_timeout(procs, endpoint, bus, peer_factory):
    from geometry_msgs.msg import Twist
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    dom = domain_id(2)
    gt = _realtime_plant_and_truth(procs, endpoint, bus)
    bridge = procs.diffbot("ros2", "--endpoint", endpoint, "--domain-id", str(dom), name="bridge")
    peer = peer_factory(dom)
    pub = peer.node.create_publisher(
        Twist, "/robot1/cmd_vel_unstamped",
        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    m = Twist()
    m.linear.x = 0.3
    stop = threading.Event()

    def keep_driving():
        while not stop.is_set():
            pub.publish(m)
            time.sleep(0.05)
    threading.Thread(target=keep_driving, daemon=True).start()
    try:
        wait_for(lambda: gt and gt[-1].twist.twist.linear.x > 0.2, 40, what="the robot to drive")
        bridge.send_signal(signal.SIGKILL)
        bridge.wait(5)
        t_kill = codec.stamp_ns(gt[-1].header.stamp)
        # cmd_timeout_s is 0.5 s (simulated; realtime mode): stopped well within 1 s after
        wait_for(lambda: codec.stamp_ns(gt[-1].header.stamp) > t_kill + 1_000_000_000, 10,
                 what="1 s of simulated time")
        late = [g for g in gt if codec.stamp_ns(g.header.stamp) > t_kill + 700_000_000]
        assert late and all(abs(g.twist.twist.linear.x) < 0.02 for g in late)
    finally:
        stop.set()


SHORT_LEASE = os.path.join(ROOT, "tests", "data", "fastdds_short_lease.xml")


def _run_square(tmp_path, dom: int, tag: str, kill_after_s: float | None = None):
    env = dict(os.environ, ROS_DOMAIN_ID=str(dom), PYTHONUNBUFFERED="1")
    ex_env = dict(env)
    if kill_after_s is not None:   # the controller's participant lease: 2 s instead of 20
        ex_env.update(FASTDDS_DEFAULT_PROFILES_FILE=SHORT_LEASE,
                      FASTRTPS_DEFAULT_PROFILES_FILE=SHORT_LEASE)
    out = tmp_path / tag
    run = subprocess.Popen([sys.executable, "-m", "diffbot.cli", "run", "square-ros2", "--out",
                            str(out), "--timeout", "120"], cwd=ROOT, env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           start_new_session=True)
    ex = subprocess.Popen([sys.executable, EXAMPLE], env=ex_env, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, start_new_session=True)
    try:
        if kill_after_s is not None:
            # killed once it has commanded the robot for a while (its start-up under load
            # can take longer than a fixed sleep)
            bridge_log = out / "logs" / "ros2_bridge.log"
            wait_for(lambda: bridge_log.exists()
                     and "the ROS 2 controller answered" in bridge_log.read_text(), 90,
                     what="the ROS 2 controller's first command")
            time.sleep(kill_after_s)
            ex.send_signal(signal.SIGKILL)
        ex.wait(120)
        log = run.communicate(timeout=150)[0].decode()
    finally:
        for p in (ex, run):
            if p.poll() is None:       # Ctrl-C first: the launcher stops what it started
                os.killpg(p.pid, signal.SIGINT)
                try:
                    p.wait(15)
                except subprocess.TimeoutExpired:
                    os.killpg(p.pid, signal.SIGKILL)
                    p.wait(5)
    return run.returncode, log, out


def test_rclpy_square_in_lockstep_drives_the_native_square_to_the_byte(tmp_path, square_seed0):
    """The example's rclpy square (the same control law as controllers/square_path.py, over
    ROS 2 messages, through `diffbot ros2 --lockstep`) drives the native scenario's run
    (conftest.square_seed0: `diffbot run square --seed 0`) row for row, to the byte: the
    bridge loses nothing and keeps lockstep, and a run of it is reproducible, as the native
    one is. The ROS 2 node answers up to 3 more ticks after its last leg before it leaves
    the graph (the native controller exits at once), so its run goes on by those rows."""
    code, log, out = _run_square(tmp_path, domain_id(3), "run")
    assert code == 0, log
    summary = json.load(open(out / "summary.json"))
    assert summary["exit_codes"]["ros2_bridge"] == 0, summary
    m = summary["metrics"]["robot1"]
    assert m["final_odom_error_m"] < 0.02, m
    assert 5.9 < m["path_length_m"] < 6.1, m              # the whole 1.5 m square was driven
    ros = (out / "trajectory.csv").read_bytes().splitlines(keepends=True)
    native = (Path(square_seed0["out"]) / "trajectory.csv").read_bytes().splitlines(keepends=True)
    assert len(list(csv.reader(b"".join(native).decode().splitlines()))) > 2000
    left = next((i for i, (a, b) in enumerate(zip(native, ros)) if a != b), None)
    assert left is None, \
        f"the ROS 2 controller's run left the native one at row {left}: {ros[left]!r}, " \
        f"native {native[left]!r}"
    assert len(native) <= len(ros) <= len(native) + 3, (len(native), len(ros))


def test_a_killed_ros2_controller_ends_the_bridge_like_a_node(tmp_path):
    code, log, out = _run_square(tmp_path, domain_id(4), "killed", kill_after_s=2.0)
    bridge_log = open(out / "logs" / "ros2_bridge.log").read()
    summary = json.load(open(out / "summary.json"))
    why = f"{log}\n{bridge_log}\n{summary}"
    assert summary["exit_codes"]["ros2_bridge"] == 0, why
    assert summary["metrics"]["robot1"]["path_length_m"] < 5.0, why   # the square was cut short
    assert "the ROS 2 controller left the graph" in bridge_log, why


# ---------------------------------------------------------------- `diffbot run sim --ros2`
AVOIDER = os.path.join(ROOT, "examples", "ros2", "wall_avoider.py")


def test_sim_over_ros2_rep105_odom_robot_description_one_type_and_reset(
        procs, endpoint, peer_factory, tmp_path, monkeypatch):
    import xml.etree.ElementTree as ET

    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    from std_srvs.srv import Empty

    from plant.world import load_world
    dom = domain_id(5)
    monkeypatch.setenv("ROS_DOMAIN_ID", str(dom))
    out = tmp_path / "sim"
    run = procs.diffbot("run", "sim", "--ros2", "--endpoint", endpoint, "--out", str(out),
                        "--timeout", "300", name="run")
    peer = peer_factory(dom)
    odom, gt, desc, joints = [], [], [], []
    peer.node.create_subscription(Odometry, "/robot1/odom", odom.append, qos_profile_sensor_data)
    peer.node.create_subscription(Odometry, "/robot1/ground_truth", gt.append,
                                  qos_profile_sensor_data)
    peer.node.create_subscription(JointState, "/robot1/joint_states", joints.append,
                                  qos_profile_sensor_data)
    peer.node.create_subscription(String, "/robot1/robot_description", desc.append, latched())
    wait_for(lambda: odom and desc and joints and gt, 60, what="odom, joints, robot_description")
    # REP 105: odometry in robot1/odom, starting at the origin (the robot starts at rest)
    first = odom[0]
    assert (first.header.frame_id, first.child_frame_id) == ("robot1/odom", "robot1/base_link")
    assert math.hypot(first.pose.pose.position.x, first.pose.pose.position.y) < 1e-3
    assert gt[0].header.frame_id == "world" and gt[0].child_frame_id == "robot1/base_link"
    x0, y0, _ = load_world("living_room").robot("robot1").pose
    # the URDF: links in the bus's frames, wheel joints named as in joint_states
    robot = ET.fromstring(desc[0].data)
    links = {e.get("name") for e in robot.iter("link")}
    assert {"robot1/base_link", "robot1/left_wheel", "robot1/right_wheel", "robot1/caster",
            "robot1/laser", "robot1/camera", "robot1/camera_optical"} <= links
    kinds = {e.get("name"): e.get("type") for e in robot.iter("joint")}
    assert set(joints[0].name) <= {n for n, k in kinds.items() if k == "continuous"}
    # one type per topic, one bridge node
    # (the graph is discovered asynchronously: the bridge's subscriptions may come after its
    # publications have delivered)
    wanted = {"/robot1/cmd_vel", "/robot1/cmd_vel_unstamped"}
    wait_for(lambda: wanted <= set(dict(peer.node.get_topic_names_and_types())), 20,
             what="the bridge's cmd_vel topics in the ROS 2 graph")
    types = dict(peer.node.get_topic_names_and_types())
    assert types["/robot1/cmd_vel"] == ["geometry_msgs/msg/TwistStamped"]
    assert types["/robot1/cmd_vel_unstamped"] == ["geometry_msgs/msg/Twist"]
    # (node names are discovered on their own, after or before the topics)
    wait_for(lambda: any(n.startswith("ros2_bridge") for n in peer.node.get_node_names()), 20,
             what="the bridge node in the ROS 2 graph")
    assert [n for n in peer.node.get_node_names() if n.startswith("ros2_bridge")] == ["ros2_bridge"]
    # a teleop at rest says "stop" once and falls silent: nothing to warn about
    pub = peer.node.create_publisher(Twist, "/robot1/cmd_vel_unstamped",
                                     QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    wait_for(lambda: pub.get_subscription_count(), 20, what="the bridge's cmd_vel_unstamped")
    pub.publish(Twist())
    t_zero = codec.stamp_ns(gt[-1].header.stamp)
    wait_for(lambda: codec.stamp_ns(gt[-1].header.stamp) > t_zero + 1_500_000_000, 20,
             what="1.5 s of simulated time after a zero command")
    plant_log = out / "logs" / "plant.log"
    assert "no command for" not in plant_log.read_text()
    # drive away, then /reset_simulation puts it back: odometry at the origin again
    m = Twist()
    m.linear.x = 0.3
    sent = 0
    end = time.monotonic() + 2.0
    while time.monotonic() < end:
        pub.publish(m)
        sent += 1
        time.sleep(0.05)
    wait_for(lambda: odom[-1].pose.pose.position.x > 0.1, 10, what="odometry to move")
    assert gt[-1].pose.pose.position.x - x0 > 0.1
    client = peer.node.create_client(Empty, "/reset_simulation")
    assert client.wait_for_service(timeout_sec=20)
    n_before = len(odom)
    future = client.call_async(Empty.Request())
    wait_for(future.done, 20, what="/reset_simulation's answer")
    wait_for(lambda: len(odom) > n_before + 5 and abs(odom[-1].pose.pose.position.x) < 1e-3,
             20, what="odometry back at the origin after the reset")
    g = gt[-1].pose.pose.position
    assert math.hypot(g.x - x0, g.y - y0) < 0.01
    # Ctrl-C: clean, and the summary counts what the bridge put on the bus
    run.send_signal(signal.SIGINT)
    assert run.wait(60) == 130, procs.log(run)
    summary = json.load(open(out / "summary.json"))
    bridge = json.load(open(out / "logs" / "ros2_bridge.json"))
    assert summary["exit_codes"]["ros2_bridge"] == 0, summary
    assert summary["message_counts"]["robot1/cmd_vel"] == bridge["published"]["robot1/cmd_vel"]
    assert 0.8 * sent <= summary["message_counts"]["robot1/cmd_vel"] - 1 <= sent
    bridge_log = (out / "logs" / "ros2_bridge.log").read_text()
    assert "Traceback" not in bridge_log and "InvalidHandle" not in bridge_log, bridge_log
    assert "/reset_simulation: {\"ok\": true" in bridge_log
    assert "DDS never delivers" not in bridge_log, bridge_log    # the right types: no warning


def test_a_lockstep_ros2_node_started_late_that_waits_for_its_first_scan_runs_to_the_end(
        procs, tmp_path, monkeypatch):
    dom = domain_id(6)
    monkeypatch.setenv("ROS_DOMAIN_ID", str(dom))
    out = tmp_path / "late"
    run = procs.diffbot("run", "sim", "--mode", "lockstep", "--ros2", "--out", str(out),
                        "--timeout", "300", name="run")
    bridge_log = out / "logs" / "ros2_bridge.log"
    wait_for(lambda: bridge_log.exists() and "lockstep member" in bridge_log.read_text(), 60,
             what="the bridge in lockstep")
    # the node comes late: the bridge has handed tick 0's sensors over and waits for its
    # answer (said after 2 s of waiting) before the node exists
    wait = "waiting for a TwistStamped on /robot1/cmd_vel stamped t=0.000 s"
    wait_for(lambda: wait in bridge_log.read_text(), 60, what="the bridge to wait for tick 0")
    node = subprocess.run([sys.executable, AVOIDER, "--seconds", "3"], env=dict(
        os.environ, PYTHONUNBUFFERED="1"), capture_output=True, text=True, timeout=180)
    assert node.returncode == 0, node.stdout + node.stderr
    assert run.wait(120) == 0, procs.log(run)
    summary = json.load(open(out / "summary.json"))
    log = bridge_log.read_text()
    assert summary["end_reason"] == "plant: ros2_bridge finished", summary
    assert summary["sim_time_s"] >= 3.0, summary
    # every tick answered by the node: its commands went on the bus, counted
    assert summary["message_counts"]["robot1/cmd_vel"] >= 150, summary
    assert "waiting for a TwistStamped on /robot1/cmd_vel stamped t=0.000 s" in log, log
    assert "the ROS 2 controller answered (t=0.000 s)" in log, log

