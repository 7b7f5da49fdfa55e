"""Lockstep survives router blips: a `diffbot router` SIGKILLed and
restarted 0-0.5 s later, again and again during one lockstep square run (--rejoin-timeout
30, --end-with the square as docs/several-machines.md runs it, --wait nodes), leaves the
recording identical, payloads and sim stamps, to an undisturbed run's (its members
composed, no router), under both couplings, with no protocol error and no stale command (docs/PROTOCOL.md section 4, "Lost
members"). A blip shorter than the plant's grace for the --end-with member's FINAL is the
window where it could step the held tick with the previous tick's command
(tests/bus/test_stale_command.py has that window scripted).

And every process ends with its run by itself, with the codes of
docs/several-machines.md, none killed by the test: after a run with blips, plant, nodes
and recorder all exit 0; when the router stays away longer than --rejoin-timeout, the plant
exits 1 and the --wait nodes and the recorder, whom its sim/end cannot reach, exit 3."""
from __future__ import annotations

import json
import os
import random
import signal
import socket
import time

import pytest

from bus.protocol import COUPLINGS

from ..support.compare_recordings import compare, topics_of
from ..conftest import ROOT, Procs, wait_for
from ..network.test_netns import net, start_router, tls_machines  # noqa: F401  (net: a fixture)

#: the blip runs are not ``serial``: what they check (the bytes, no stale command, every
#: process ending by itself) must hold however the machine's load moves a blip against the
#: plant's graces; the outage test's exits within a time are, and it is
pytestmark = pytest.mark.slow

CLIENT = os.path.join(ROOT, "diffbot", "launch", "configs", "client.json5")
#: the blips and a tail of the run after them, in simulated time. Time hardly moves over the
#: blips: it is held while the router is down, until the members and the recorder are back,
#: and 0.5 s more after a held recorder is back, and the next blip comes 0.02-0.15 s after
#: the members rejoin: the last blip came at t = 0.8-1.7 s on loopback, 0.04-0.44 s across
#: namespaces, at a load of 3-10 on 2 cores (the plant's log). Short of the square's end
#: (t = 45.9 s sequential, 48.7 s pipelined: --end-with would end the run there). A run
#: that outgrows the plan fails, saying so.
DURATION_S = "15"
#: blips per coupling in one run, and (wall s) how long after the last rejoin each comes
LOOPBACK_BLIPS, LOOPBACK_AFTER_S = 8, (0.02, 0.15)
NETNS_BLIPS, NETNS_AFTER_S = 10, (0.02, 0.1)
#: how long the router stays down (wall s), in turn: so short that the members are often
#: back within the plant's 0.5 s grace for the --end-with member's FINAL (the stale-command
#: window: without the barrier's wait, 20 such blips made 2-3 stale commands across
#: namespaces), and longer (0.1-0.5 s, the members back after the grace: a hold)
DOWN_S = ((0.0, 0.1), (0.1, 0.5))
#: (wall s) how long after the members the recorder is back in one blip of the loopback
#: runs: many more ticks than the plant re-publishes (25), had it not held time for it (a
#: CI run across namespaces once had its recorder back ~54 ticks after the members)
RECORDER_LATE_S = 1.5
#: (wall s) how long the recorder is frozen before the router goes in another blip, with
#: its token still there (the client config's lease is 1 s): unpaced, lockstep would run on
#: ~100 ticks past what it took in, more than the plant re-publishes, as a loaded machine
#: once let a recorder fall behind before a blip (docs/PROTOCOL.md section 4, "Watchers
#: that keep up")
RECORDER_LAG_S = 0.5


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def loopback_router() -> dict:
    """A router on a free loopback port; every process a client by the shipped
    client.json5 (docs/several-machines.md, plain TCP)."""
    port = free_port()
    env = {"DIFFBOT_ROUTER": "127.0.0.1", "DIFFBOT_PORT": str(port)}
    client = ["--zenoh-config", CLIENT]
    return {"router_args": ["--listen", f"tcp/127.0.0.1:{port}"], "plant_args": client,
            "node_args": client, "rec_args": client, "router_env": env, "plant_env": env,
            "ctrl_env": env}


def blip_plan(seed: str, n: int, after_s: tuple[float, float]) -> list[tuple[float, float]]:
    """``n`` (after, down) pairs, wall s, drawn with ``seed`` (the same every run)."""
    rng = random.Random(seed)
    return [(rng.uniform(*after_s), rng.uniform(*DOWN_S[i % len(DOWN_S)])) for i in range(n)]


#: the run, as the plant and its two members take it: the same in the blipped runs and in
#: the undisturbed reference (composed_square)
PLANT_ARGS = ("--world", "living_room", "--disable", "camera", "--seed", "0",
              "--duration", DURATION_S, "--end-with", "square_path_robot1")
ODOMETRY = ("fmu-node", "fmus/build/odometry_fmi2.fmu", "--robot", "robot1",
            "--name", "odometry_robot1")
SQUARE = ("controller", "square_path", "--robot", "robot1", "--side", "1.5",
          "--name", "square_path_robot1")


def square(tmp: str, coupling: str, bus: dict, ns: dict, blips: list[tuple[float, ...]]
           ) -> tuple[str, dict, str]:
    """A square run through a router: (MCAP path, plant stats, plant log). For each of
    ``blips``, (after, down[, late]): ``after`` wall s after the run started or the last
    rejoin, the router is SIGKILLed and restarted ``down`` s later; the plant must notice
    and the members rejoin each time. With ``late``, the recorder is frozen over the blip
    and let go ``late`` s after the members are back: it comes back after them (as a slow
    reconnect does), and the plant, which held time for it, goes on only then. With
    ``lag`` too, it is frozen ``lag`` s before the router goes: the plant, running on,
    comes to wait for it (docs/PROTOCOL.md section 4, "Watchers that keep up")."""
    os.makedirs(tmp, exist_ok=True)
    r = Procs(tmp)
    mcap, stats = os.path.join(tmp, "run.mcap"), os.path.join(tmp, "plant.json")
    try:
        router = start_router(r, bus, ns.get("router"))
        plant = r.diffbot("plant", *PLANT_ARGS, "--coupling", coupling,
                          "--expect", "odometry_robot1,square_path_robot1",
                          "--rejoin-timeout", "30", "--stats", stats, *bus["plant_args"],
                          name="plant", netns=ns.get("plant"), env=bus["plant_env"])
        rec = r.diffbot("record", mcap, "--compression", "none", *bus["rec_args"],
                        name="recorder", netns=ns.get("ctrl"), env=bus["ctrl_env"])
        wait_for(lambda: "recording" in r.log(rec) or rec.poll() is not None, 30,
                 what="the recorder")
        odometry = r.diffbot(*ODOMETRY, "--wait", *bus["node_args"],
                             name="odometry", netns=ns.get("ctrl"), env=bus["ctrl_env"])
        square_node = r.diffbot(*SQUARE, "--wait",
                                *bus["node_args"], name="square", netns=ns.get("ctrl"),
                                env=bus["ctrl_env"])
        wait_for(lambda: "running living_room" in r.log(plant), 60, what="the run")
        for i, (after, down, *late) in enumerate(blips):
            time.sleep(after)
            assert plant.poll() is None and "stopped at" not in r.log(plant), \
                f"the run ended before blip {i + 1} (too fast for the plan?): {r.log(plant)}"
            if late:
                rec.send_signal(signal.SIGSTOP)
                time.sleep(late[1] if len(late) > 1 else 0.0)
            router.send_signal(signal.SIGKILL)
            router.wait(5)
            time.sleep(down)
            router = start_router(r, bus, ns.get("router"))
            wait_for(lambda: r.log(plant).count("lockstep member rejoined") >= 2 * (i + 1),
                     30, what=f"both members back after blip {i + 1}")
            if late:
                assert "recorder went with the router" in r.log(plant), r.log(plant)
                time.sleep(late[0])
                rec.send_signal(signal.SIGCONT)
                wait_for(lambda: "recorder: time goes on" in r.log(plant), 30,
                         what=f"the recorder back after blip {i + 1}")
        assert plant.wait(120) == 0, r.log(plant)
        # every process ends by itself with the run (--wait included): none is killed here
        for p in (rec, odometry, square_node):
            assert p.wait(30) == 0, r.log(p)
            assert "Traceback" not in r.log(p)
        log = r.log(plant)
    finally:
        r.cleanup()
    # (each blip was seen: both members rejoined after it; a router back within the plant's
    # 0.25 s check may go without a "lost the router" line)
    with open(stats) as f:
        return mcap, json.load(f), log


def composed_square(tmp: str, coupling: str) -> tuple[str, dict, str]:
    """The undisturbed run of ``square``, its members hosted in the plant's process
    (``--compose``; the recorder a process, on a unix socket): the bytes of the same run over
    processes (tests/runs/test_composed.py) in 3.0 s and 4.6 s of CPU, against 7.7 s and 9.9 s
    for the members as processes through a router. The blipped runs are so compared with
    an undisturbed run that shares neither their processes nor their router."""
    os.makedirs(tmp, exist_ok=True)
    r = Procs(tmp)
    mcap, stats = os.path.join(tmp, "run.mcap"), os.path.join(tmp, "plant.json")
    ep = ["--endpoint", f"unixsock-stream/{tmp}/bus.sock"]
    try:
        plant = r.diffbot("plant", *PLANT_ARGS, "--coupling", coupling,
                          "--compose", " ".join(ODOMETRY), "--compose", " ".join(SQUARE),
                          "--wait-for", "recorder", "--stats", stats, *ep, name="plant")
        rec = r.diffbot("record", mcap, "--compression", "none", *ep, name="recorder")
        assert plant.wait(120) == 0, r.log(plant)
        assert rec.wait(30) == 0, r.log(rec)
        log = r.log(plant)
    finally:
        r.cleanup()
    with open(stats) as f:
        return mcap, json.load(f), log


def same_run(ref: tuple, got: tuple) -> None:
    lines = compare(ref[0], got[0])
    assert lines and all(ln.startswith("same") for ln in lines), "\n".join(lines)
    assert ref[1]["sim_time_s"] == got[1]["sim_time_s"] == pytest.approx(float(DURATION_S))
    assert got[1]["protocol_errors"] == {}, got[1]
    assert ref[1]["stale_commands"] == got[1]["stale_commands"] == 0


@pytest.fixture(scope="module")
def undisturbed(tmp_path_factory):
    """The undisturbed square of a coupling (composed_square), run once for both blip
    tests of the coupling: a run through a router, on loopback or across namespaces over
    TLS, records the same bytes as one without (tests/network/test_netns.py), so both blipped runs
    must too."""
    runs: dict[str, tuple] = {}

    def of(coupling: str) -> tuple:
        if coupling not in runs:
            runs[coupling] = composed_square(
                str(tmp_path_factory.mktemp(f"undisturbed-{coupling}")), coupling)
        return runs[coupling]
    return of


@pytest.mark.parametrize("coupling", COUPLINGS)
def test_router_blips_leave_the_recording_as_an_undisturbed_run_s(tmp_path, coupling,
                                                                 undisturbed):
    ref = undisturbed(coupling)
    plan = blip_plan(coupling, LOOPBACK_BLIPS, LOOPBACK_AFTER_S)
    plan[0] += (RECORDER_LATE_S,)            # the recorder back well after the members
    plan[1] += (0.0, RECORDER_LAG_S)         # ... far behind when the router goes
    got = square(str(tmp_path / "blips"), coupling, loopback_router(), {}, plan)
    same_run(ref, got)
    print(f"\n{coupling}: {LOOPBACK_BLIPS} of {LOOPBACK_BLIPS} router blips on loopback: "
          "recording identical")


#: the plant's --rejoin-timeout in the outage test, and how long the router stays away:
#: past the plant's giving up, short of the nodes' (the rejoin timeout + GRACE_S after the
#: router went), so they see the router back with no plant on it, and must end all the same
OUTAGE_REJOIN_S = 2.0
OUTAGE_S = 3.0
#: bus.plantwatch.GONE_GRACE_S, and scheduling noise on a loaded 2-core machine
GRACE_S, SLACK_S = 2.0, 3.0


@pytest.mark.serial                  # a wall-clock promise: runs alone under xdist
@pytest.mark.parametrize("coupling", COUPLINGS)
def test_a_router_lost_past_the_rejoin_timeout_ends_every_process_by_itself(tmp_path,
                                                                           coupling):
    """The router killed and back only after the plant gave up: the plant exits 1 ("lost
    lockstep member"), and its sim/end reaches nobody; the --wait nodes and the recorder,
    without the plant for longer than the run's rejoin timeout (sim/info) + 2 s, exit 3 by
    themselves, the router coming back in the meantime (~1 s before they give up) with no
    plant on it, and the recording is closed properly."""
    bus = loopback_router()
    tmp = str(tmp_path)
    r = Procs(tmp)
    mcap = os.path.join(tmp, "run.mcap")
    try:
        router = start_router(r, bus, None)
        plant = r.diffbot("plant", "--world", "living_room", "--disable", "camera",
                          "--coupling", coupling, "--seed", "0", "--duration", "600",
                          "--expect", "odometry_robot1,square_path_robot1",
                          "--rejoin-timeout", str(OUTAGE_REJOIN_S), *bus["plant_args"],
                          name="plant", env=bus["plant_env"])
        rec = r.diffbot("record", mcap, "--compression", "none", *bus["rec_args"],
                        name="recorder", env=bus["ctrl_env"])
        wait_for(lambda: "INFO recording" in r.log(rec) or rec.poll() is not None, 30,
                 what="the recorder")
        nodes = [r.diffbot("fmu-node", "fmus/build/odometry_fmi2.fmu", "--robot", "robot1",
                           "--name", "odometry_robot1", "--wait", *bus["node_args"],
                           name="odometry", env=bus["ctrl_env"]),
                 r.diffbot("controller", "square_path", "--robot", "robot1", "--side", "1.5",
                           "--name", "square_path_robot1", "--wait", *bus["node_args"],
                           name="square", env=bus["ctrl_env"])]
        wait_for(lambda: "running living_room" in r.log(plant), 60, what="the run")
        time.sleep(0.5)
        router.send_signal(signal.SIGKILL)
        router.wait(5)
        lost = time.monotonic()
        assert plant.wait(OUTAGE_REJOIN_S + SLACK_S + 1) == 1, r.log(plant)
        assert "not back within --rejoin-timeout" in r.log(plant)
        time.sleep(max(0.0, OUTAGE_S - (time.monotonic() - lost)))
        start_router(r, bus, None)             # back, with no plant left to end the run
        deadline = lost + OUTAGE_REJOIN_S + GRACE_S + SLACK_S + 1 + OUTAGE_S
        for p in (*nodes, rec):
            code = p.wait(max(1.0, deadline - time.monotonic()))
            log = r.log(p)
            assert code == 3, log
            assert "the plant has been gone for" in log and "Traceback" not in log, log
            assert f"rejoin timeout ({OUTAGE_REJOIN_S:g} s" in log, log
    finally:
        r.cleanup()
    with open(mcap, "rb") as f:                  # closed properly: summary and footer
        assert f.read()[-8:] == b"\x89MCAP0\r\n"
    assert topics_of(mcap)["/sim/clock"], "recorded nothing"


@pytest.mark.parametrize("coupling", COUPLINGS)
def test_router_blips_across_namespaces_over_tls(tmp_path, net, coupling, undisturbed):
    """The full case: three namespaces, the shipped TLS configs and the docs' steps
    (tests/network/test_netns.py); NETNS_BLIPS short blips per coupling in one run each, compared
    with the undisturbed run on loopback."""
    remote = tls_machines(str(tmp_path))
    ref = undisturbed(coupling)
    got = square(str(tmp_path / "blips"), coupling, remote, net.ns,
                 blip_plan(f"netns-{coupling}", NETNS_BLIPS, NETNS_AFTER_S))
    same_run(ref, got)
    print(f"\n{coupling}: {NETNS_BLIPS} of {NETNS_BLIPS} router blips across namespaces: "
          "recording identical")
