"""`diffbot run SCENARIO --place ...` (diffbot/launch/placement.py): a scenario's processes on the
nodes of a real two-node Ray cluster on this machine (tests/support/ray_cluster.py), the plant on
one node and the controllers on the other, give the local run's summary metrics to the
bit (lockstep); Ctrl-C of a placed run leaves no process on either node. Plus the
placement's bad input, which needs no cluster."""
from __future__ import annotations

import json
import os
import time

import pytest

from diffbot.runner import procs as dprocs
from diffbot.launch.scenario_run import RECORDER, VIEW, ScenarioRun
from diffbot.launch.placement import CONFIGS, Placement, PlacementError, assign, parse_place, resolve
from diffbot.launch.scenario import load_scenario

from ..conftest import wait_for
from ..network.test_exposure import cmdline

#: xdist_group: one worker starts the session's Ray cluster (conftest.ray_cluster)
pytestmark = pytest.mark.xdist_group("ray")
SQUARE = ("run", "square", "--seed", "0", "--duration", "12")
#: what differs between two runs of the same lockstep scenario, wherever they run
NOT_COMPARED = {"wall_time_s", "plant_wall_time_s", "real_time_factor", "plant_per_tick_ms",
                "cpu_per_tick_ms", "placement"}
NODES = [{"id": "a1b2c3d4e5f6" * 4, "address": "10.0.0.1", "hostname": "sim", "cpus": 8,
          "resources": ["plant"]},
         {"id": "0f9e8d7c6b5a" * 4, "address": "10.0.0.2", "hostname": "robot", "cpus": 4,
          "resources": []},
         {"id": "77aa77aa77aa" * 4, "address": "10.0.0.2", "hostname": "robot", "cpus": 4,
          "resources": ["gpu-box"]}]


def test_place_names_processes_by_name_prefix_or_star():
    names = ["plant", "odometry_robot1", "square_path_robot1"]
    assert assign(parse_place(["plant=a,square_path=b"]), names) == \
        {"plant": "a", "square_path_robot1": "b"}
    assert assign(parse_place(["*=b", "plant=a"]), names) == \
        {"plant": "a", "odometry_robot1": "b", "square_path_robot1": "b"}
    assert assign({"odometry_robot1": "c", "odometry": "d"}, names) == {"odometry_robot1": "c"}
    with pytest.raises(PlacementError, match="no such process.*square_path_robot1"):
        assign({"camera": "a"}, names)
    for bad in ("plant", "plant=", "=a", "plant=a,plant=b"):
        with pytest.raises(PlacementError):
            parse_place([bad])


def test_a_host_is_a_node_id_prefix_ip_host_name_or_resource_and_one_node_only():
    assert resolve("a1b2c3", NODES) is NODES[0]
    assert resolve("10.0.0.1", NODES) is NODES[0]
    assert resolve("sim", NODES) is NODES[0]
    assert resolve("gpu-box", NODES) is NODES[2]
    assert resolve(NODES[1]["id"], NODES) is NODES[1]
    with pytest.raises(PlacementError, match="names 2 Ray nodes"):
        resolve("robot", NODES)
    with pytest.raises(PlacementError, match="no live Ray node is 'elsewhere'.*10.0.0.2"):
        resolve("elsewhere", NODES)
    with pytest.raises(PlacementError, match="no live Ray node"):
        resolve("a1b", NODES)                          # too short a prefix to mean an id


def test_with_tls_every_process_gets_the_shipped_config_of_its_role(tmp_path):
    run = ScenarioRun(load_scenario("square"), str(tmp_path), "lockstep", 0, "",
                      zenoh_config=os.path.join(CONFIGS, "recorder_tls.json5"),
                      record=str(tmp_path / "r.mcap"), view_port=0,
                      placement=Placement(where={}, tls=True))
    run.build()
    config = {c.name: os.path.basename(c.argv[c.argv.index("--zenoh-config") + 1])
              for c in run.children}
    assert config == {"plant": "plant_tls.json5", RECORDER: "recorder_tls.json5",
                      VIEW: "view_tls.json5", "odometry_robot1": "node_tls.json5",
                      "square_path_robot1": "node_tls.json5"}
    assert all(c.argv.count("--zenoh-config") == 1 for c in run.children)


@pytest.mark.slow
def test_a_bad_placement_exits_2_before_anything_starts(procs, tmp_path):
    p = procs.diffbot("run", "square", "--place", "lidar=here", "--out", str(tmp_path / "o"))
    assert p.wait(60) == 2
    assert "no such process in this run (processes: plant, odometry_robot1, " \
        "square_path_robot1)" in procs.log(p)
    p = procs.diffbot("run", "square", "--address", "auto", "--out", str(tmp_path / "o"))
    assert p.wait(60) == 2
    assert "add --place NAME=HOST" in procs.log(p)


# ---------------------------------------------------------------- on a real cluster
@pytest.fixture
def cluster(ray_cluster):
    """The session's two-node cluster (conftest), both nodes alive."""
    ray_cluster.revive()
    return ray_cluster


def ray_env(cluster) -> dict:
    return {k: v for k, v in cluster.env.items() if k.startswith("RAY_")}


def where(cluster, out: str) -> dict[str, set[str]]:
    """Which of the run's processes run under which node's process tree ("head"/"worker")."""
    found: dict[str, set[str]] = {}
    for label, node in zip(("head", "worker"), cluster.nodes):
        for pid in dprocs.descendants(node.pid):
            cmd = cmdline(pid)
            if out in cmd and "diffbot.cli" in cmd:
                found.setdefault(label, set()).add(cmd.split("diffbot.cli ")[1].split()[0])
    return found


def placed(procs, cluster, out: str, *args: str):
    return procs.diffbot(*args, "--out", out, "--address", cluster.address,
                         "--place", "plant=head,*=worker", env=ray_env(cluster))


# (first in the file: the session's Ray cluster starts in this test's turn, not in the
# serial one below, which the other xdist worker waits out)
@pytest.mark.slow
@pytest.mark.timeout(300)
def test_ctrl_c_of_a_placed_run_leaves_no_process_on_either_node(cluster, procs, tmp_path):
    out = str(tmp_path / "stopped")
    p = placed(procs, cluster, out, "run", "square", "--duration", "300")
    wait_for(lambda: where(cluster, out) == {"head": {"plant"},
                                             "worker": {"fmu-node", "controller"}},
             120, 0.1, "the plant on the head, the controllers on the worker")
    time.sleep(1.0)
    tree = [pid for n in cluster.nodes for pid in dprocs.descendants(n.pid)
            if out in cmdline(pid)]
    p.send_signal(2)
    assert p.wait(120) == 130, procs.log(p)
    assert not [pid for pid in tree if dprocs.alive(pid)]
    assert not where(cluster, out)
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    assert summary["end_reason"] == "interrupted (SIGINT)"
    assert set(summary["exit_codes"]) == {"plant", "odometry_robot1", "square_path_robot1"}


@pytest.mark.serial      # the plant exits within the stop grace (exit_codes): alone under xdist
@pytest.mark.slow
@pytest.mark.timeout(420)
def test_placed_square_gives_the_local_runs_summary(cluster, procs, tmp_path):
    local, on_ray = str(tmp_path / "local"), str(tmp_path / "ray")
    p = procs.diffbot(*SQUARE, "--out", local)
    assert p.wait(180) == 0, procs.log(p)

    p = placed(procs, cluster, on_ray, *SQUARE)
    seen: dict[str, set[str]] = {}
    while p.poll() is None:
        for k, v in where(cluster, on_ray).items():
            seen.setdefault(k, set()).update(v)
        time.sleep(0.1)
    assert p.returncode == 0, procs.log(p)
    assert seen == {"head": {"plant"}, "worker": {"fmu-node", "controller"}}, seen

    with open(os.path.join(local, "summary.json")) as f:
        ref = json.load(f)
    with open(os.path.join(on_ray, "summary.json")) as f:
        got = json.load(f)
    assert got["metrics"]["final_odom_error_m"] is not None
    ids = {n: got["placement"][n].get("id") for n in got["exit_codes"]}
    assert ids["odometry_robot1"] == ids["square_path_robot1"] != ids["plant"], ids
    assert None not in ids.values(), ids               # every process on a Ray node
    assert {k: v for k, v in got.items() if k not in NOT_COMPARED} == \
        {k: v for k, v in ref.items() if k not in NOT_COMPARED}
    # the same results folder as a local run: every process's log and statistics, the plots
    assert sorted(os.listdir(os.path.join(on_ray, "logs"))) == \
        sorted(os.listdir(os.path.join(local, "logs")))
    assert sorted(os.listdir(on_ray)) == sorted(os.listdir(local))
