"""One naming scheme: the same topic names and frames over ROS 2, in the live view (the
official Foxglove client, on the subprotocol docs/live-view.md names) and in an MCAP
recording of the same run (`diffbot run sim --ros2 --view --record`)."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess

import pytest

from bus import codec
from bridges.mcapfile import Recorded, iter_recording
from tests.conftest import ROOT, wait_for
from tests.bridges.test_ros2_bridge import Peer, _latched, domain_id
from tests.bridges.test_view import JS, _node_client

#: one xdist worker for the ROS 2 tests: their DDS domains are numbered per process
#: (ros2_peer); tests/bridges/test_ros2_bridge.py's group
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("square_seed0")]
rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable (the ros2 extra)")

#: what the plant and the odometry node publish for robot1, as topics under /robot1/
OUTPUTS = {"scan", "camera/image_raw", "camera/camera_info", "joint_states", "gps",
           "ground_truth", "odom", "robot_description"}
FRAMES = {"scan": "robot1/laser", "camera/image_raw": "robot1/camera_optical",
          "camera/camera_info": "robot1/camera_optical", "odom": "robot1/odom",
          "ground_truth": "world", "gps": "world"}


def test_same_names_and_frames_over_ros2_in_foxglove_and_in_the_recording(
        procs, endpoint, tmp_path, monkeypatch):
    node = _node_client()
    pytest.importorskip("foxglove")
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image, LaserScan
    from std_msgs.msg import String
    dom = domain_id(7)
    monkeypatch.setenv("ROS_DOMAIN_ID", str(dom))
    out, mcap = tmp_path / "sim", tmp_path / "sim.mcap"
    run = procs.diffbot("run", "sim", "--ros2", "--view", "--view-port", "0", "--record",
                        str(mcap), "--endpoint", endpoint, "--out", str(out), "--timeout", "300",
                        name="run")
    view_log = out / "logs" / "view.log"
    url = wait_for(lambda: view_log.exists() and (re.search(
        r"ws://127\.0\.0\.1:\d+", view_log.read_text()) or [None])[0], 60, what="the view")
    assert "subprotocol foxglove.sdk.v1" in view_log.read_text()
    # over ROS 2
    peer = Peer(dom)
    try:
        ros: dict[str, str] = {}
        for topic, cls in (("scan", LaserScan), ("camera/image_raw", Image),
                           ("camera/camera_info", CameraInfo), ("odom", Odometry),
                           ("ground_truth", Odometry)):
            peer.node.create_subscription(cls, f"/robot1/{topic}", lambda m, t=topic: ros.setdefault(
                t, m.header.frame_id), qos_profile_sensor_data)
        urdf_ros: list[str] = []
        peer.node.create_subscription(String, "/robot1/robot_description",
                                      lambda m: urdf_ros.append(m.data), _latched())
        wait_for(lambda: len(ros) == 5 and urdf_ros, 60, what="robot1's topics over ROS 2")

        def graph() -> set[str]:
            return {n[len("/robot1/"):] for n, _ in peer.node.get_topic_names_and_types()
                    if n.startswith("/robot1/")}
        # the bridge's command subscriptions reach a peer's graph by DDS discovery, which
        # may come after the first samples of its publishers (seen under load)
        ros_topics = wait_for(lambda: (g := graph()) >= OUTPUTS | {"cmd_vel", "cmd_vel_unstamped"}
                              and g, 30, what="robot1's topics and commands in the ROS 2 graph")
    finally:
        peer.close()
    # in Foxglove (the official client, asking for the subprotocol the docs name)
    res = tmp_path / "client.json"
    r = subprocess.run([node, os.path.join(JS, "view_client.mjs"), url, "robot1", str(res),
                        "reset"], cwd=JS, capture_output=True, text=True, timeout=90)
    assert r.returncode == 0, r.stdout + r.stderr + (res.read_text() if res.exists() else "")
    fox = json.loads(res.read_text())
    run.send_signal(signal.SIGINT)
    assert run.wait(60) == 130, procs.log(run)
    assert fox["subprotocol"] == "foxglove.sdk.v1"
    view_topics = {c["topic"][len("/robot1/"):] for c in fox["channels"]
                   if c["topic"].startswith("/robot1/")}
    # in the recording
    rec = Recorded(str(mcap))
    rec_frames: dict[str, str] = {}
    tf_static = urdf_rec = None
    for msg in iter_recording(str(mcap), rec):
        topic = rec.key_of(msg.channel_id)
        schema = rec.schemas[rec.channels[msg.channel_id].schema_id].name
        if topic == "tf_static" and tf_static is None:
            tf_static = codec.decode(msg.data, schema)
        elif topic == "robot1/robot_description":
            urdf_rec = codec.decode(msg.data, schema).data
        elif topic.startswith("robot1/") and topic[7:] in FRAMES and topic[7:] not in rec_frames:
            rec_frames[topic[7:]] = codec.decode(msg.data, schema).header.frame_id
    rec_topics = {c.topic.lstrip("/")[len("robot1/"):] for c in rec.channels.values()
                  if c.topic.lstrip("/").startswith("robot1/")}
    # the same names everywhere ...
    assert OUTPUTS <= ros_topics and OUTPUTS <= view_topics and OUTPUTS <= rec_topics, \
        (ros_topics, view_topics, rec_topics)
    assert "cmd_vel" in ros_topics and "cmd_vel_unstamped" in ros_topics
    # ... only what the scenario has (no follower here) ...
    assert not {"follower/debug", "camera/image_annotated", "camera/image",
                "camera/info"} & (view_topics | ros_topics | rec_topics)
    # ... the same frames everywhere
    for topic in ("scan", "camera/image_raw", "camera/camera_info", "odom", "ground_truth"):
        assert ros[topic] == rec_frames[topic] == FRAMES[topic], (topic, ros, rec_frames)
    assert fox["scans"][0]["frame_id"] == "robot1/laser"
    assert fox["image"]["frame_id"] == "robot1/camera_optical"
    assert (fox["odom"]["frame_id"], fox["odom"]["child_frame_id"]) == \
        ("robot1/odom", "robot1/base_link")
    static = {(p, c) for p, c in fox["tf_static"]}
    assert {("world", "robot1/odom"), ("robot1/base_link", "robot1/laser"),
            ("robot1/camera", "robot1/camera_optical")} <= static
    assert static == {(t.header.frame_id, t.child_frame_id) for t in tf_static.transforms}
    assert fox["robot_description"] == urdf_ros[0] == urdf_rec
    assert fox["moved_m"] > 0.1                     # the Teleop panel's Twist drove it
    # ... and the Service Call panel's /reset_simulation put it back at its start pose
    from plant.world import load_world
    x0, y0, _ = load_world("living_room").robot("robot1").pose
    assert fox["reset_response"]["encoding"] == "cdr"
    for _, x, y in fox["after_reset"]:
        assert abs(x - x0) < 0.01 and abs(y - y0) < 0.01, fox["after_reset"]
