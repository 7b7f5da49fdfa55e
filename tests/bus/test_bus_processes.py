"""Real processes on a real Zenoh bus: lockstep, realtime watchdog, bad commands, queryables."""
from __future__ import annotations

import functools
import json
import math
import os
import signal
import threading
import time

import numpy as np
import pytest
import zenoh

from bus import codec
from bus.keys import Keys

from ..conftest import SLACK_S, wait_for

pytestmark = pytest.mark.slow
K = Keys()


class Tap:
    """Collects decoded ground truth and clock ticks (with wall arrival times) in the test."""

    def __init__(self, session, robot="robot1"):
        self.lock = threading.Lock()
        self.clock: list[tuple[float, int]] = []
        self.gt: list = []
        self.subs = [
            session.declare_subscriber(K.clock, self._on_clock),
            session.declare_subscriber(K.topic(robot, "ground_truth"), self._on_gt),
        ]

    def _on_clock(self, s):
        t = codec.msg_stamp_ns(codec.decode(s.payload.to_bytes(), "rosgraph_msgs/msg/Clock"))
        with self.lock:
            self.clock.append((time.monotonic(), t))

    def _on_gt(self, s):
        m = codec.decode(s.payload.to_bytes(), "nav_msgs/msg/Odometry")
        with self.lock:
            self.gt.append(m)

    def last_t(self) -> int:
        with self.lock:
            return self.clock[-1][1] if self.clock else -1

    def speed_at(self, t_ns: int) -> float:
        with self.lock:
            for m in self.gt:
                if codec.msg_stamp_ns(m) >= t_ns:
                    return abs(m.twist.twist.linear.x)
        return math.nan


def plant(procs, endpoint, tmp_path, *extra, world="empty"):
    stats = str(tmp_path / "plant.json")
    p = procs.diffbot("plant", "--world", world, "--endpoint", endpoint, "--stats", stats,
                      *extra, name="plant")
    p.stats_path = stats
    return p


@pytest.mark.serial                  # a wall-clock promise: runs alone under xdist
def test_lockstep_member_killed_leaves_sync_set_at_once(procs, endpoint, bus, tmp_path):
    # the controller is not --expect'ed: dropped when it goes, not lost (an expected one
    # ends the run: tests/runs/test_faults.py)
    p = plant(procs, endpoint, tmp_path, "--mode", "lockstep", "--expect", "odometry_robot1")
    s = bus()
    tap = Tap(s)
    procs.diffbot("controller", "odometry", "--endpoint", endpoint, name="odo")
    ctrl = procs.diffbot("controller", "wheel_schedule", "--schedule", "1000:2,2",
                         "--endpoint", endpoint, name="ctrl")
    wait_for(lambda: tap.last_t() > 2e9, 60, what="lockstep run to reach t=2 s")
    # the run does not wait for it (not --expect'ed): on a loaded machine it may join late
    wait_for(lambda: "lockstep member joined: wheel_schedule_robot1" in procs.log(p), 60,
             what="the controller to join")
    ctrl.send_signal(signal.SIGKILL)
    killed = time.monotonic()
    ctrl.wait(5)
    # The plant goes on with the remaining member (the odometry node).
    t_at_kill = tap.last_t()
    wait_for(lambda: tap.last_t() > t_at_kill + 200_000_000, 10, what="ticks after the kill")
    with tap.lock:
        gaps = [w for w, t in tap.clock if w > killed]
    # a killed member's socket closes at once: the plant does not wait for its 1 s lease
    # (one tick, 20 ms, plus the documented scheduling slack; still below the lease)
    assert gaps[0] - killed < 0.02 + SLACK_S < 1.0, \
        f"plant resumed {gaps[0] - killed:.3f} s after the kill"
    assert p.poll() is None
    assert "lockstep member lost: wheel_schedule_robot1" in procs.log(p)
    assert "the others go on without it" in procs.log(p)


@pytest.mark.serial                  # a wall-clock promise: runs alone under xdist
def test_realtime_watchdog_stops_robot_after_cmd_timeout(procs, endpoint, bus, tmp_path):
    plant(procs, endpoint, tmp_path, "--mode", "realtime")
    s = bus()
    tap = Tap(s)
    ctrl = procs.diffbot("controller", "wheel_schedule", "--schedule", "1000:3,3",
                         "--endpoint", endpoint, name="ctrl")
    # driving, then 0.5 s more for the ramp: a realtime plant does not wait for a controller
    # that a loaded machine starts late (t > 1.5 s alone once found the robot still at rest)
    driving = wait_for(lambda: tap.last_t() > 1.5e9 and tap.speed_at(tap.last_t()) > 0.3
                       and tap.last_t(), 30, what="robot driving")
    wait_for(lambda: tap.last_t() > driving + 0.5e9, 10, what="0.5 s of driving")
    assert tap.speed_at(tap.last_t()) == pytest.approx(0.36, rel=0.05)
    ctrl.send_signal(signal.SIGKILL)
    t_kill = tap.last_t()
    wait_for(lambda: tap.last_t() > t_kill + 1.2e9, 10, what="sim to run on")
    # cmd_timeout 0.5 s, then the drive's deceleration limit brings it to rest.
    assert tap.speed_at(t_kill + 300_000_000) > 0.3          # held the last command meanwhile
    assert tap.speed_at(t_kill + 700_000_000) < 0.005


def test_bad_commands_are_counted_and_never_reach_the_physics(procs, endpoint, bus, tmp_path):
    p = plant(procs, endpoint, tmp_path, "--mode", "fast")
    s = bus()
    tap = Tap(s)
    wait_for(lambda: tap.last_t() > 0, 30, what="plant ticking")
    key = K.topic("robot1", "cmd_vel")
    rng = np.random.default_rng(0)
    good = codec.encode(codec.twist_stamped(0, 0.2, 0.0))
    bad = [bytes(rng.integers(0, 256, n, dtype=np.uint8)) for n in (0, 3, 17, 64, 300)]
    bad += [good[:10], codec.encode(codec.twist_stamped(0, math.nan, 0.0)),
            codec.encode(codec.twist_stamped(0, 0.1, math.inf)),
            codec.encode(codec.twist_stamped(0, 1e9, 0.0)),
            codec.encode(codec.twist_stamped(0, -1e300, 1e300))]
    wheel_bad = [codec.encode(codec.joint_state(0, ["a", "b"], velocity=[1, 1])),
                 codec.encode(codec.joint_state(0, [], velocity=[1.0])),
                 codec.encode(codec.joint_state(0, [], velocity=[math.nan, 1.0]))]
    # BLOCK: a burst of puts from a session on a loaded machine is otherwise dropped by
    # Zenoh at the sender (its default congestion control), and the counts below would lie
    put = functools.partial(s.put, congestion_control=zenoh.CongestionControl.BLOCK)
    for _ in range(3):
        for b in bad:
            put(key, b)
            put(key, good)                # good commands interleaved keep working
        for b in wheel_bad:
            put(K.topic("robot1", "wheel_cmd"), b)
    # Last, a faster command: once the robot goes faster than any good one took it, the
    # plant has taken everything before it (one session's samples arrive in order); a
    # fast-mode plant can run 2 s ahead before a loaded machine delivers the burst.
    put(key, codec.encode(codec.twist_stamped(0, 0.6, 0.0)))

    def sentinel_acted() -> bool:
        with tap.lock:
            return any(m.twist.twist.linear.x > 0.45 for m in tap.gt)
    wait_for(sentinel_acted, 30, what="the last command to act")
    t0 = tap.last_t()
    wait_for(lambda: tap.last_t() > t0 + 2e9, 30, what="plant to keep running")
    assert p.poll() is None
    with tap.lock:
        last = tap.gt[-1]
    pos = last.pose.pose.position
    assert all(math.isfinite(v) for v in (pos.x, pos.y, pos.z))
    p.send_signal(signal.SIGINT)
    p.wait(10)
    stats = json.load(open(p.stats_path))
    rejected = stats["rejected"]
    assert rejected.get("robot1/cmd_vel", 0) == 3 * len(bad)
    assert rejected.get("robot1/wheel_cmd", 0) == 3 * len(wheel_bad)
    assert "rejected robot1/cmd_vel" in procs.log(p)        # logged, rate-limited
    assert procs.log(p).count("rejected robot1/cmd_vel") < 10
    assert pos.x > 0.01                                      # the good commands moved it


@pytest.mark.parametrize("physics", ["in the plant", "own process"])
def test_info_and_reset_queryables(procs, endpoint, bus, tmp_path, physics):
    extra = ("--physics-process",) if physics == "own process" else ()
    plant(procs, endpoint, tmp_path, "--mode", "fast", *extra, world="living_room")
    s = bus()

    def query(key, payload=None):
        replies = list(s.get(key, payload=payload, timeout=5.0))
        assert replies, f"no reply on {key}"
        r = replies[0]
        return (True, json.loads(r.ok.payload.to_bytes())) if r.ok is not None else \
            (False, json.loads(r.err.payload.to_bytes()))

    ok, info = wait_for(lambda: _try(lambda: query(K.info)), 30, what="sim/info")
    assert ok and info["mode"] == "fast" and "robot1" in info["robots"]
    assert info["robots"]["robot1"]["wheel_radius_m"] == 0.12
    assert any(o["name"] == "sofa_seat" for o in info["objects"])
    ok, rep = query(K.reset, json.dumps({"seed": 5, "poses": {"robot1": [0.5, 0.5, 1.0]}}))
    assert ok and rep["seed"] == 5
    tap = Tap(s)
    wait_for(lambda: tap.gt, 10, what="ground truth after reset")
    with tap.lock:
        m = tap.gt[-1]
    assert m.pose.pose.position.x == pytest.approx(0.5, abs=0.01)
    assert codec.quaternion_to_yaw(m.pose.pose.orientation) == pytest.approx(1.0, abs=0.01)
    ok, rep = query(K.reset, json.dumps({"poses": {"nobody": [0, 0, 0]}}))
    assert not ok and "unknown robot" in rep["error"]
    ok, rep = query(K.reset, b"{not json")
    assert not ok


def _try(f):
    try:
        return f()
    except AssertionError:
        return None


def test_user_zenoh_config_passes_through_a_router(procs, tmp_path, endpoint):
    """Plant and controller as clients of a separate router, configured by the user's file."""
    ep = endpoint
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([ep]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    router = zenoh.open(conf)
    try:
        client = tmp_path / "client.json5"
        client.write_text('{ mode: "client", connect: { endpoints: ["%s"] },\n'
                          '  listen: { endpoints: [] },\n'
                          '  scouting: { multicast: { enabled: false }, gossip: { enabled: false } } }\n'
                          % ep)
        p = procs.diffbot("plant", "--world", "empty", "--zenoh-config", str(client),
                          "--duration", "3", "--stats", str(tmp_path / "plant.json"), name="plant")
        c = procs.diffbot("controller", "wheel_schedule", "--schedule", "100:2,2",
                          "--zenoh-config", str(client), name="ctrl")
        assert p.wait(60) == 0, procs.log(p)
        stats = json.load(open(tmp_path / "plant.json"))
        assert stats["sim_time_s"] == pytest.approx(3.0)
        assert stats["members_seen"] == ["wheel_schedule_robot1"]
        c.wait(10)
        assert c.returncode == 0 and "the simulation ended" in procs.log(c)
    finally:
        router.close()


def test_bad_zenoh_config_file_is_exit_2(procs, tmp_path):
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    p = procs.diffbot("plant", "--zenoh-config", str(bad), name="plant")
    assert p.wait(30) == 2
    log = procs.log(p)
    assert "bad.json5" in log and "Traceback" not in log
