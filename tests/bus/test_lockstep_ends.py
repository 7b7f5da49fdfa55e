"""Lockstep's fixed points, driven by the client written from docs/PROTOCOL.md alone
(tests/support/conformance_client.py): the tick-0 command acts under pipelined coupling, a lost
--end-with member ends the run at once, a duplicate output (its ACK included) never changes
a run; a reset in the first 26 ticks is told from a re-publish, a stamp for
a tick not due is a protocol error that changes nothing."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from bus import codec
from bus.keys import Keys
from bus.protocol import COUPLINGS

from ..conftest import ROOT, wait_for

K = Keys()
TOKEN = "<the sim/end token>"
CLIENT = os.path.join(ROOT, "tests", "support", "conformance_client.py")


def client(endpoint, *args, **kw):
    return subprocess.Popen([sys.executable, CLIENT, "--endpoint", endpoint, *args],
                            env=dict(os.environ, PYTHONPATH=ROOT), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True, **kw)


class Watch:
    """Ground truth x by stamp and sim/end's text, from a session of the test's own."""

    def __init__(self, endpoint, epoch: int = 0) -> None:
        from bus.session import open_session
        self.truth: dict[int, bytes] = {}       # of the world of ``epoch`` (resets)
        self.end: list[str] = []
        self.last_t: int | None = None          # the stamp of the last one in, any world
        s = self.session = open_session("test", endpoint)

        def on_truth(smp) -> None:
            a = codec.parse_attachment(smp.attachment.to_bytes())
            self.last_t = a.t_ns
            if a.epoch == epoch:
                self.truth.setdefault(a.t_ns, smp.payload.to_bytes())
        self.subs = [
            s.declare_subscriber(K.topic("robot1", "ground_truth"), on_truth),
            s.declare_subscriber(K.end, lambda smp: self.end.append(
                smp.payload.to_bytes().decode())),
            s.liveliness().declare_subscriber(K.end, lambda smp: self.end.append(TOKEN))]
        # the plant answers sim/info only after it has taken in what came before the query
        # on this link, the subscriptions above: no tick goes out before it knows of them
        wait_for(lambda: any(r.ok is not None for r in s.get(K.info, timeout=1.0)), 60,
                 step=0.05, what="the plant's sim/info")

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()
        self.session.close()

    def xs(self) -> list[float]:
        return [codec.decode(self.truth[t], "nav_msgs/msg/Odometry").pose.pose.position.x
                for t in sorted(self.truth)]


def drive(procs, endpoint, tmp_path, coupling, *client_args, world=(), epoch=0):
    stats = tmp_path / f"plant-{len(procs.procs)}.json"
    plant = procs.diffbot("plant", "--world", "empty", *world, "--coupling", coupling,
                          "--expect", "conformance", "--end-with", "conformance",
                          "--endpoint", endpoint, "--stats", str(stats), name="plant")
    w = Watch(endpoint, epoch)
    c = client(endpoint, *client_args)
    try:
        assert c.wait(120) == 0, c.stderr.read()
        assert plant.wait(30) == 0, procs.log(plant)
        # the run's last tick in, every tick is (one publisher, one link, in order). Closed
        # right after the plant's exit, a loaded machine's watch once lacked 38 ticks, and
        # once all but two.
        last = round(json.loads(stats.read_text())["sim_time_s"] * 1e9)
        wait_for(lambda: w.last_t == last, 30, what=f"the ground truth of t = {last} ns")
    finally:
        if c.poll() is None:
            c.kill()
            c.wait()
        w.close()
    return w, json.loads(stats.read_text())


@pytest.mark.slow
@pytest.mark.parametrize("world", [(), ("--set", "world.mode=kinematic")],
                         ids=["dynamic", "kinematic"])
def test_driving_100_ticks_goes_as_far_under_both_couplings(procs, endpoint, tmp_path,
                                                            world):
    """Pipelined applies the command of tick 0 at tick 1 (it never acted: 4 mm short)."""
    dist = {}
    for i, coupling in enumerate(COUPLINGS):
        ep = endpoint.replace("bus.sock", f"bus{i}.sock")
        w, st = drive(procs, ep, tmp_path, coupling, "--ticks", "100", "--speed", "0.2",
                      world=world)
        assert st["protocol_errors"] == {}, st
        xs = w.xs()
        dist[coupling] = xs[-1] - xs[0]
        assert xs[1 if coupling == "sequential" else 2] > 1e-4     # the first command acted
    assert dist["sequential"] == pytest.approx(0.2 * 0.02 * 99, abs=0.02)
    # kinematic: the same positions a tick later; dynamic: the robot, spawned a hair above
    # the floor, slips a little in its first tick, when the sequential one already drives
    tol = 1e-9 if world else 2e-4
    assert dist["pipelined"] == pytest.approx(dist["sequential"], abs=tol), dist
    print(f"\n{'kinematic' if world else 'dynamic'}: pipelined - sequential = "
          f"{(dist['pipelined'] - dist['sequential']) * 1e3:+.4f} mm over 100 ticks "
          "(docs/PROTOCOL.md, \"Couplings\")")


@pytest.mark.slow
@pytest.mark.parametrize("coupling", COUPLINGS)
def test_duplicate_commands_never_change_the_run(procs, endpoint, tmp_path, coupling):
    """20 second commands (reversing the robot), 0 to 40 ms after the first, each carrying
    the ACK again, are ignored whole: one protocol error each, none for a second ACK."""
    w0, _ = drive(procs, endpoint, tmp_path, coupling, "--ticks", "110", "--speed", "0.2")
    w1, st = drive(procs, endpoint.replace("bus.sock", "bus2.sock"), tmp_path, coupling,
                   "--ticks", "110", "--speed", "0.2", "--duplicates", "20")
    assert st["protocol_errors"] == {"robot1/cmd_vel: a second message from conformance for "
                                     "one tick": 20}, st
    assert w0.truth == w1.truth


@pytest.mark.slow
@pytest.mark.parametrize("coupling", COUPLINGS)
def test_a_reset_in_the_first_26_ticks_is_a_new_world_not_a_re_publish(procs, endpoint,
                                                                        tmp_path, coupling):
    """The client drives backwards for 10 ticks, resets the world instead of answering tick
    10, then drives 60 ticks forward: the stamps 0..9 of the new world are ones it answered
    and keeps (a re-published tick looks the same), but the epoch of the plant's attachment
    says a new world, so it steps: the new world goes exactly as a fresh run. (Had it
    re-sent its old answers, the new world would start backwards.)"""
    w0, _ = drive(procs, endpoint, tmp_path, coupling, "--ticks", "60", "--speed", "0.2")
    w1, st = drive(procs, endpoint.replace("bus.sock", "bus2.sock"), tmp_path, coupling,
                   "--ticks", "60", "--speed", "0.2", "--reset-at", "10", epoch=1)
    assert st["protocol_errors"] == {} and st["rejected"] == {}, st
    assert len(w0.truth) > 55 and w1.truth == w0.truth


@pytest.mark.slow
@pytest.mark.parametrize("coupling", COUPLINGS)
def test_a_future_stamp_is_a_protocol_error_and_never_acts(procs, endpoint, tmp_path,
                                                           coupling):
    """Five commands (reversing the robot) stamped 10 ticks ahead of their tick: counted in
    protocol_errors, not rejected (docs/PROTOCOL.md section 7), and the run is unchanged."""
    w0, _ = drive(procs, endpoint, tmp_path, coupling, "--ticks", "60", "--speed", "0.2")
    w1, st = drive(procs, endpoint.replace("bus.sock", "bus2.sock"), tmp_path, coupling,
                   "--ticks", "60", "--speed", "0.2", "--future", "5")
    assert st["protocol_errors"] == {"robot1/cmd_vel: stamped for a tick not due": 5}, st
    assert st["rejected"] == {}
    assert w1.truth == w0.truth


@pytest.mark.serial                  # a wall-clock promise: runs alone under xdist
@pytest.mark.slow
@pytest.mark.parametrize("how", ["SIGKILL", "never acks"])
def test_a_lost_end_with_member_ends_the_run_at_once(procs, endpoint, tmp_path, how):
    stats = tmp_path / "plant.json"
    plant = procs.diffbot("plant", "--world", "empty", "--coupling", "pipelined", "--expect",
                          "conformance", "--end-with", "conformance", "--endpoint", endpoint,
                          "--stats", str(stats), name="plant")
    w = Watch(endpoint)
    c = client(endpoint, "--ticks", "100000", *(["--quit-at", "50"] if how != "SIGKILL"
                                                 else []))
    try:
        wait_for(lambda: len(w.truth) > 50, 60, what="the run")
        if how == "SIGKILL":
            os.kill(c.pid, signal.SIGKILL)
        c.wait(10)
        gone = time.monotonic()
        code = plant.wait(10)
        took = time.monotonic() - gone
    finally:
        if c.poll() is None:
            c.kill()
            c.wait()
    assert code == 1, procs.log(plant)
    w.close()
    assert took <= 3.0, f"the plant ended {took:.2f} s after the member went"
    wait_for(lambda: len(w.end) >= 2, 5, what="sim/end, text and token")
    # the text first (docs/PROTOCOL.md section 4, "End")
    assert w.end[0].startswith("lost lockstep member conformance at t="), w.end
    assert w.end[1] == TOKEN
    st = json.loads(stats.read_text())
    assert st["end_reason"] == w.end[0] and st["exit_code"] == 1
    assert st["members_lost"] == ["conformance"]
    log = procs.log(plant)
    assert "lockstep member lost: conformance" in log and "Traceback" not in log
    print(f"\n{how}: the plant ended {took:.2f} s after the member went")
