"""Promises of the docs about running that had no test: SIGTERM to ``diffbot run`` is
Ctrl-C (docs/scenarios.md), ``required = false`` in a scenario file, the plant's
``--join-timeout`` with an expected member that never joins (docs/PROTOCOL.md section 1),
and ``--namespace`` end to end: two namespaced runs through one router see nothing of
each other, and a run's recording holds its own keys only."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest
import zenoh

from ..conftest import ROOT, SLACK_S, wait_for
from ..runs.test_scenarios import processes_mentioning

pytestmark = pytest.mark.slow


def run_cmd(*args, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "diffbot.cli", "run", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            stdin=subprocess.DEVNULL, start_new_session=True, **kw)


def finish(p: subprocess.Popen, timeout: float = 120) -> tuple[int, str]:
    try:
        _, err = p.communicate(timeout=timeout)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(5)
    return p.returncode, err


# ---------------------------------------------------------------------- SIGTERM

@pytest.mark.serial                  # a wall-clock promise: runs alone under xdist
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_sigterm_to_diffbot_run_does_what_ctrl_c_does(tmp_path, sig):
    out = tmp_path / "run"
    p = run_cmd("drive-test", "--mode", "realtime", "--out", str(out))
    try:
        plant_log = out / "logs" / "plant.log"
        wait_for(lambda: plant_log.exists() and "running" in plant_log.read_text(), 60,
                 what="the plant to run")
        ctrl_log = out / "logs" / "wheel_schedule_robot1.log"
        wait_for(lambda: ctrl_log.exists() and "mode realtime" in ctrl_log.read_text(), 60,
                 what="the controller to run")
        children = f"{out}/logs/"                  # in each child's command line (--stats)
        assert len(processes_mentioning(children)) == 2          # the plant, the controller
        p.send_signal(sig)
        sent = time.monotonic()
        # "stops every child within 2 s" (then it writes the summary and the plots)
        wait_for(lambda: not processes_mentioning(children), 2.0 + SLACK_S,
                 what=f"every child to stop after {sig.name}")
        code, err = finish(p, 60)
    finally:
        if p.poll() is None:
            p.kill()
    assert code == 130, err                         # EXIT_INTERRUPTED, for either signal
    assert not processes_mentioning(str(out)), "a process outlived the run"
    s = json.loads((out / "summary.json").read_text())
    assert s["end_reason"] == f"interrupted ({sig.name})"
    assert s["exit_code"] == 130
    # (a child the launcher had to SIGKILL: its stderr says which and how long after its
    # SIGINT, scenario_run.stop_all)
    assert s["exit_codes"] == {"plant": 0, "wheel_schedule_robot1": 0}, (s["exit_codes"], err)
    assert s["sim_time_s"] > 0 and "Traceback" not in err


# ---------------------------------------------------------------------- required = false

SCENARIO = """
[scenario]
world = "empty"
mode = "lockstep"
duration_s = 30.0

[[process]]
name = "wheel_schedule_robot1"
command = ["controller", "wheel_schedule", "--robot", "robot1", "--schedule", "12:1,1"]
ends_run = true

[[process]]
name = "broken"
command = ["controller", "wheel_schedule", "--robot", "robot1", "--schedule", "nonsense"]
sync = false
{required}
"""


@pytest.mark.parametrize("required", [False, True])
def test_a_process_not_required_may_die_without_ending_the_run(tmp_path, required):
    # (12 s simulated, a few wall seconds in lockstep: long enough that the broken process,
    # started beside it, has died by itself before the run ends, however slow its start)
    path = tmp_path / "optional.toml"
    path.write_text(SCENARIO.format(required=f"required = {str(required).lower()}"))
    out = tmp_path / "run"
    code, err = finish(run_cmd(str(path), "--out", str(out)))
    s = json.loads((out / "summary.json").read_text())
    assert s["exit_codes"]["broken"] == 2, s["exit_codes"]        # a bad option: exit 2
    if required:                                                    # the default
        assert code == 1 and s["end_reason"] == "broken failed with exit code 2", (code, err)
        return
    assert code == 0, err
    assert s["end_reason"] == "plant: wheel_schedule_robot1 finished", s["end_reason"]
    assert s["sim_time_s"] == pytest.approx(12.0, abs=0.05)
    assert s["exit_codes"]["wheel_schedule_robot1"] == 0 and s["exit_codes"]["plant"] == 0


# ---------------------------------------------------------------------- --join-timeout

@pytest.mark.serial                  # a wall-clock promise: runs alone under xdist
def test_join_timeout_ends_a_plant_whose_expected_member_never_joins(procs, endpoint, tmp_path):
    stats = tmp_path / "plant.json"
    p = procs.diffbot("plant", "--world", "empty", "--mode", "lockstep", "--expect",
                      "odometry_robot1,ghost", "--join-timeout", "2", "--stats", str(stats),
                      "--endpoint", endpoint, name="plant")
    procs.diffbot("controller", "odometry", "--endpoint", endpoint, name="odo")
    wait_for(lambda: "lockstep member joined: odometry_robot1" in procs.log(p), 60,
             what="the member that does come")
    # it gives up after the 2 s (not the default 30; 5 s for closing on a loaded machine)
    assert p.wait(2 + 5) == 1, procs.log(p)
    log = procs.log(p)
    # ... on the one that never came, and only on it
    assert "nodes did not join within 2 s: ghost" in log, log
    s = json.loads(stats.read_text())
    assert s["ticks"] == 0 and s["sim_time_s"] == 0


@pytest.mark.serial                  # a wall-clock promise: runs alone under xdist
def test_join_timeout_is_waited_out_in_full(procs, endpoint):
    p = procs.diffbot("plant", "--world", "empty", "--mode", "lockstep", "--expect", "ghost",
                      "--join-timeout", "3", "--endpoint", endpoint, name="plant")
    wait_for(lambda: "waiting for nodes: ghost" in procs.log(p), 60, what="the plant to wait")
    waiting = time.monotonic()
    assert p.wait(3 + 5) == 1, procs.log(p)
    assert time.monotonic() - waiting > 3 - 0.2, "gave up before --join-timeout"


# ---------------------------------------------------------------------- --namespace

@pytest.fixture
def router(tmp_path, endpoint):
    """A Zenoh router in this process and a client config file for it."""
    ep = endpoint
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([ep]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    r = zenoh.open(conf)
    client = tmp_path / "client.json5"
    client.write_text('{ mode: "client", connect: { endpoints: ["%s"] },\n'
                      '  listen: { endpoints: [] },\n'
                      '  scouting: { multicast: { enabled: false }, gossip: { enabled: false } } }\n'
                      % ep)
    try:
        yield r, client
    finally:
        r.close()


def test_two_namespaced_runs_on_one_router_see_nothing_of_each_other(router, tmp_path):
    r, client = router
    keys: set[str] = set()
    sub = r.declare_subscriber("**", lambda s: keys.add(str(s.key_expr)))
    runs = {}
    for ns in ("a", "b"):
        args = ["drive-test", "--zenoh-config", str(client), "--namespace", ns,
                "--out", str(tmp_path / ns)]
        if ns == "a":
            args += ["--record", str(tmp_path / "a.mcap")]
        runs[ns] = run_cmd(*args)
    results = {ns: finish(p, 180) for ns, p in runs.items()}
    sub.undeclare()
    for ns, (code, err) in results.items():
        assert code == 0, f"{ns}: {err}"
    sa, sb = (json.loads((tmp_path / ns / "summary.json").read_text()) for ns in "ab")
    # the same scenario and seed, each undisturbed by the other: the same run, no rejects
    assert sa["metrics"] == sb["metrics"]
    assert {k[2:]: n for k, n in sa["message_counts"].items()} == \
        {k[2:]: n for k, n in sb["message_counts"].items()}
    assert all(k.startswith("a/") for k in sa["message_counts"]), sa["message_counts"]
    assert all(k.startswith("b/") for k in sb["message_counts"]), sb["message_counts"]
    for s in (sa, sb):
        assert all(not v for v in s["rejected"].values()), s["rejected"]
    for ns in "ab":
        plant = json.loads((tmp_path / ns / "logs" / "plant.json").read_text())
        assert plant["members_seen"] == ["wheel_schedule_robot1"]
        assert plant["protocol_errors"] == {}
    # every key on the router is under one of the two prefixes
    assert keys and all(k.startswith(("a/", "b/")) for k in keys), sorted(keys)[:10]
    assert {"a/sim/clock", "b/sim/clock"} <= keys
    # a's recording holds a's messages, as many as a's summary counts, and none of b's
    from ..bridges.test_record_replay import mcap_summary
    _, counts, _ = mcap_summary(tmp_path / "a.mcap")
    derived = {"/a/scene", "/a/tf", "/a/tf_static"}     # the recorder's, for 3-D viewers
    assert derived <= set(counts), sorted(counts)
    assert {t: n for t, n in counts.items() if t not in derived} == \
        {f"/{k}": n for k, n in sa["message_counts"].items()}


# ---------------------------------------------------------------------- the end of a run

def test_at_the_plant_s_end_the_nodes_end_by_themselves_before_they_are_asked(tmp_path):
    """A plant that ended the run (exit 0) published sim/end: its nodes end by themselves,
    and the launcher asks them to stop only if they have not within END_GRACE_S. Asked at
    once, a node still finishing raced the request: a placed node's Ray task cancelled as it
    returned lost the node's exit code (a summary.json said -2 for a node that ended 0)."""
    from diffbot.runner import procs
    from diffbot.launch.scenario import load_scenario
    from diffbot.launch.scenario_run import END_GRACE_S, ScenarioRun
    run = ScenarioRun(load_scenario("square"), str(tmp_path), "lockstep", 0, "")
    plant = procs.Child("plant", [sys.executable, "-c", "pass"], str(tmp_path / "p.log"))
    plant.start().wait(30)
    # a node a SIGINT would end with -2 (KeyboardInterrupt), done in half a second
    finishing = 0.5
    node = procs.Child("node", [sys.executable, "-c", f"import time; time.sleep({finishing})"],
                       str(tmp_path / "n.log")).start()
    run.children, run.recorder = [plant, node], None
    t0 = time.monotonic()
    run.stop_all()
    assert plant.exit_code == 0 and node.exit_code == 0, node.describe_exit()
    assert time.monotonic() - t0 < END_GRACE_S, "waited out the grace for a node that had ended"


def test_on_ctrl_c_the_plant_gets_the_grace_its_nodes_did_not_use(tmp_path):
    """Ctrl-C: the nodes are asked to stop, then the plant, and whatever is left after
    STOP_GRACE_S in all is killed. The plant once got a fixed half of it (0.75 s); on a
    loaded machine a plant that needed more was SIGKILLed and its statistics lost
    (summary.json: sim_time_s null). Nodes that end at once leave it the rest."""
    from diffbot.runner import procs
    from diffbot.launch.scenario import load_scenario
    from diffbot.launch.scenario_run import STOP_GRACE_S, ScenarioRun
    run = ScenarioRun(load_scenario("square"), str(tmp_path), "realtime", 0, "")
    slow = 0.7 * STOP_GRACE_S            # more than half the grace, less than all of it
    plant = procs.Child("plant", [sys.executable, "-c", (
        "import signal, sys, time\n"
        f"signal.signal(signal.SIGINT, lambda *a: (time.sleep({slow}), sys.exit(0)))\n"
        "print('ready', flush=True)\n"
        "while True: time.sleep(1)\n")], str(tmp_path / "p.log")).start()
    node = procs.Child("node", [sys.executable, "-c", "import time; time.sleep(60)"],
                       str(tmp_path / "n.log")).start()
    wait_for(lambda: "ready" in (tmp_path / "p.log").read_text(), 30, what="the plant")
    run.children, run.recorder = [plant, node], None
    t0 = time.monotonic()
    run.stop_all()
    assert plant.exit_code == 0, plant.describe_exit()           # ended by itself
    assert node.exit_code not in (None, -signal.SIGKILL)         # stopped by the SIGINT
    assert time.monotonic() - t0 < STOP_GRACE_S + SLACK_S
