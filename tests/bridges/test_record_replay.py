"""Recording the bus into MCAP, replaying it, and looking at a live bus (topics, echo)."""
from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import mcap.reader as mcap_reader
import pytest

from bus import codec
from bus.keys import Keys
from bridges.mcapfile import (INFO_METADATA, McapRecording, Recorded, RecordError, iter_recording,
                        layout, recover)

from ..conftest import ROOT, wait_for

K = Keys()

#: The drive test with the Python odometry node on the bus, short: every plant topic of
#: the empty world, a controller's wheel_cmd and a node's odom.
DRIVE_ODOM = """
[scenario]
description = "drive test with odometry, short"
world = "empty"
mode = "lockstep"
duration_s = 20.0

[[process]]
name = "odometry_robot1"
command = ["controller", "odometry", "--robot", "robot1"]

[[process]]
name = "wheel_schedule_robot1"
command = ["controller", "wheel_schedule", "--robot", "robot1", "--schedule", "1.5:1,1;1.5:1,-1"]
ends_run = true
"""


def diffbot(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "diffbot.cli", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def mcap_summary(file):
    """(schema name per topic, message count per topic, metadata records) via mcap's reader."""
    with open(file, "rb") as f:
        r = mcap_reader.make_reader(f)
        assert r.get_header().profile == "ros2"
        s = r.get_summary()
        types = {c.topic: s.schemas[c.schema_id].name for c in s.channels.values()
                 if c.topic not in DERIVED}
        counts = {c.topic: s.statistics.channel_message_counts.get(c.id, 0)
                  for c in s.channels.values() if c.topic not in DERIVED}
        assert {s.schemas[c.schema_id].encoding for c in s.channels.values()} == {"ros2msg"}
        assert {c.message_encoding for c in s.channels.values()} == {"cdr"}
        meta = {m.name: dict(m.metadata) for m in r.iter_metadata()}
    return types, counts, meta


#: what the recorder adds for 3-D viewers (bridges/scene.py; tested in tests/bridges/test_view.py)
class _Derived(frozenset):
    """What the recorder adds from sim/info (no bus keys): the scene, the transforms and
    each robot's ``/<robot>/robot_description``."""

    def __contains__(self, topic) -> bool:
        return super().__contains__(topic) or str(topic).endswith("/robot_description")


DERIVED = _Derived({"/scene", "/tf", "/tf_static"})


def rosbags_storage(file):
    """rosbags' own MCAP storage reader on a single file: {topic: (msgtype, count)}."""
    from rosbags.rosbag2.storage_mcap import McapReader
    r = McapReader(Path(file))
    r.open()
    try:
        return {c.topic: (c.msgtype, c.msgcount) for c in r.connections
                if c.topic not in DERIVED}
    finally:
        r.close()


def read_messages(path, topic=None):
    """[(key, log_time, sequence, data)] in file order."""
    rec = Recorded(str(path))
    out = [(rec.key_of(m.channel_id), m.log_time, m.sequence, m.data)
           for m in iter_recording(str(path), rec)]
    return [x for x in out if topic is None or x[0] == topic], rec


# ====================================================================== unit (no processes)
def test_layout_single_file_or_rosbag2_directory(tmp_path):
    assert layout(str(tmp_path / "run.mcap")) == (str(tmp_path / "run.mcap"), None)
    assert layout(str(tmp_path / "bag")) == (str(tmp_path / "bag" / "bag_0.mcap"),
                                             str(tmp_path / "bag"))


def _fill(rec: McapRecording, n: int, start: int = 0):
    for i in range(start, start + n):
        t = i * 20_000_000
        rec.write(K.topic("robot1", "gps"), "geometry_msgs/msg/PointStamped",
                  codec.encode(codec.point_stamped(t, i, 0, 0)), t, 1_700_000_000_000_000_000 + t,
                  2 * i)
        rec.write(K.clock, "rosgraph_msgs/msg/Clock", codec.encode(codec.clock(t)), t,
                  1_700_000_000_000_000_000 + t, 2 * i + 1)


def test_file_opens_in_mcap_and_rosbags_with_schemas_times_and_sequence(tmp_path):
    rec = McapRecording(str(tmp_path / "a.mcap"))
    rec.add_metadata(INFO_METADATA, {"sim_info": json.dumps({"mode": "lockstep"})})
    _fill(rec, 50)
    rec.close()
    types, counts, meta = mcap_summary(tmp_path / "a.mcap")
    assert types == {"/robot1/gps": "geometry_msgs/msg/PointStamped",
                     "/sim/clock": "rosgraph_msgs/msg/Clock"}
    assert counts == {"/robot1/gps": 50, "/sim/clock": 50}
    assert json.loads(meta[INFO_METADATA]["sim_info"]) == {"mode": "lockstep"}
    assert "serialized_metadata" in meta["rosbag2"]
    assert rosbags_storage(tmp_path / "a.mcap") == {
        "/robot1/gps": ("geometry_msgs/msg/PointStamped", 50),
        "/sim/clock": ("rosgraph_msgs/msg/Clock", 50)}
    msgs, _ = read_messages(tmp_path / "a.mcap", "robot1/gps")
    key, t, seq, data = msgs[7]
    assert (t, seq) == (7 * 20_000_000, 14)           # log time = sim stamp; seq kept
    assert codec.msg_stamp_ns(codec.decode(data, "geometry_msgs/msg/PointStamped")) == t


def test_a_stop_mid_stream_still_writes_what_is_queued(tmp_path):
    """A signal stops the recorder's loop while messages wait in its queue (Zenoh's thread
    queued them, the writing thread had not taken them yet): ``close()`` writes them all,
    in their order, before the footer."""
    import logging

    from bridges.record import Recorder
    out = McapRecording(str(tmp_path / "stop.mcap"))
    rec = Recorder(None, K, out, [K.all], logging.getLogger("test-recorder"))
    rec.with_scene = False
    gps = K.topic("robot1", "gps")
    for i in range(40):
        t = (i + 1) * 20_000_000
        rec.queue.put((gps, codec.encode(codec.point_stamped(t, i, 0, 0)),
                       codec.attachment(i, t, epoch=1), 1_700_000_000_000_000_000 + t))
    rec.stop_event.set()                       # what SIGINT/SIGTERM do (proc.stop_on_signals)
    rec.run()
    rec.close()
    msgs, _ = read_messages(tmp_path / "stop.mcap", gps)
    assert [(t, seq) for _, t, seq, _ in msgs] == [((i + 1) * 20_000_000, i) for i in range(40)]
    assert mcap_summary(tmp_path / "stop.mcap")[1] == {"/robot1/gps": 40}
    assert rec.stats()["messages"] == 40


def test_refuses_to_overwrite(tmp_path):
    (tmp_path / "a.mcap").write_bytes(b"x")
    with pytest.raises(RecordError, match="exists already"):
        McapRecording(str(tmp_path / "a.mcap"))


def test_unclosed_file_keeps_flushed_chunks_and_recovers(tmp_path):
    """What a SIGKILL leaves: every flushed chunk, no footer; replay reads it, recover fixes it."""
    rec = McapRecording(str(tmp_path / "bag"))
    _fill(rec, 40)
    rec.flush()                                       # what the recorder does every --flush s
    _fill(rec, 40, start=40)
    rec.flush()
    _fill(rec, 5, start=80)                           # still in the open chunk: lost
    killed = tmp_path / "killed"
    killed.mkdir()
    data = Path(rec.file).read_bytes()
    (killed / "killed_0.mcap").write_bytes(data + b"\x06\x40\x00")   # + a half-written record
    rec.close()
    with pytest.raises(Exception):                    # no footer: indexed readers refuse
        with open(killed / "killed_0.mcap", "rb") as f:
            list(mcap_reader.make_reader(f).iter_messages())
    msgs, r = read_messages(killed)
    assert len(msgs) == 160 and not r.complete and r.error
    assert recover(str(killed)) == {"robot1/gps": 80, "sim/clock": 80}
    types, counts, _ = mcap_summary(killed / "killed_0.mcap")
    assert counts == {"/robot1/gps": 80, "/sim/clock": 80}
    from rosbags.highlevel import AnyReader
    with AnyReader([killed], default_typestore=codec.TYPESTORE) as ar:   # metadata.yaml written
        assert {c.topic: c.msgcount for c in ar.connections} == {"/robot1/gps": 80,
                                                                  "/sim/clock": 80}


def test_replayer_serves_the_recorded_sim_info_or_makes_one_up(tmp_path):
    from bridges.replay import replay_info, scan
    rec = McapRecording(str(tmp_path / "a.mcap"))
    _fill(rec, 3)
    rec.close()
    info = replay_info(*scan(str(tmp_path / "a.mcap")), K, "fast", 0.0)
    assert info["mode"] == "fast" and info["synthesized"]
    assert info["robots"] == {"robot1": {"topics": {}}}
    assert info["control_tick_s"] == pytest.approx(0.02)
    rec = McapRecording(str(tmp_path / "b.mcap"))
    rec.add_metadata(INFO_METADATA, {"sim_info": json.dumps(
        {"mode": "lockstep", "robots": {"r2": {}}, "control_tick_s": 0.01})})
    _fill(rec, 3)
    rec.close()
    info = replay_info(*scan(str(tmp_path / "b.mcap")), K, "realtime", 2.0)
    assert (info["mode"], info["rate"], info["replay"]["recorded_mode"]) == (
        "realtime", 2.0, "lockstep")
    assert info["robots"] == {"r2": {}} and info["control_tick_s"] == 0.01


def test_echo_prints_readable_messages_with_large_arrays_summarised():
    from bridges.topics import format_message
    gps = codec.encode(codec.point_stamped(1_500_000_000, 1.25, -2.0, 0.0))
    text = format_message("robot1/gps", gps, codec.attachment(9, 1_500_000_000), K)
    assert text.splitlines()[0] == ("--- /robot1/gps  seq 9  t 1.500000 s  "
                                    "(geometry_msgs/msg/PointStamped)")
    assert "point: {x: 1.25, y: -2.0, z: 0.0}" in text
    import numpy as np
    img = codec.encode(codec.image(0, np.zeros((120, 160, 3), np.uint8)))
    text = format_message("robot1/camera/image_raw", img, None, K)
    assert "data: <uint8[57600]>" in text and len(text) < 1000


# ====================================================================== processes
@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory):
    """The drive test with odometry, recorded into a rosbag2 bag directory."""
    d = tmp_path_factory.mktemp("rec")
    (d / "drive_odom.toml").write_text(DRIVE_ODOM)
    t0 = time.monotonic()
    r = diffbot("run", str(d / "drive_odom.toml"), "--out", str(d / "out"),
                "--record", str(d / "out" / "bag"))
    assert r.returncode == 0, r.stderr
    return d / "out", time.monotonic() - t0


@pytest.mark.slow
def test_recorded_run_has_every_topic_and_the_runs_message_counts(recorded_run):
    out, _ = recorded_run
    summary = json.load(open(out / "summary.json"))
    expected = summary["message_counts"]
    assert set(expected) >= {"sim/clock", "robot1/joint_states", "robot1/gps",
                             "robot1/ground_truth", "robot1/odom", "robot1/wheel_cmd"}
    file, _ = layout(str(out / "bag"))
    types, counts, meta = mcap_summary(file)
    assert types == {f"/{k}": K.msgtype_of(k) for k in expected}
    assert counts == {f"/{k}": n for k, n in expected.items()}
    info = json.loads(meta[INFO_METADATA]["sim_info"])
    assert info["mode"] == "lockstep" and "robot1" in info["robots"]
    from rosbags.highlevel import AnyReader
    with AnyReader([out / "bag"], default_typestore=codec.TYPESTORE) as ar:
        assert {c.topic: (c.msgtype, c.msgcount) for c in ar.connections
                if c.topic not in DERIVED} == {
            f"/{k}": (K.msgtype_of(k), n) for k, n in expected.items()}
        seen = set()
        for conn, t, raw in ar.messages():        # every payload decodes; log time = stamp
            if conn.topic not in seen and conn.topic not in DERIVED:
                seen.add(conn.topic)
                assert codec.msg_stamp_ns(ar.deserialize(raw, conn.msgtype)) == t
        assert seen == set(types)
    assert json.load(open(out / "logs" / "recorder.json"))["rejected"] == {}
    assert summary["exit_codes"]["recorder"] == 0


@pytest.mark.slow
@pytest.mark.serial          # a node that falls 8 ticks behind a replay drops ticks (below)
def test_replayed_sensors_give_a_fresh_odometry_node_the_same_odom(recorded_run, procs, endpoint,
                                                                 tmp_path):
    """Odometry reads only the plant's sensors, which come before sim/clock in every tick, so
    the replayed bytes in their recorded order reproduce its output bit for bit.

    At a pace the node keeps up with: a replay waits for nobody (realtime and fast modes
    lose what a node cannot keep up with, docs/PROTOCOL.md), and a node more than 8 ticks
    behind drops the oldest (bus/member.py); --fast on a loaded machine did, 1 run in ~9.
    At 4x real time a tick is 5 ms of wall time, several times what the node needs."""
    out, _ = recorded_run
    replay = procs.diffbot("replay", str(out / "bag"), "--rate", "4", "--exclude", "robot1/odom",
                           "--expect", "odometry_robot1,tap", "--endpoint", endpoint,
                           name="replay")
    node = procs.diffbot("controller", "odometry", "--robot", "robot1", "--endpoint", endpoint,
                         name="odometry")
    tap = procs.diffbot("record", str(tmp_path / "again.mcap"), "robot1/odom", "--name", "tap",
                        "--endpoint", endpoint, name="tap")
    for p in (replay, node, tap):
        p.wait(60)
        assert p.returncode == 0, procs.log(p)
    original, _ = read_messages(out / "bag", "robot1/odom")
    again, _ = read_messages(tmp_path / "again.mcap", "robot1/odom")
    assert len(original) > 100
    replayed = {t: d for _, t, _, d in again}
    # The same bytes at every stamp of the original run (the replay may go on further: the
    # recording has the plant's last ticks, after the original node had been stopped).
    assert {t: replayed.get(t) for _, t, _, _ in original} == {t: d for _, t, _, d in original}
    assert "mode realtime" in procs.log(node)             # learnt from the replayer's sim/info


@pytest.mark.slow
def test_ctrl_c_to_the_launcher_leaves_a_complete_recording(tmp_path):
    out = tmp_path / "run"
    file = tmp_path / "run.mcap"
    p = subprocess.Popen([sys.executable, "-m", "diffbot.cli", "run", "drive-test", "--mode",
                          "realtime", "--out", str(out), "--record", str(file)], cwd=ROOT,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    try:
        plant_log = out / "logs" / "plant.log"
        wait_for(lambda: plant_log.exists() and "running" in plant_log.read_text(), 60,
                 what="the plant to start running")
        time.sleep(1.5)
        p.send_signal(signal.SIGINT)
        p.wait(30)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130
    summary = json.load(open(out / "summary.json"))
    types, counts, _ = mcap_summary(file)
    assert counts == {f"/{k}": n for k, n in summary["message_counts"].items()}
    assert counts["/sim/clock"] > 50                      # > 1 s at 50 Hz
    assert rosbags_storage(file) == {t: (types[t], n) for t, n in counts.items()}


@pytest.mark.serial                  # a wall-clock promise: runs alone under xdist
@pytest.mark.slow
def test_sigkill_loses_at_most_the_last_flush_period(procs, endpoint, tmp_path):
    plant = procs.diffbot("plant", "--world", "empty", "--mode", "realtime", "--endpoint",
                          endpoint, name="plant")
    rec = procs.diffbot("record", str(tmp_path / "k.mcap"), "--flush", "0.25", "--endpoint",
                        endpoint, name="rec")
    wait_for(lambda: "recording" in procs.log(rec), 60, what="the recorder to start")
    time.sleep(2.0)
    rec.send_signal(signal.SIGKILL)
    rec.wait(10)
    msgs, r = read_messages(tmp_path / "k.mcap")
    assert not r.complete                                 # no footer after a SIGKILL ...
    clock = [t for k, t, _, _ in msgs if k == "sim/clock"]
    assert (clock[-1] - clock[0]) * 1e-9 > 2.0 - 0.25 - 0.5   # ... but all but the last flush
    r2 = diffbot("record", "--recover", str(tmp_path / "k.mcap"))
    assert r2.returncode == 0, r2.stderr
    _, counts, _ = mcap_summary(tmp_path / "k.mcap")
    assert sum(counts.values()) == len([m for m in msgs if f"/{m[0]}" not in DERIVED])
    assert rosbags_storage(tmp_path / "k.mcap")["/sim/clock"][1] == len(clock)
    assert plant.poll() is None


@pytest.mark.serial                  # a wall-clock promise: runs alone under xdist
@pytest.mark.slow
def test_topics_and_echo_against_a_running_plant(procs, endpoint):
    plant = procs.diffbot("plant", "--world", "empty", "--mode", "realtime", "--endpoint",
                          endpoint, name="plant")
    wait_for(lambda: "running" in procs.log(plant), 60, what="the plant to start running")
    r = diffbot("topics", "--duration", "2", "--endpoint", endpoint)
    assert r.returncode == 0, r.stderr
    line = next(ln for ln in r.stdout.splitlines() if ln.startswith("robot1/joint_states "))
    key, msgtype, hz, sim_hz, count = line.split()
    assert msgtype == "sensor_msgs/msg/JointState"
    # 50 Hz of simulated time; per wall second the same, a realtime plant being paced to
    # the wall clock: 10 % for the 2 s window's edges, and 20 % below for a loaded machine
    assert float(sim_hz) == pytest.approx(50, abs=0.5)
    assert 50 * 0.8 < float(hz) < 50 * 1.1, hz
    assert "nodes alive: plant" in r.stdout
    r = diffbot("echo", "robot1/gps", "--count", "2", "--timeout", "30", "--endpoint", endpoint)
    assert r.returncode == 0, r.stderr
    blocks = [b for b in r.stdout.split("--- ") if b.strip()]
    assert len(blocks) == 2
    for b in blocks:
        assert re.match(r"/robot1/gps  seq \d+  t \d+\.\d{6} s  epoch 0  "
                        r"\(geometry_msgs/msg/PointStamped\)",
                        b)
        assert "frame_id: world" in b and re.search(r"point: \{x: \S+, y: \S+, z: \S+\}", b)


@pytest.mark.slow
@pytest.mark.serial          # a node that falls 8 ticks behind a replay drops ticks (below)
def test_replayed_camera_gives_a_fresh_follower_the_same_commands(procs, endpoint, tmp_path):
    """The follower reads only its camera (the plant's sensors, which come before sim/clock
    in every tick): a recorded lockstep follow run replayed into a fresh follower gives the
    same cmd_vel at every stamp as the original run.

    At 4x real time, as the odometry replay above: --fast on two xdist workers once left
    the follower's last 13 ticks without new frames (a node more than 8 ticks behind drops
    the oldest, bus/member.py)."""
    out = tmp_path / "out"
    r = diffbot("run", "follow", "--duration", "4", "--seed", "2", "--out", str(out),
                "--record", str(out / "follow.mcap"))
    assert r.returncode == 0, r.stderr
    replay = procs.diffbot("replay", str(out / "follow.mcap"), "--rate", "4",
                           "--keys", "sim/clock", "follower/camera/image_raw", "follower/camera/camera_info",
                           "--expect", "ball_follower_follower,tap", "--endpoint", endpoint,
                           name="replay")
    node = procs.diffbot("controller", "ball_follower", "--robot", "follower",
                         "--name", "ball_follower_follower", "--endpoint", endpoint,
                         name="follower")
    tap = procs.diffbot("record", str(tmp_path / "again.mcap"), "follower/cmd_vel", "--name",
                        "tap", "--endpoint", endpoint, name="tap")
    for p in (replay, node, tap):
        p.wait(60)
        assert p.returncode == 0, procs.log(p)
    original, _ = read_messages(out / "follow.mcap", "follower/cmd_vel")
    again, _ = read_messages(tmp_path / "again.mcap", "follower/cmd_vel")
    assert len(original) > 150
    replayed = {t: d for _, t, _, d in again}
    assert {t: replayed.get(t) for _, t, _, _ in original} == {t: d for _, t, _, d in original}
