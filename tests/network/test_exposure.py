"""Exposure: by default nothing listens beyond loopback and nothing multicasts; the
multi-machine set-up (a router, clients, TLS + access control) works as documented.

Sockets are attributed to the run's processes through /proc/<pid>/fd (socket inodes) and
/proc/net/{tcp,tcp6,udp,udp6}; multicast memberships are per interface in
/proc/net/igmp{,6}, so those are compared before and during the run.
"""
from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time

import pytest
import zenoh

from ..conftest import ROOT, wait_for
from ..runs.test_scenarios import processes_mentioning

#: serial: multicast memberships and the default port are the whole machine's (a second xdist worker would disturb it: tests/conftest.py)
pytestmark = [pytest.mark.slow, pytest.mark.serial]
CONFIGS = os.path.join(ROOT, "diffbot", "launch", "configs")
LOOPBACK = {"127.0.0.1", "::1"}


# ---------------------------------------------------------------------- /proc helpers

def _addr(hexaddr: str) -> tuple[str, int]:
    ip, port = hexaddr.split(":")
    raw = bytes.fromhex(ip)
    # /proc/net prints each 32-bit word in host (little-endian) order
    raw = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
    fam = socket.AF_INET if len(raw) == 4 else socket.AF_INET6
    text = socket.inet_ntop(fam, raw)
    if text.startswith("::ffff:") and "." in text:        # v4-mapped
        text = text[7:]
    return text, int(port, 16)


def proc_net() -> list[dict]:
    """Every TCP/UDP socket of this network namespace."""
    out = []
    for kind in ("tcp", "tcp6", "udp", "udp6"):
        try:
            with open(f"/proc/net/{kind}") as f:
                lines = f.read().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            parts = line.split()
            (lip, lport), (rip, rport) = _addr(parts[1]), _addr(parts[2])
            out.append({"kind": kind, "local": lip, "lport": lport, "remote": rip,
                        "rport": rport, "state": parts[3], "inode": int(parts[9])})
    return out


def socket_inodes(pids) -> dict[int, int]:
    """inode -> pid for the sockets the processes hold."""
    out = {}
    for pid in pids:
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:
            continue
        for fd in fds:
            try:
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            m = re.match(r"socket:\[(\d+)\]", target)
            if m:
                out[int(m.group(1))] = pid
    return out


def is_multicast_or_any(ip: str) -> bool:
    if ip in ("0.0.0.0", "::"):
        return True
    if ":" in ip:
        return ip.lower().startswith("ff")
    return 224 <= int(ip.split(".")[0]) <= 239


def exposure_problems(pids) -> list[str]:
    """Listeners beyond loopback, UDP sockets bound to an any/multicast address."""
    inodes = socket_inodes(pids)
    problems = []
    for s in proc_net():
        pid = inodes.get(s["inode"])
        if pid is None:
            continue
        where = f"pid {pid} ({cmdline(pid)[:80]}): {s['kind']} {s['local']}:{s['lport']}"
        if s["kind"].startswith("tcp") and s["state"] == "0A" and s["local"] not in LOOPBACK:
            problems.append(f"{where} listens beyond loopback")
        if s["kind"].startswith("udp") and is_multicast_or_any(s["local"]) and s["rport"] == 0:
            problems.append(f"{where} is an unconnected UDP socket on an any/multicast address")
    return problems


def listeners(pids) -> list[tuple[str, int]]:
    inodes = socket_inodes(pids)
    return sorted((s["local"], s["lport"]) for s in proc_net()
                  if s["inode"] in inodes and s["kind"].startswith("tcp") and s["state"] == "0A")


def multicast_groups() -> set[tuple[str, str]]:
    """(interface, group) memberships from /proc/net/igmp and /proc/net/igmp6."""
    groups = set()
    try:
        iface = None
        for line in open("/proc/net/igmp").read().splitlines()[1:]:
            if not line.startswith((" ", "\t")):
                iface = line.split()[1].rstrip(":")
            else:
                grp = line.split()[0]
                ip = socket.inet_ntop(socket.AF_INET, bytes.fromhex(grp)[::-1])
                groups.add((iface, ip))
    except OSError:
        pass
    try:
        for line in open("/proc/net/igmp6").read().splitlines():
            parts = line.split()
            ip = socket.inet_ntop(socket.AF_INET6, bytes.fromhex(parts[2]))
            groups.add((parts[1], ip))
    except OSError:
        pass
    return groups


def cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode("utf-8", "replace")
    except OSError:
        return "?"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def watch(pids_fn, until, period=0.1) -> tuple[list[str], set[tuple[str, int]]]:
    """Sample the processes' sockets until ``until()``; (problems, listeners seen)."""
    problems, seen = [], set()
    while not until():
        pids = pids_fn()
        problems += exposure_problems(pids)
        seen.update(listeners(pids))
        time.sleep(period)
    return sorted(set(problems)), seen


def diffbot(*args, env=None, **kw):
    e = dict(os.environ, PYTHONUNBUFFERED="1")
    e.pop("DIFFBOT_ENDPOINT", None)
    e.update(env or {})
    return subprocess.Popen([sys.executable, "-m", "diffbot.cli", *args], cwd=ROOT, env=e,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kw)


def _finish(p, timeout=120) -> tuple[str, str]:
    try:
        return p.communicate(timeout=timeout)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(5)


# ---------------------------------------------------------------------- the defaults

def test_a_run_on_a_tcp_endpoint_listens_on_loopback_only_and_never_multicasts(tmp_path):
    port = free_port()
    out = tmp_path / "run"
    groups_before = multicast_groups()
    run = diffbot("run", "drive-test", "--endpoint", f"tcp/127.0.0.1:{port}", "--out", str(out))
    pids = lambda: [run.pid, *processes_mentioning(str(out))]  # noqa: E731
    problems, seen = watch(pids, lambda: run.poll() is not None)
    groups_during = multicast_groups()
    _, err = _finish(run)
    assert run.returncode == 0, err
    assert not problems, "\n".join(problems)
    assert seen == {("127.0.0.1", port)}, f"listeners: {seen}"      # the plant, nothing else
    new = groups_during - groups_before
    assert not new, f"multicast memberships appeared during the run: {new}"


def test_plant_on_the_default_endpoint_listens_on_loopback_only(tmp_path):
    from bus.session import DEFAULT_ENDPOINT
    m = re.fullmatch(r"tcp/127\.0\.0\.1:(\d+)", DEFAULT_ENDPOINT)
    assert m, f"the default endpoint is {DEFAULT_ENDPOINT!r}, not loopback TCP"
    port = int(m.group(1))
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            pytest.skip(f"the default port {port} is in use by something else")
    groups_before = multicast_groups()
    plant = diffbot("plant", "--world", "empty", "--mode", "lockstep", "--duration", "4",
                    "--expect", "wheel_schedule_robot1")
    ctrl = diffbot("controller", "wheel_schedule", "--schedule", "100:1,1")
    problems, seen = watch(lambda: [plant.pid, ctrl.pid], lambda: plant.poll() is not None)
    groups_during = multicast_groups()
    _, perr = _finish(plant)
    _, cerr = _finish(ctrl, 30)
    assert plant.returncode == 0, perr
    assert not problems, "\n".join(problems)
    assert seen == {("127.0.0.1", port)}, seen
    assert not groups_during - groups_before


# ---------------------------------------------------------------------- multi-machine

def test_example_configs_parse_and_say_what_they_claim():
    client = zenoh.Config.from_file(os.path.join(CONFIGS, "client.json5"))
    assert json.loads(client.get_json("mode")) == "client"
    assert json.loads(client.get_json("listen/endpoints")) == []
    assert json.loads(client.get_json("scouting/multicast/enabled")) is False
    assert json.loads(client.get_json("scouting/gossip/enabled")) is False
    # the TLS files and their access control: tests/network/test_tls.py


def client_config(tmp_path, endpoint: str, name="client.json5", tls: dict | None = None):
    """The shipped client.json5 pointed at ``endpoint`` (and TLS files, if given)."""
    conf = zenoh.Config.from_file(os.path.join(CONFIGS, "client.json5"))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    if tls:
        conf.insert_json5("transport/link/tls", json.dumps(tls))
    path = tmp_path / name
    path.write_text(str(conf))            # the whole config as JSON
    return str(path)


def start_router(*args):
    router = diffbot("router", *args)
    return router


def test_scenario_runs_through_diffbot_router_with_client_configs(tmp_path):
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    router = start_router("--listen", ep)
    try:
        wait_for(lambda: ("127.0.0.1", port) in listeners([router.pid]) or router.poll(), 30,
                 what="the router to listen")
        assert router.poll() is None, _finish(router)[1]
        conf = client_config(tmp_path, ep)
        out = tmp_path / "run"
        run = diffbot("run", "drive-test", "--zenoh-config", conf, "--out", str(out))
        pids = lambda: [run.pid, *processes_mentioning(str(out))]  # noqa: E731
        problems, seen = watch(pids, lambda: run.poll() is not None)
        _, err = _finish(run)
        assert run.returncode == 0, err
        s = json.load(open(out / "summary.json"))
        assert s["metrics"]["steady_linear_velocity_mps"] == pytest.approx(0.120, rel=0.01)
        assert not problems and not seen, (problems, seen)     # the clients listen nowhere
        assert exposure_problems([router.pid]) == []
        assert listeners([router.pid]) == [("127.0.0.1", port)]
    finally:
        router.send_signal(signal.SIGINT)
        _, rerr = _finish(router, 20)
    assert router.returncode == 0, rerr
    assert "listening on " + ep in rerr
