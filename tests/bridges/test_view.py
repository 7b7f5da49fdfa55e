"""The live view (`diffbot view`) and the 3-D scene it shares with recordings.

The multi-process test drives the view with the real Foxglove JS client under Node
(tests/js, installed by `make setup` with `npm ci`).
"""
from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
import types

import numpy as np
import pytest

from bridges import scene
from bus import codec
from bus.keys import Keys

from ..conftest import ROOT, wait_for

K = Keys()
JS = os.path.join(ROOT, "tests", "js")


def _info(world: str) -> dict:
    from plant.sim import Simulation
    from plant.world import load_world
    return Simulation(load_world(world)).describe()


def _quat_yaw(q) -> float:
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))


def test_scene_has_every_world_object_with_its_size_pose_and_colour():
    from plant.world import load_world
    spec = load_world("living_room_follow")
    markers = scene.scene(_info("living_room_follow")).markers
    world = {m.text: m for m in markers if m.ns == "world"}
    walls = {"floor", "wall_front", "wall_back", "wall_left", "wall_right"}
    assert set(world) == walls | {o.name for o in spec.objects}
    assert len(world) == len([m for m in markers if m.ns == "world"])     # one each
    lx, ly = spec.floor_size_m
    assert (world["floor"].scale.x, world["floor"].scale.y) == (lx, ly)
    assert world["floor"].pose.position.z + world["floor"].scale.z / 2 == pytest.approx(0.0)
    assert world["wall_left"].pose.position.y > ly / 2
    for o in spec.objects:
        m = world[o.name]
        assert m.header.frame_id == "world"
        assert m.type == {"box": m.CUBE, "cylinder": m.CYLINDER, "sphere": m.SPHERE}[o.shape]
        if o.shape == "box":
            want = o.size
        elif o.shape == "cylinder":
            want = (2 * o.size[0], 2 * o.size[0], o.size[1])
        else:
            want = (2 * o.size[0],) * 3
        assert (m.scale.x, m.scale.y, m.scale.z) == pytest.approx(want)
        p = m.pose.position
        assert (p.x, p.y, p.z) == pytest.approx(o.pose[:3])
        assert _quat_yaw(m.pose.orientation) == pytest.approx(o.pose[3])
        assert (m.color.r, m.color.g, m.color.b, m.color.a) == pytest.approx((*o.color, 1.0))
    # Robots: chassis, two wheels, caster and the leader's ball post and green ball, each in
    # the robot's own frame so it moves with /tf.
    leader = {m.text: m for m in markers if m.ns == "leader"}
    assert set(leader) == {"leader_chassis", "leader_caster", "leader_left_wheel_visual",
                           "leader_right_wheel_visual", "leader_ball_post", "leader_green_ball"}
    ball = leader["leader_green_ball"]
    part = next(p for p in spec.robot("leader").parts if p.name == "green_ball")
    assert ball.header.frame_id == "leader/base_link" and ball.frame_locked
    assert (ball.pose.position.x, ball.pose.position.y, ball.pose.position.z) == \
        pytest.approx(part.pose[:3])
    assert (ball.color.r, ball.color.g, ball.color.b) == pytest.approx(part.color)
    assert ball.scale.x == pytest.approx(2 * part.size[0])
    wheel = leader["leader_left_wheel_visual"]        # axle along y: a cylinder rolled 90 deg
    assert wheel.pose.position.y == pytest.approx(spec.robot("leader").drive.wheel_separation_m / 2)
    assert abs(wheel.pose.orientation.x) == pytest.approx(math.sqrt(0.5))
    # It survives CDR (what goes to Foxglove and into recordings).
    again = codec.decode(codec.encode(scene.scene(_info("living_room_follow"))), scene.SCENE_TYPE)
    assert [m.text for m in again.markers] == [m.text for m in markers]


def test_sensor_frames_sit_at_their_mounts_and_odom_at_the_start_pose():
    from plant.world import load_world
    spec = load_world("living_room")
    info = _info("living_room")
    tfs = {t.child_frame_id: t for t in scene.static_tf(info).transforms}
    lidar, cam = spec.robot("robot1").sensors.lidar, spec.robot("robot1").sensors.camera
    laser = tfs["robot1/laser"]
    assert laser.header.frame_id == "robot1/base_link"
    assert (laser.transform.translation.x, laser.transform.translation.z) == \
        pytest.approx((lidar.mount_x_m, lidar.mount_z_m))
    assert tfs["robot1/camera"].transform.translation.x == pytest.approx(cam.mount_x_m)
    assert tfs["robot1/camera_optical"].header.frame_id == "robot1/camera"
    # REP 105: world -> robot1/odom is the start pose; no bare frames any more
    odom = tfs["robot1/odom"]
    x0, y0, yaw0 = spec.robot("robot1").pose
    assert odom.header.frame_id == "world"
    assert (odom.transform.translation.x, odom.transform.translation.y) == (x0, y0)
    assert codec.quaternion_to_yaw(odom.transform.rotation) == pytest.approx(yaw0)
    assert not {"laser", "camera", "odom", "base_link"} & set(tfs)
    assert scene.to_world((x0, y0, yaw0), 0.0, 0.0, 0.0) == (x0, y0, yaw0)
    gt = codec.odometry(40_000_000, 1.0, -2.0, 0.3, 0.0, 0.0, frame_id="world", z=0.12)
    t = scene.ground_truth_transform("robot1", gt)
    assert (t.header.frame_id, t.child_frame_id) == ("world", "robot1/base_link")
    assert (t.transform.translation.x, t.transform.translation.y) == (1.0, -2.0)
    assert codec.stamp_ns(t.header.stamp) == 40_000_000


def test_teleop_twist_parsing_cdr_json_and_bad_input():
    pytest.importorskip("foxglove")
    from bridges.view_clients import parse_twist
    tw = codec.T["geometry_msgs/msg/Twist"]
    v3 = codec.T["geometry_msgs/msg/Vector3"]
    cdr = codec.encode(tw(linear=v3(x=0.3, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=-0.5)))
    assert parse_twist(cdr, "cdr", "geometry_msgs/msg/Twist") == (0.3, -0.5)
    stamped = codec.encode(codec.twist_stamped(0, 0.2, 0.1))
    assert parse_twist(stamped, "cdr", "geometry_msgs/msg/TwistStamped") == (0.2, 0.1)
    js = json.dumps({"linear": {"x": 0.1, "y": 0, "z": 0}, "angular": {"x": 0, "y": 0, "z": 1}})
    assert parse_twist(js.encode(), "json", "geometry_msgs/Twist") == (0.1, 1.0)
    for data, enc, schema in ((b"\x00\x01", "cdr", "geometry_msgs/msg/Twist"),
                              (b"{}", "json", "geometry_msgs/msg/Twist"),
                              (b'{"linear": {"x": NaN}, "angular": {"z": 0}}', "json", ""),
                              (cdr, "protobuf", "geometry_msgs/msg/Twist"),
                              (cdr, "cdr", "sensor_msgs/msg/Image")):
        with pytest.raises(ValueError):
            parse_twist(data, enc, schema)


def _node_client():
    node = shutil.which("node")
    if node is None:
        pytest.skip("node (Node.js >= 18) is not installed: the Foxglove client tests need it")
    if not os.path.isdir(os.path.join(JS, "node_modules", "@foxglove", "ws-protocol")):
        pytest.skip("tests/js/node_modules missing: run `make setup` (npm ci in tests/js)")
    return node


@pytest.mark.slow
def test_foxglove_client_sees_scan_image_scene_drives_and_reconnects(procs, endpoint, bus,
                                                                     tmp_path):
    node = _node_client()
    pytest.importorskip("foxglove")
    plant = procs.diffbot("plant", "--world", "living_room", "--mode", "realtime",
                          "--endpoint", endpoint, name="plant")
    s = bus()
    scans: dict[int, np.ndarray] = {}
    clock: list[int] = []

    def on_scan(sample):
        m = codec.decode(sample.payload.to_bytes(), "sensor_msgs/msg/LaserScan")
        scans[codec.stamp_ns(m.header.stamp)] = np.array(m.ranges)

    def on_clock(sample):
        clock.append(codec.parse_attachment(sample.attachment.to_bytes())[1])
    subs = [s.declare_subscriber(K.topic("robot1", "scan"), on_scan),
            s.declare_subscriber(K.clock, on_clock)]
    stats = tmp_path / "view.json"
    view = procs.diffbot("view", "--port", "0", "--endpoint", endpoint, "--stats", str(stats),
                         "--image-rate", "5", name="view")
    view_started = time.monotonic()
    url = wait_for(lambda: (re.search(r"ws://127\.0\.0\.1:\d+", procs.log(view)) or [None])[0],
                   30, what="the view to serve")

    def client(phase: str) -> dict:
        out = tmp_path / f"{phase}.json"
        r = subprocess.run([node, os.path.join(JS, "view_client.mjs"), url, "robot1", str(out),
                            phase], cwd=JS, capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stdout + r.stderr + (out.read_text() if out.exists() else "")
        return json.loads(out.read_text())

    got = client("full")
    topics = {c["topic"]: c for c in got["channels"]}
    assert {"/robot1/scan", "/robot1/camera/image_raw", "/robot1/ground_truth", "/scene", "/tf",
            "/tf_static"} <= set(topics)
    assert all(c["encoding"] == "cdr" and c["schemaEncoding"] == "ros2msg"
               for c in topics.values())
    assert "clientPublish" in got["server"]["capabilities"]
    # LaserScan: the bus's 180 ranges for the same stamp, in the robot's laser frame
    for sc in got["scans"]:
        bus_ranges = scans[sc["stamp"]]
        assert len(sc["ranges"]) == len(bus_ranges) == 180
        js = np.array([np.inf if r is None else r for r in sc["ranges"]], dtype=np.float32)
        np.testing.assert_array_equal(js, bus_ranges)
        assert sc["frame_id"] == "robot1/laser"
    img = got["image"]
    assert (img["width"], img["height"], img["encoding"], img["bytes"]) == (160, 120, "rgb8",
                                                                           160 * 120 * 3)
    assert img["sum"] > 0
    # Scene: one entity per world object (and one per robot part)
    info = _info("living_room")
    world = [m for m in got["scene"] if m["ns"] == "world"]
    assert sorted(m["name"] for m in world) == sorted(o["name"] for o in info["objects"])
    assert len(world) == len(info["objects"])
    assert {m["name"] for m in got["scene"] if m["ns"] == "robot1"} == \
        {b["name"] for b in info["robots"]["robot1"]["body"]}
    # Teleop: a Twist published as the Teleop panel does moves the robot
    assert got["twists_sent"] >= 1 and got["moved_m"] > 0.1
    # Disconnected (the client exited) and connect again: the run goes on, unnoticed
    n0 = len(clock)
    again = client("receive")
    assert again["scene"] and again["scans"] and again["tf"] > 0
    assert plant.poll() is None and view.poll() is None
    assert len(clock) > n0
    assert np.all(np.diff(clock) > 0)               # sim time went on, never back
    assert "error" not in procs.log(plant).lower()
    for sub in subs:
        sub.undeclare()
    view.send_signal(2)
    view.wait(10)
    view_s = time.monotonic() - view_started
    assert view.returncode == 0, procs.log(view)
    st = json.loads(stats.read_text())
    assert st["teleop_messages"] == got["twists_sent"] and st["rejected"] == {}
    # the camera renders 25 frames per second; the view sent at most --image-rate 5 of them
    assert 0 < st["sent"]["/robot1/camera/image_raw"] <= 5 * view_s + 2


@pytest.mark.slow
def test_recording_holds_the_scene_and_a_transform_per_ground_truth(procs, endpoint, tmp_path):
    from bridges.mcapfile import Recorded, iter_recording
    plant = procs.diffbot("plant", "--world", "living_room", "--mode", "fast", "--duration", "1",
                          "--expect", "recorder", "--endpoint", endpoint, name="plant")
    rec = procs.diffbot("record", str(tmp_path / "r.mcap"), "--endpoint", endpoint,
                        name="recorder")
    assert plant.wait(60) == 0, procs.log(plant)
    assert rec.wait(30) == 0, procs.log(rec)
    r = Recorded(str(tmp_path / "r.mcap"))
    by_topic: dict[str, list] = {}
    for m in iter_recording(str(tmp_path / "r.mcap"), r):
        by_topic.setdefault(r.channels[m.channel_id].topic, []).append(m)
    types = {c.topic: r.schemas[c.schema_id].name for c in r.channels.values()}
    assert types["/scene"] == "visualization_msgs/msg/MarkerArray"
    assert types["/tf"] == "tf2_msgs/msg/TFMessage" == types["/tf_static"]
    assert len(by_topic["/scene"]) == 1 and len(by_topic["/tf_static"]) == 1
    sc = codec.decode(by_topic["/scene"][0].data, scene.SCENE_TYPE)
    info = _info("living_room")
    assert [m.text for m in sc.markers if m.ns == "world"] == [o["name"] for o in info["objects"]]
    gts = by_topic["/robot1/ground_truth"]
    tfs = by_topic["/tf"]
    assert len(tfs) == len(gts) >= 50
    for g, t in zip(gts[-5:], tfs[-5:]):
        gt = codec.decode(g.data, "nav_msgs/msg/Odometry")
        tr = codec.decode(t.data, scene.TF_TYPE).transforms[0]
        assert t.log_time == g.log_time == codec.stamp_ns(tr.header.stamp)
        assert tr.child_frame_id == "robot1/base_link"
        assert tr.transform.translation.x == gt.pose.pose.position.x


@pytest.mark.slow
def test_run_with_view_starts_it_first_and_stops_it_cleanly(tmp_path):
    pytest.importorskip("foxglove")
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m",
                        "diffbot.cli", "run", "drive-test", "--view", "--view-port", "0",
                        "--duration", "1", "--out", str(out)], cwd=ROOT, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["exit_codes"]["view"] == 0
    log = (out / "logs" / "view.log").read_text()
    assert re.search(r"serving ws://127\.0\.0\.1:\d+", log)
    assert json.loads((out / "logs" / "view.json").read_text())["rejected"] == {}


def test_shipped_layout_names_only_channels_the_view_serves():
    pytest.importorskip("foxglove")
    import logging

    from bridges.view import NODE_TOPICS, View
    layout = json.loads(open(os.path.join(ROOT, "bridges", "foxglove_layout.json")).read())
    panels = set()

    def walk(node):
        if isinstance(node, str):
            panels.add(node)
        else:
            walk(node["first"])
            walk(node["second"])
    walk(layout["layout"])
    assert panels == set(layout["configById"])
    served = set()
    for world in ("living_room", "living_room_follow"):
        v = View(None, K, logging.getLogger("test"))
        info = _info(world)
        # the scenarios' nodes have spoken (the view advertises their topics only then)
        v._found = {K.topic(r, t) for r in info["robots"] for t in NODE_TOPICS}
        v.load_info(info)
        served |= set(v._deps)
    named = set(re.findall(r'"(/[A-Za-z0-9_/]+)', json.dumps(layout["configById"])))
    publish_only = {"/move_base_simple/goal", "/clicked_point", "/initialpose",
                    "/robot1/cmd_vel_unstamped"}
    assert named - publish_only <= served, named - publish_only - served
    assert layout["configById"]["Teleop!drive"]["topic"] == "/robot1/cmd_vel_unstamped"
    # the robots are drawn from their URDF (robot_description), as the view serves it
    urdfs = {la["topic"] for la in layout["configById"]["3D!room"]["layers"].values()
             if la["layerId"] == "foxglove.Urdf"}
    assert urdfs == {"/robot1/robot_description", "/leader/robot_description",
                     "/follower/robot_description"} and urdfs <= served


def test_view_advertises_node_topics_only_once_a_node_published_them():
    pytest.importorskip("foxglove")
    import logging

    from bridges.view import View

    class Session:                     # the probes' subscribers, not a bus
        def declare_subscriber(self, key, handler):
            return types.SimpleNamespace(undeclare=lambda: None)
    v = View(Session(), K, logging.getLogger("test"))
    v.load_info(_info("living_room"))
    assert "/robot1/scan" in v._deps and "/robot1/robot_description" in v._deps
    assert not {"/robot1/odom", "/robot1/follower/debug", "/robot1/camera/image_annotated",
                "/robot1/path/odom"} & set(v._deps)
    v.found(K.topic("robot1", "odom"))
    assert {"/robot1/odom", "/robot1/path/odom", "/robot1/metrics/odometry_error_m"} <= set(v._deps)
    assert "/robot1/camera/image_annotated" not in v._deps
