"""A real Ray cluster on this machine for tests: a head and worker nodes, each a
``ray start --block`` process of its own (own temp dir, free ports, 127.0.0.1 only, token
auth), stopped by PID with its whole process tree -- never a global ``ray stop``, which
would end other people's clusters on the same machine."""
from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
import time

from diffbot.runner import procs

RAY = os.path.join(os.path.dirname(sys.executable), "ray")
PORT_OPTIONS = ("--node-manager-port", "--object-manager-port", "--metrics-export-port",
                "--dashboard-agent-listen-port", "--dashboard-agent-grpc-port",
                "--runtime-env-agent-port")


def free_ports(n: int) -> list[int]:
    socks = []
    for _ in range(n):
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        socks.append(s)
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


class Cluster:
    def __init__(self) -> None:
        self.tmp = tempfile.mkdtemp(prefix="dbray-", dir="/tmp")   # short: unix sockets
        self.env = dict(os.environ, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32),
                        RAY_USAGE_STATS_ENABLED="0",
                        # a dead node is noticed in ~3 s instead of ~30 s
                        RAY_health_check_period_ms="1000", RAY_health_check_timeout_ms="1000",
                        RAY_health_check_failure_threshold="3")
        self.nodes: list[procs.Child] = []
        self.dead: list[procs.Child] = []      # nodes a test killed (see revive)
        self.address = ""

    def start_node(self, num_cpus: int, head: bool = False,
                   resources: dict | None = None) -> procs.Child:
        """A node; ``resources``: custom resources (``ray start --resources``), by which a
        test can name the node (``diffbot run --place plant=NAME``)."""
        i = len(self.nodes)
        ports = free_ports(len(PORT_OPTIONS) + 1 + 10)
        argv = [RAY, "start", "--block", "--node-ip-address=127.0.0.1", f"--num-cpus={num_cpus}",
                "--disable-usage-stats", "--include-log-monitor=false",
                *[f"{o}={p}" for o, p in zip(PORT_OPTIONS, ports)],
                f"--worker-port-list={','.join(map(str, ports[len(PORT_OPTIONS) + 1:]))}"]
        if resources:
            argv.append(f"--resources={json.dumps(resources)}")
        if head:
            self.address = f"127.0.0.1:{ports[len(PORT_OPTIONS)]}"
            argv += ["--head", f"--port={ports[len(PORT_OPTIONS)]}", "--include-dashboard=false",
                     f"--temp-dir={self.tmp}"]
        else:
            argv += [f"--address={self.address}"]
        node = procs.Child(f"ray{i}", argv, os.path.join(self.tmp, f"node{i}.log"),
                           env=self.env, die_with_parent=True).start()
        node.spec = (num_cpus, head, resources)
        self.nodes.append(node)
        return node

    def wait_started(self, node: procs.Child, timeout_s: float = 60.0) -> None:
        """Wait until ``ray start`` says the node's runtime started (its log; polling that
        file costs nothing, where each ``ray status`` is a second or two of CPU that the
        starting node would want)."""
        deadline = time.monotonic() + timeout_s
        while "Ray runtime started" not in node.tail(10_000) and time.monotonic() < deadline:
            if node.poll() is not None:
                raise RuntimeError(f"{node.name} exited {node.exit_code}:\n{node.tail(30)}")
            time.sleep(0.05)

    def wait_nodes(self, n: int, timeout_s: float = 60.0, exactly: bool = False) -> None:
        """Wait until ``ray status`` shows ``n`` live nodes (at least, or ``exactly``)."""
        deadline = time.monotonic() + timeout_s
        out = ""
        while time.monotonic() < deadline:
            for node in self.nodes:
                if node.poll() is not None:
                    raise RuntimeError(f"{node.name} exited {node.exit_code}:\n{node.tail(30)}")
            r = subprocess.run([RAY, "status", f"--address={self.address}"], env=self.env,
                               capture_output=True, text=True, timeout=60)
            out = r.stdout
            active = out.split("Active:", 1)[-1].split("Pending:", 1)[0]   # not the dead ones
            live = active.count(" node_")
            if r.returncode == 0 and (live == n if exactly else live >= n):
                return
            time.sleep(1.0)
        raise RuntimeError(f"not {n} Ray nodes after {timeout_s:g} s:\n{out}")

    def revive(self) -> None:
        """A new worker (same CPUs and resources) for each one a test killed, so that the
        next test that shares this cluster finds all its nodes."""
        dead = [n for n in self.nodes[1:] if n.poll() is not None]
        if not dead:
            return
        for node in dead:
            self.nodes.remove(node)
            self.dead.append(node)
        self.wait_nodes(len(self.nodes), exactly=True)   # Ray has seen them die
        for node in dead:
            self.wait_started(self.start_node(*node.spec))
        self.wait_nodes(len(self.nodes), exactly=True)

    def stop(self) -> None:
        procs.stop(self.nodes + self.dead, grace_s=10.0)
        shutil.rmtree(self.tmp, ignore_errors=True)


@contextlib.contextmanager
def two_nodes(cpus: int = 1):
    """A head and a worker node (``cpus`` each; custom resources ``head`` and ``worker`` name
    them), stopped afterwards; fails if a Ray process outlived the cluster. The tests share
    one (conftest's ``ray_cluster``, for the session): starting one takes tens of seconds."""
    c = Cluster()
    try:
        # the worker joins once the head's runtime is up; `ray status` is asked only then
        c.wait_started(c.start_node(cpus, head=True, resources={"head": 1}))
        c.wait_started(c.start_node(cpus, resources={"worker": 1}))
        c.wait_nodes(2)
        yield c
    finally:
        pids = {p for n in c.nodes + c.dead if n.pid
                for p in [n.pid, *procs.descendants(n.pid)]}
        c.stop()
        assert not [p for p in pids if procs.alive(p)], "a Ray process outlived the cluster"

