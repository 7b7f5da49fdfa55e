"""`diffbot sweep --engine ray --address` on a real two-node Ray cluster on this machine
(tests/support/ray_cluster.py): runs land on both nodes, give the local engine's metrics to the
bit, and a worker node killed mid-sweep loses no row."""
from __future__ import annotations

import glob
import json
import os
import time

import pytest

from diffbot.runner import procs as dprocs

from ..conftest import LOCAL_SWEEP, wait_for
from ..runs.test_sweep import _cmdline, read_rows

ray = pytest.importorskip("ray", reason="the [cluster] extra (make setup installs it)")

#: xdist_group: one worker starts the session's Ray cluster (conftest.ray_cluster)
pytestmark = [pytest.mark.slow, pytest.mark.timeout(420), pytest.mark.xdist_group("ray")]
SWEEP = LOCAL_SWEEP                  # (conftest.local_sweep is its run on the local engine)
#: what must be identical between engines: the parameters and every metric
NOT_COMPARED = {"run", "wall_time_s", "real_time_factor", "node", "host", "out", "log_tail"}


@pytest.fixture
def cluster(ray_cluster):
    """The session's two-node cluster (conftest), both nodes alive."""
    ray_cluster.revive()
    return ray_cluster


def sweep(procs, out: str, *extra: str, env=None):
    p = procs.diffbot(*SWEEP, "--out", out, *extra, env=env)
    return p


def ray_env(cluster) -> dict:
    """The cluster's token (and auth mode) for the sweep: extra environment variables."""
    return {k: v for k, v in cluster.env.items() if k.startswith("RAY_")}


def test_ctrl_c_stops_the_runs_on_every_node(cluster, procs, tmp_path):
    out = str(tmp_path / "stopped")
    p = procs.diffbot("sweep", "follow", "--grid", "robots.follower.camera.noise.std=0,10",
                      "--duration", "300", "--cpus-per-run", "1", "--out", out,
                      "--engine", "ray", "--address", cluster.address, env=ray_env(cluster))

    def runs_on(node) -> list[int]:
        return [pid for pid in dprocs.descendants(node.pid) if out in _cmdline(pid)]
    wait_for(lambda: all(runs_on(n) for n in cluster.nodes), 120, 0.1, "a run on each node")
    # each run's plant started: its launcher takes SIGINT as a stop request by then
    wait_for(lambda: len(glob.glob(os.path.join(out, "runs", "*", "logs", "plant.log"))) == 2,
             60, 0.05, "both runs' plants")
    tree = [pid for n in cluster.nodes for pid in dprocs.descendants(n.pid)
            if "diffbot.cli" in _cmdline(pid)]
    p.send_signal(2)
    assert p.wait(120) == 130, procs.log(p)
    assert not [pid for pid in tree if dprocs.alive(pid)]
    rows = read_rows(out)
    assert [r["status"] for r in rows] == ["interrupted", "interrupted"]
    # each run stopped itself on the SIGINT and summed up what it ran (not killed after
    # the stop grace, which leaves no summary)
    for r in rows:
        with open(os.path.join(out, r["out"], "summary.json")) as f:
            assert json.load(f)["end_reason"] == "interrupted (SIGINT)", r


def test_two_nodes_same_metrics_as_local_and_a_dead_worker_loses_nothing(cluster, procs,
                                                                        tmp_path, local_sweep):
    env = ray_env(cluster)
    local = local_sweep["out"]          # the same sweep on the local engine (conftest)

    on_ray = str(tmp_path / "ray")
    p = sweep(procs, on_ray, "--engine", "ray", "--address", cluster.address, env=env)
    assert p.wait(150) == 0, procs.log(p)
    rows, ref = read_rows(on_ray), read_rows(local)
    # DIFFBOT_PLOTS=0 (the suite's): the table alone, no figure of the sweep or of a run
    assert not [f for _, _, fs in os.walk(on_ray) for f in fs if f.endswith(".png")]
    assert len({r["node"] for r in rows}) == 2, [r["node"] for r in rows]
    for a, b in zip(rows, ref):
        assert a["status"] == "ok"
        assert {k: v for k, v in a.items() if k not in NOT_COMPARED} == \
            {k: v for k, v in b.items() if k not in NOT_COMPARED}

    # the worker node dies while its runs are in flight: Ray runs them again on the head
    killed = str(tmp_path / "killed")
    p = sweep(procs, killed, "--engine", "ray", "--address", cluster.address, env=env)
    worker = cluster.nodes[1]

    def run_on_worker() -> bool:
        return any("diffbot.cli run" in _cmdline(pid) for pid in dprocs.descendants(worker.pid))
    wait_for(run_on_worker, 120, 0.05, "a run on the worker node")
    time.sleep(0.5)
    dprocs.stop([worker], grace_s=0.0, sig=9)            # the whole node, at once
    t_kill = time.monotonic()
    assert p.wait(240) == 0, procs.log(p)
    rows = read_rows(killed)
    assert len(rows) == 4 and all(r["status"] == "ok" for r in rows), rows
    for a, b in zip(rows, ref):
        assert {k: v for k, v in a.items() if k not in NOT_COMPARED} == \
            {k: v for k, v in b.items() if k not in NOT_COMPARED}
    assert time.monotonic() - t_kill < 200

