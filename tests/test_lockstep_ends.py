"""Issue 20's fixed points, driven by the client written from docs/PROTOCOL.md alone
(tests/conformance_client.py): the tick-0 command acts under pipelined coupling, a lost
--end-with member ends the run at once, a duplicate output never changes a run."""
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

from .conftest import ROOT, wait_for

K = Keys()
TOKEN = "<the sim/end token>"
CLIENT = os.path.join(ROOT, "tests", "conformance_client.py")


def client(endpoint, *args, **kw):
    return subprocess.Popen([sys.executable, CLIENT, "--endpoint", endpoint, *args],
                            env=dict(os.environ, PYTHONPATH=ROOT), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True, **kw)


class Watch:
    """Ground truth x by stamp and sim/end's text, from a session of the test's own."""

    def __init__(self, endpoint) -> None:
        from bus.session import open_session
        self.truth: dict[int, bytes] = {}
        self.end: list[str] = []
        s = self.session = open_session("test", endpoint)
        self.subs = [
            s.declare_subscriber(K.topic("robot1", "ground_truth"), lambda smp: self.truth.
                                 setdefault(codec.parse_attachment(smp.attachment.to_bytes())
                                            .t_ns, smp.payload.to_bytes())),
            s.declare_subscriber(K.end, lambda smp: self.end.append(
                smp.payload.to_bytes().decode())),
            s.liveliness().declare_subscriber(K.end, lambda smp: self.end.append(TOKEN))]

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()
        self.session.close()

    def xs(self) -> list[float]:
        return [codec.decode(self.truth[t], "nav_msgs/msg/Odometry").pose.pose.position.x
                for t in sorted(self.truth)]


def drive(procs, endpoint, tmp_path, coupling, *client_args, world=()):
    stats = tmp_path / f"plant-{len(procs.procs)}.json"
    plant = procs.diffbot("plant", "--world", "empty", *world, "--coupling", coupling,
                          "--expect", "conformance", "--end-with", "conformance",
                          "--endpoint", endpoint, "--stats", str(stats), name="plant")
    w = Watch(endpoint)
    c = client(endpoint, *client_args)
    try:
        assert c.wait(120) == 0, c.stderr.read()
        assert plant.wait(30) == 0, procs.log(plant)
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


@pytest.mark.slow
@pytest.mark.parametrize("coupling", COUPLINGS)
def test_duplicate_commands_never_change_the_run(procs, endpoint, tmp_path, coupling):
    """20 second commands (reversing the robot), 0 to 40 ms after the first, are ignored."""
    w0, _ = drive(procs, endpoint, tmp_path, coupling, "--ticks", "110", "--speed", "0.2")
    w1, st = drive(procs, endpoint.replace("bus.sock", "bus2.sock"), tmp_path, coupling,
                   "--ticks", "110", "--speed", "0.2", "--duplicates", "20")
    assert st["protocol_errors"] == {"robot1/cmd_vel: a second message from conformance for "
                                     "one tick": 20}, st
    assert w0.truth == w1.truth


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
