"""Fault injection: kill -9 and freeze (SIGSTOP/SIGCONT) each kind of process at random
points of lockstep and realtime runs, started by hand and under ``diffbot run``.

What each test pins down is the table of docs/failures.md:

* a controller dies       -> the plant stops its robot and carries on; under the launcher a
                             required one ends the run (exit 1, named), nothing is left over;
* the odometry node dies  -> (lockstep) the controller that waits for odom exits 4 at once
                             instead of holding the simulation; the plant carries on;
* the plant dies          -> every node exits 3 within 1 s ("the plant is gone"); with
                             ``--wait`` it waits, and carries on with a new plant;
* a process is frozen     -> handled as dead once its 1 s lease runs out; when it resumes it
                             does not corrupt the run (a dropped node exits 3, or rejoins with
                             ``--wait``; a resumed plant keeps time monotonic and does not race
                             to catch up with the wall clock).

Kill points are drawn from a seeded RNG (from the test id), so a failure replays; where the
test sees the clock they are points of simulated time, under the launcher short waits.
"""
from __future__ import annotations

import json
import math
import os
import random
import signal
import subprocess
import sys
import threading
import time

import pytest

from bus import codec
from bus.keys import Keys
from bus.runtime import EXIT_INPUT_GONE
from bus.session import OPEN_TIMEOUT_MS
from plant.modes import STALL_S

from ..conftest import ROOT, SLACK_S, Procs, require_built_fmus, wait_for
from ..runs.test_scenarios import processes_mentioning

#: serial: kills and freezes processes and times their answers against the wall clock (a second xdist worker would disturb it: tests/conftest.py)
pytestmark = [pytest.mark.slow, pytest.mark.serial]
K = Keys()
LEASE_S = 1.0


class Tap:
    """Clock ticks (wall arrival, stamp) and ground truth of robot1, seen by the test."""

    def __init__(self, session, robot="robot1"):
        self.lock = threading.Lock()
        self.clock: list[tuple[float, int]] = []
        self.gt: list[tuple[int, object]] = []
        self.subs = [session.declare_subscriber(K.clock, self._on_clock),
                     session.declare_subscriber(K.topic(robot, "ground_truth"), self._on_gt)]

    def _on_clock(self, s):
        t = codec.msg_stamp_ns(codec.decode(s.payload.to_bytes(), "rosgraph_msgs/msg/Clock"))
        with self.lock:
            self.clock.append((time.monotonic(), t))

    def _on_gt(self, s):
        m = codec.decode(s.payload.to_bytes(), "nav_msgs/msg/Odometry")
        with self.lock:
            self.gt.append((codec.msg_stamp_ns(m), m))

    def last_t(self) -> int:
        with self.lock:
            return self.clock[-1][1] if self.clock else -1

    def wait_sim(self, seconds: float) -> None:
        """Until the plant's clock has gone ``seconds`` of simulated time further (a kill
        point in simulated time: the same point of the run whatever the machine's load)."""
        t0 = self.last_t()
        wait_for(lambda: self.last_t() >= t0 + seconds * 1e9, 60,
                 what=f"{seconds:.2f} s more of simulated time")

    def first_tick_after(self, wall: float) -> float | None:
        with self.lock:
            return next((w for w, _ in self.clock if w > wall), None)

    def speed_at(self, t_ns: int) -> float:
        """|v| of robot1 at the first ground truth stamped at or after ``t_ns``."""
        with self.lock:
            for t, m in self.gt:
                if t >= t_ns:
                    return abs(m.twist.twist.linear.x)
        return math.nan

    def speed_now(self) -> float:
        """|v| at the last clock seen, once its ground truth is in too (the two come by
        separate subscribers, each on its own thread: the clock may be seen first)."""
        t = self.last_t()
        wait_for(lambda: not math.isnan(self.speed_at(t)), 5,
                 what=f"the ground truth of t={t * 1e-9:.2f} s")
        return self.speed_at(t)

    def check_sane(self) -> None:
        """Time never went back (per plant run) and every ground truth is finite."""
        with self.lock:
            stamps = [t for _, t in self.clock]
            gts = list(self.gt)
        for a, b in zip(stamps, stamps[1:]):
            # strictly increasing, except a new plant that starts again at 0, or the last
            # ticks re-published for a member that rejoined (docs/PROTOCOL.md, "Lost members")
            assert b > a or b == 0 or a - b <= 25 * 20_000_000, f"clock went from {a} to {b} ns"
        for _, m in gts:
            p, tw = m.pose.pose.position, m.twist.twist
            assert all(math.isfinite(v) for v in (p.x, p.y, p.z, tw.linear.x, tw.angular.z))


def start_plant(procs, endpoint, tmp_path, mode, *extra, world="empty", tag="plant"):
    """``mode`` is a plant mode, or ``lockstep-pipelined`` for the pipelined coupling."""
    stats = str(tmp_path / f"{tag}.json")
    mode, _, coupling = mode.partition("-")
    p = procs.diffbot("plant", "--world", world, "--mode", mode, "--endpoint", endpoint,
                      "--coupling", coupling or "sequential", "--stats", stats, *extra,
                      name=tag)
    p.stats_path = stats
    return p


def start_node(procs, endpoint, tmp_path, *args, tag):
    stats = str(tmp_path / f"{tag}.json")
    p = procs.diffbot(*args, "--endpoint", endpoint, "--stats", stats, name=tag)
    p.stats_path = stats
    return p


def drive(procs, endpoint, tmp_path, *extra, tag="ctrl"):
    """A controller that drives robot1 straight at 3 rad/s for a long time."""
    return start_node(procs, endpoint, tmp_path, "controller", "wheel_schedule",
                      "--schedule", "1000:3,3", *extra, tag=tag)


def odometry(procs, endpoint, tmp_path, *extra, tag="odo"):
    return start_node(procs, endpoint, tmp_path, "controller", "odometry", *extra, tag=tag)


def exits_within(p, timeout: float) -> tuple[int, float]:
    t0 = time.monotonic()
    code = Procs.wait(p, timeout, f"{os.path.basename(p.log_path)[:-4]} to exit")
    return code, time.monotonic() - t0


def stats(p) -> dict:
    with open(p.stats_path) as f:
        return json.load(f)


def rng_for(request) -> random.Random:
    return random.Random(request.node.name)


LOCKSTEP_EXPECT = ("--expect", "odometry_robot1,wheel_schedule_robot1")


def mode_args(mode):
    return LOCKSTEP_EXPECT if mode.startswith("lockstep") else ()


# ====================================================================== started by hand

@pytest.mark.parametrize("mode", ["lockstep", "lockstep-pipelined", "realtime"])
def test_controller_killed_robot_stops_and_plant_carries_on(mode, procs, endpoint, bus,
                                                            tmp_path, request):
    rng = rng_for(request)
    p = start_plant(procs, endpoint, tmp_path, mode, *mode_args(mode))
    odo = odometry(procs, endpoint, tmp_path)
    ctrl = drive(procs, endpoint, tmp_path)
    tap = Tap(bus())
    kill_at = int(rng.uniform(0.8, 3.0) / 0.02) * 20_000_000
    wait_for(lambda: tap.last_t() >= kill_at, 60, what=f"t={kill_at * 1e-9:.2f} s")
    assert tap.speed_now() == pytest.approx(0.36, rel=0.05)
    ctrl.send_signal(signal.SIGKILL)
    killed, t_kill = time.monotonic(), tap.last_t()
    if mode.startswith("lockstep"):
        # a lockstep plant never runs alone: its expected member is lost, the run ends
        code, took = exits_within(p, 10)
        assert code == 1 and took < 3.0, procs.log(p)
        assert "lost lockstep member wheel_schedule_robot1" in procs.log(p)
        assert "lockstep member lost: wheel_schedule_robot1" in procs.log(p)
        return
    wait_for(lambda: tap.last_t() > t_kill + 1_500_000_000, 20, what="the plant to carry on")
    resumed = tap.first_tick_after(killed)
    # a realtime plant does not wait for a dead controller (one that waited for its lease
    # would pause >= 1 s): its next tick comes within a tick, plus scheduling slack
    assert resumed - killed < 0.02 + SLACK_S < LEASE_S, f"plant paused {resumed - killed:.3f} s"
    # cmd_timeout 0.5 s (simulated) after the last command, then the deceleration limit
    assert tap.speed_at(t_kill + 1_200_000_000) < 0.005
    assert p.poll() is None and odo.poll() is None
    tap.check_sane()
    assert "no command for" in procs.log(p)


@pytest.mark.parametrize("mode", ["lockstep", "lockstep-pipelined"])
def test_odometry_killed_in_lockstep_the_run_ends_naming_it(
        mode, procs, endpoint, bus, tmp_path, request):
    rng = rng_for(request)
    p = start_plant(procs, endpoint, tmp_path, mode, "--expect",
                    "odometry_robot1,square_path_robot1")
    odo = odometry(procs, endpoint, tmp_path)
    sq = start_node(procs, endpoint, tmp_path, "controller", "square_path", "--laps", "50",
                    tag="square")
    tap = Tap(bus())
    kill_at = int(rng.uniform(0.5, 4.0) / 0.02) * 20_000_000
    wait_for(lambda: tap.last_t() >= kill_at, 60, what=f"t={kill_at * 1e-9:.2f} s")
    odo.send_signal(signal.SIGKILL)
    code, took = exits_within(p, 10)
    assert code == 1 and took < 3.0, procs.log(p)
    assert "lost lockstep member odometry_robot1" in procs.log(p)
    # its consumer sees the end (0), or, first, that its input will never come (4): which
    # one is a race between the plant's sim/end and the node's grace; the log says which
    code, took = exits_within(sq, 10)
    log = procs.log(sq)
    gone = "lockstep member odometry_robot1 left the simulation, so it will never come"
    assert code == (EXIT_INPUT_GONE if gone in log else 0), log
    assert took < PRODUCER_EXIT_S
    tap.check_sane()


def test_a_node_whose_input_producer_left_exits_4_while_the_plant_holds_time(
        procs, endpoint, bus, tmp_path):
    """docs/controllers.md: exit 4, an awaited input's producer left the simulation. With
    --rejoin-timeout the plant holds time for the lost member instead of ending the run,
    so nothing races the node's own verdict."""
    p = start_plant(procs, endpoint, tmp_path, "lockstep", "--expect",
                    "odometry_robot1,square_path_robot1", "--rejoin-timeout", "30")
    odo = odometry(procs, endpoint, tmp_path)
    sq = start_node(procs, endpoint, tmp_path, "controller", "square_path", "--laps", "50",
                    tag="square")
    session = bus()
    tap = Tap(session)
    odoms: set[int] = set()
    session.declare_subscriber(K.topic("robot1", "odom"), lambda s: odoms.add(codec.msg_stamp_ns(
        codec.decode(s.payload.to_bytes(), "nav_msgs/msg/Odometry"))))
    wait_for(lambda: tap.last_t() >= 1_000_000_000, 60, what="t=1 s")
    kill_between_ticks(odo, tap, odoms)
    code, took = exits_within(sq, LEASE_S + PRODUCER_EXIT_S + 10)
    log = procs.log(sq)
    assert code == EXIT_INPUT_GONE == 4, log
    assert "no odom for t=" in log and "odometry_robot1 left the simulation" in log, log
    assert "Traceback" not in log
    assert took < LEASE_S + PRODUCER_EXIT_S, f"exited {took:.2f} s after the kill"
    assert p.poll() is None, "the plant holds time for the lost member (--rejoin-timeout)"
    tap.check_sane()
    # docs/failures.md: a process that seems stuck says where its threads are on SIGUSR1
    main_thread = procs.dump_stacks(p, 10.0)
    assert "in _run_module_as_main" in main_thread, procs.log(p)[-3000:]   # dumped whole
    assert "in hold" in main_thread, main_thread              # (plant/modes.py: Lockstep.hold)
    time.sleep(0.2)
    assert p.poll() is None, "SIGUSR1 does not stop a process"


PRODUCER_EXIT_S = 0.5 + 0.2 + SLACK_S      # grace + poll period + scheduling


def kill_between_ticks(odo, tap: Tap, odoms: set[int]) -> None:
    """SIGKILL the odometry node while it has not published the odom of the plant's last
    tick, so its consumer waits for that odom. (Killed after publishing it and before its
    ACK reached the plant, the consumer has all it needs and simply waits for a next clock
    that the plant, holding time for the lost member, never sends: no input is missing.)
    The node is stopped first (SIGSTOP, well inside its 1 s lease) to look where it is."""
    for _ in range(50):
        odo.send_signal(signal.SIGSTOP)
        t, quiet_since, t0 = tap.last_t(), time.monotonic(), time.monotonic()
        while time.monotonic() - quiet_since < 0.25 and time.monotonic() - t0 < 0.6:
            time.sleep(0.02)
            if tap.last_t() != t:
                t, quiet_since = tap.last_t(), time.monotonic()
        if time.monotonic() - quiet_since >= 0.25 and t not in odoms:
            odo.send_signal(signal.SIGKILL)
            return
        odo.send_signal(signal.SIGCONT)
        tap.wait_sim(0.1)
    raise AssertionError("never caught the odometry node before its odom of a tick")


def test_odometry_killed_in_realtime_its_consumer_stops_steering_blind(
        procs, endpoint, bus, tmp_path, request):
    rng = rng_for(request)
    p = start_plant(procs, endpoint, tmp_path, "realtime")
    odo = odometry(procs, endpoint, tmp_path)
    sq = start_node(procs, endpoint, tmp_path, "controller", "square_path", "--laps", "50",
                    "--speed", "0.3", tag="square")
    tap = Tap(bus())
    wait_for(lambda: tap.speed_at(0) == tap.speed_at(0) and any(
        abs(m.twist.twist.linear.x) > 0.1 for _, m in list(tap.gt)), 60, what="driving")
    tap.wait_sim(rng.uniform(0.0, 1.0))
    odo.send_signal(signal.SIGKILL)
    t_kill = tap.last_t()
    wait_for(lambda: tap.last_t() > t_kill + 2_000_000_000, 20, what="the plant to go on")
    # odom goes stale after 0.5 s: the controller sees None and stops its robot
    assert tap.speed_at(t_kill + 1_500_000_000) < 0.005
    assert p.poll() is None and sq.poll() is None
    tap.check_sane()


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_plant_killed_every_node_exits_3_within_1_s(mode, procs, endpoint, bus, tmp_path,
                                                    request):
    rng = rng_for(request)
    p = start_plant(procs, endpoint, tmp_path, mode, *mode_args(mode))
    nodes = [odometry(procs, endpoint, tmp_path), drive(procs, endpoint, tmp_path)]
    tap = Tap(bus())
    wait_for(lambda: tap.last_t() > 0, 60, what="the plant to run")
    tap.wait_sim(rng.uniform(0.2, 1.2))
    p.send_signal(signal.SIGKILL)
    killed = time.monotonic()
    for n in nodes:
        assert n.wait(10) == 3, procs.log(n)
        took = time.monotonic() - killed
        assert took < 1.0 + SLACK_S, f"exited {took:.2f} s after the plant died"
        assert "the plant is gone; stopping" in procs.log(n)
        assert "Traceback" not in procs.log(n)
    report(f"plant killed ({mode}) -> every node exited", took)


def test_plant_killed_nodes_with_wait_carry_on_with_a_plant_back_within_the_rejoin_timeout(
        procs, endpoint, bus, tmp_path):
    """--wait across an outage: the plant's sim/info says how long (rejoin_timeout_s); a
    plant back within it is carried on with, and its end ends the nodes (exit 0)."""
    p = start_plant(procs, endpoint, tmp_path, "realtime", "--rejoin-timeout", "30",
                    tag="plant1")
    nodes = [odometry(procs, endpoint, tmp_path, "--wait"),
             drive(procs, endpoint, tmp_path, "--wait")]
    tap = Tap(bus())
    wait_for(lambda: tap.speed_at(0) == tap.speed_at(0) and tap.last_t() > 1e9, 60,
             what="driving")
    p.send_signal(signal.SIGKILL)
    p.wait(10)
    # each node says how long it waits, the run's rejoin timeout (30 s) + the grace, not
    # the grace alone (bus.plantwatch): the deadline its exit would come from
    wait_for(lambda: all("waiting for it to come back (--wait), up to 32 s" in procs.log(n)
                         for n in nodes), 10, what="the nodes to wait for the plant")
    assert all(n.poll() is None for n in nodes), "--wait nodes wait for the plant"
    with tap.lock:
        seen = len(tap.gt)
    p2 = start_plant(procs, endpoint, tmp_path, "realtime", tag="plant2")
    restarted = time.monotonic()

    def driving_again():
        with tap.lock:
            return any(abs(m.twist.twist.linear.x) > 0.3 for _, m in tap.gt[seen:])
    wait_for(driving_again, 60, what="the robot driving again under the new plant")
    report("plant restarted -> driving again", time.monotonic() - restarted)
    for n in nodes:
        assert n.poll() is None
        log = procs.log(n)
        assert "waiting for it to come back (--wait), up to 32 s" in log, log
        assert "the plant is back" in log and "Traceback" not in log
    p2.send_signal(signal.SIGINT)
    assert p2.wait(10) == 0
    for n in nodes:                      # the run they took part in ended: so do they
        assert n.wait(10) == 0, procs.log(n)
        assert "the simulation ended (stopped); stopping" in procs.log(n)
    assert stats(nodes[1])["plant_lost"] >= 1


@pytest.mark.parametrize("end", ["sigint", "kill"])
def test_nodes_with_wait_end_with_the_run_they_took_part_in(end, procs, endpoint, bus,
                                                             tmp_path):
    """--wait waits for a plant to start, not past the end of a run: a plant that ends
    (sim/end) ends its --wait nodes (exit 0); one killed, with the default rejoin timeout
    0, ends them 2 s later (exit 3, bus.plantwatch.GONE_GRACE_S)."""
    p = start_plant(procs, endpoint, tmp_path, "realtime")
    nodes = [odometry(procs, endpoint, tmp_path, "--wait"),
             drive(procs, endpoint, tmp_path, "--wait")]
    tap = Tap(bus())
    wait_for(lambda: tap.speed_at(0) == tap.speed_at(0) and tap.last_t() > 1e9, 60,
             what="driving")
    p.send_signal(signal.SIGKILL if end == "kill" else signal.SIGINT)
    p.wait(10)
    for n in nodes:
        code, took = exits_within(n, 10)
        log = procs.log(n)
        assert "Traceback" not in log
        if end == "sigint":
            assert code == 0 and "the simulation ended (stopped); stopping" in log
        else:
            assert code == 3 and "the plant has been gone for " in log, log
            assert "longer than the run's rejoin timeout (0 s" in log, log
    report(f"plant ended ({end}) -> --wait nodes ended", took)


def test_node_with_wait_started_before_the_plant_waits_for_it(procs, endpoint, bus, tmp_path):
    ctrl = drive(procs, endpoint, tmp_path, "--wait")
    # its first try found no plant listening (without --wait it would exit): it says it waits
    wait_for(lambda: "yet; waiting for one (--wait)" in procs.log(ctrl), 30,
             what="the node to wait for a plant")
    assert ctrl.poll() is None
    start_plant(procs, endpoint, tmp_path, "lockstep", "--expect", "wheel_schedule_robot1")
    tap = Tap(bus())
    wait_for(lambda: tap.speed_at(0) == tap.speed_at(0) and tap.last_t() > 1e9, 60,
             what="the lockstep run")
    assert tap.speed_now() == pytest.approx(0.36, rel=0.05)


# ---------------------------------------------------------------------- frozen processes

@pytest.mark.parametrize("wait", [False, True], ids=["exits", "rejoins"])
def test_frozen_lockstep_member_is_dropped_within_the_lease_and_handled_on_resume(
        wait, procs, endpoint, bus, tmp_path, request):
    rng = rng_for(request)
    p = start_plant(procs, endpoint, tmp_path, "lockstep", *LOCKSTEP_EXPECT,
                    *(["--rejoin-timeout", "30"] if wait else []))
    odo = odometry(procs, endpoint, tmp_path)
    ctrl = drive(procs, endpoint, tmp_path, *(["--wait"] if wait else []))
    tap = Tap(bus())
    stop_at = int(rng.uniform(0.5, 3.0) / 0.02) * 20_000_000
    wait_for(lambda: tap.last_t() >= stop_at, 60, what=f"t={stop_at * 1e-9:.2f} s")
    ctrl.send_signal(signal.SIGSTOP)
    stopped = time.monotonic()
    # The plant waits for the frozen member until its lease runs out: then it is lost.
    wait_for(lambda: "lockstep member lost: wheel_schedule_robot1" in procs.log(p),
             LEASE_S + SLACK_S + 1, what="the plant to notice the frozen member")
    report("frozen lockstep member -> lost to the plant", time.monotonic() - stopped)
    t_stop = tap.last_t()
    if not wait:                # --rejoin-timeout 0: the run ends, naming it
        code, took = exits_within(p, 10)
        assert code == 1 and "lost lockstep member wheel_schedule_robot1" in procs.log(p)
        # and the plant said what happens, not that it holds time
        assert "time is held" not in procs.log(p)
        assert "the run ends at this tick: --rejoin-timeout is 0" in procs.log(p)
    else:                       # time is held for it
        time.sleep(1.0)
        assert tap.last_t() == t_stop and p.poll() is None
    ctrl.send_signal(signal.SIGCONT)
    if not wait:
        code, took = exits_within(ctrl, 10)
        assert code == 3
        log = procs.log(ctrl)
        assert "this process was stopped for" in log and "dropped it" in log
        return
    else:
        wait_for(lambda: "lockstep member rejoined: wheel_schedule_robot1" in procs.log(p),
                 10, what="the resumed member to rejoin")
        t_rejoin = tap.last_t()
        wait_for(lambda: tap.last_t() > t_rejoin + 1_000_000_000, 20, what="lockstep again")
        assert tap.speed_now() == pytest.approx(0.36, rel=0.05)  # driving again
        assert ctrl.poll() is None
    assert p.poll() is None and odo.poll() is None
    tap.check_sane()
    p.send_signal(signal.SIGINT)
    assert p.wait(10) == 0
    assert stats(p)["sim_time_s"] > 0


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_frozen_plant_nodes_exit_after_the_lease_and_it_resumes_sanely(
        mode, procs, endpoint, bus, tmp_path, request):
    rng = rng_for(request)
    p = start_plant(procs, endpoint, tmp_path, mode, *mode_args(mode))
    nodes = [odometry(procs, endpoint, tmp_path), drive(procs, endpoint, tmp_path)]
    tap = Tap(bus())
    wait_for(lambda: tap.last_t() > 0, 60, what="the plant to run")
    tap.wait_sim(rng.uniform(0.2, 1.2))
    p.send_signal(signal.SIGSTOP)
    stopped = time.monotonic()
    wait_for(lambda: all("the plant is gone" in procs.log(n) for n in nodes), 10,
             step=0.01, what="every node to notice")
    noticed = time.monotonic() - stopped
    for n in nodes:
        assert n.wait(10) == 3, procs.log(n)
    exited = time.monotonic() - stopped
    report(f"frozen plant ({mode}) -> every node noticed", noticed)
    report(f"frozen plant ({mode}) -> every node exited", exited)
    assert noticed < LEASE_S + SLACK_S
    # + closing the session: a frozen router hangs the reconnect handshake (open_timeout)
    assert exited < LEASE_S + OPEN_TIMEOUT_MS / 1000 + 2 * SLACK_S
    frozen_for = 3.0
    time.sleep(max(0.0, frozen_for - exited))
    t_before = tap.last_t()
    p.send_signal(signal.SIGCONT)
    resumed = time.monotonic()
    if mode.startswith("lockstep"):
        # its members exited while it was frozen: a lockstep plant does not run on alone
        code, took = exits_within(p, 10)
        assert code == 1 and "lost lockstep member" in procs.log(p), procs.log(p)
        assert tap.last_t() <= t_before + 20_000_000
        return
    wait_for(lambda: tap.first_tick_after(resumed + 1.0), 20, what="ticks after the resume")
    time.sleep(1.0)
    assert p.poll() is None
    tap.check_sane()
    with tap.lock:
        after = [(w, t) for w, t in tap.clock if w > resumed + 0.5]
    assert after and after[0][1] >= t_before                      # time went on, not back
    if mode == "realtime":
        (w0, t0), (w1, t1) = after[0], after[-1]
        sim, wall = (t1 - t0) * 1e-9, w1 - w0
        # paced again, not racing to catch up the 3 s it was frozen (which would be 3 s of
        # simulated time more): within a stall's worth and the scheduling slack of the wall
        assert abs(sim - wall) < STALL_S + SLACK_S, \
            f"{sim:.2f} s simulated in {wall:.2f} s after the resume (caught up?)"
        p.send_signal(signal.SIGINT)
        p.wait(10)
        assert stats(p)["stalls"] >= 1
        assert "behind the wall clock" in procs.log(p)


# ====================================================================== under the launcher

SCENARIO = """
[scenario]
world = "empty"
mode = "{mode}"

[[process]]
name = "odometry_robot1"
command = ["controller", "odometry", "--robot", "robot1"]

[[process]]
name = "wheel_schedule_robot1"
command = ["controller", "wheel_schedule", "--robot", "robot1", "--schedule", "1000:2,2"]
ends_run = true
"""


def launch(tmp_path, scenario_text=None, scenario="faults", *extra):
    out = tmp_path / "run"
    if scenario_text is not None:
        path = tmp_path / f"{scenario}.toml"
        path.write_text(scenario_text)
        scenario = str(path)
    p = subprocess.Popen([sys.executable, "-m", "diffbot.cli", "run", scenario, "--out",
                          str(out), "--timeout", "120", *extra], cwd=ROOT,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    p.out = out
    return p


def child_pid(out, name: str) -> int:
    """PID of the run's process called ``name`` (its --name, or the plant's --stats)."""
    marker = f"{out}/logs/{name}.json"
    pids = processes_mentioning(marker)
    assert len(pids) == 1, f"{name}: {pids}"
    return pids[0]


def wait_running(run, timeout=60.0):
    plant_log = run.out / "logs" / "plant.log"
    wait_for(lambda: plant_log.exists() and "running" in plant_log.read_text(), timeout,
             what="the plant to run")


def finish(run) -> tuple[int, str]:
    try:
        _, err = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
    wait_for(lambda: not processes_mentioning(str(run.out)), 5, what="no process left")
    return run.returncode, err


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
@pytest.mark.parametrize("victim,expect", [
    ("wheel_schedule_robot1", "wheel_schedule_robot1 was killed by SIGKILL"),
    ("odometry_robot1", "odometry_robot1 was killed by SIGKILL"),
    ("plant", "plant was killed by SIGKILL"),
])
def test_launcher_kill_ends_the_run_and_names_the_process(mode, victim, expect, tmp_path,
                                                          request):
    rng = rng_for(request)
    run = launch(tmp_path, SCENARIO.format(mode=mode))
    wait_running(run)
    time.sleep(rng.uniform(0.1, 1.2))
    os.kill(child_pid(run.out, victim), signal.SIGKILL)
    code, err = finish(run)
    assert code == 1, err
    assert expect in err, err
    summary = json.load(open(run.out / "summary.json"))
    assert summary["exit_codes"][victim] == -9
    assert expect in summary["end_reason"]


@pytest.mark.parametrize("victim", ["wheel_schedule_robot1", "plant"])
def test_launcher_frozen_process_is_handled_as_dead(victim, tmp_path, request):
    rng = rng_for(request)
    run = launch(tmp_path, SCENARIO.format(mode="lockstep"))
    wait_running(run)
    time.sleep(rng.uniform(0.1, 1.2))
    pid = child_pid(run.out, victim)
    os.kill(pid, signal.SIGSTOP)
    stopped = time.monotonic()
    try:
        code, err = finish(run)
    finally:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    took = time.monotonic() - stopped
    assert code == 1, err
    assert f"{victim} stopped responding" in err, err
    report(f"launcher: frozen {victim} -> run ended, all gone", took)


def test_launcher_fmu_odometry_killed_in_the_square(tmp_path, request, fmu_built):
    rng = rng_for(request)
    run = launch(tmp_path, None, "square")
    wait_running(run)
    time.sleep(rng.uniform(0.1, 1.2))
    os.kill(child_pid(run.out, "odometry_robot1"), signal.SIGKILL)
    code, err = finish(run)
    assert code == 1, err
    assert "odometry_robot1 was killed by SIGKILL" in err


@pytest.fixture
def fmu_built():
    require_built_fmus()


# ---------------------------------------------------------------------- measurements

MEASURED: list[tuple[str, float]] = []


def report(what: str, seconds: float) -> None:
    """Detection / recovery times, printed at the end of the session (-s) and kept in
    FAULT_TIMES (a JSON lines file) if that variable is set."""
    MEASURED.append((what, seconds))
    path = os.environ.get("FAULT_TIMES")
    if path:
        with open(path, "a") as f:
            f.write(json.dumps({"what": what, "s": round(seconds, 3)}) + "\n")
    print(f"\n[fault timing] {what}: {seconds:.3f} s")
