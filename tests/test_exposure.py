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
import shutil
import signal
import socket
import subprocess
import sys
import time

import pytest
import zenoh

from .conftest import ROOT, wait_for
from .test_scenarios import processes_mentioning

pytestmark = pytest.mark.slow
CONFIGS = os.path.join(ROOT, "diffbot", "configs")
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
    router = zenoh.Config.from_file(os.path.join(CONFIGS, "router_tls.json5"))
    assert json.loads(router.get_json("mode")) == "router"
    listen = json.loads(router.get_json("listen/endpoints"))
    assert listen and all(e.startswith("tls/") and "0.0.0.0" not in e for e in listen)
    assert json.loads(router.get_json("scouting/multicast/enabled")) is False
    acl = json.loads(router.get_json("access_control"))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    assert json.loads(router.get_json("transport/link/tls/enable_mtls")) is True
    # the access-control section is accepted by a real router (TLS replaced by loopback TCP)
    router.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{free_port()}"]))
    router.insert_json5("transport/link/tls", "{}")
    zenoh.open(router).close()


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


# ---------------------------------------------------------------------- TLS + access control

def _openssl(*args, cwd):
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


def make_pki(d) -> dict[str, tuple[str, str]]:
    """A CA and certificates (CN = name) for the router and three clients: name -> (cert, key)."""
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca-key.pem", "-out",
             "ca.pem", "-days", "2", "-subj", "/CN=diffbot-test-ca", cwd=d)
    out = {}
    for name, san in (("router", "DNS:localhost,IP:127.0.0.1"), ("diffbot-plant", None),
                      ("diffbot-controller", None), ("diffbot-observer", None)):
        _openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}-key.pem", "-out",
                 f"{name}.csr", "-subj", f"/CN={name}", cwd=d)
        ext = os.path.join(d, f"{name}.ext")
        with open(ext, "w") as f:
            f.write(f"subjectAltName={san or 'DNS:' + name}\n"
                    "basicConstraints=CA:FALSE\n")
        _openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
                 "-CAcreateserial", "-out", f"{name}.pem", "-days", "2", "-extfile", ext, cwd=d)
        out[name] = (os.path.join(d, f"{name}.pem"), os.path.join(d, f"{name}-key.pem"))
    return out


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs openssl to make certificates")
def test_tls_router_with_access_control_example(tmp_path):
    """router_tls.json5 as shipped, with test certificates and a loopback address: the plant
    and a controller run a lockstep drive over mutual TLS; an observer's certificate may
    listen but its commands never reach the plant."""
    pki = make_pki(str(tmp_path))
    ca = str(tmp_path / "ca.pem")
    port = free_port()
    ep = f"tls/localhost:{port}"
    rconf = zenoh.Config.from_file(os.path.join(CONFIGS, "router_tls.json5"))
    rconf.insert_json5("listen/endpoints", json.dumps([f"tls/127.0.0.1:{port}"]))
    cert, key = pki["router"]
    rconf.insert_json5("transport/link/tls", json.dumps({
        "root_ca_certificate": ca, "listen_certificate": cert, "listen_private_key": key,
        "enable_mtls": True}))
    rpath = tmp_path / "router.json5"
    rpath.write_text(str(rconf))

    def tls_client(name):
        cert, key = pki[name]
        return client_config(tmp_path, ep, f"{name}.json5", {
            "root_ca_certificate": ca, "connect_certificate": cert, "connect_private_key": key,
            "enable_mtls": True})

    router = start_router("--zenoh-config", str(rpath))
    plant = ctrl = None
    try:
        wait_for(lambda: ("127.0.0.1", port) in listeners([router.pid]) or router.poll(), 30,
                 what="the TLS router to listen")
        assert router.poll() is None, _finish(router)[1]
        stats = tmp_path / "plant.json"
        plant = diffbot("plant", "--world", "empty", "--duration", "3", "--expect",
                        "wheel_schedule_robot1", "--stats", str(stats),
                        "--zenoh-config", tls_client("diffbot-plant"))
        ctrl = diffbot("controller", "wheel_schedule", "--schedule", "100:2,2",
                       "--zenoh-config", tls_client("diffbot-controller"))
        # an observer: may listen, may not command
        from bus.keys import Keys
        K = Keys()
        obs = zenoh.open(zenoh.Config.from_file(tls_client("diffbot-observer")))
        try:
            clocks = []
            sub = obs.declare_subscriber(K.clock, lambda s: clocks.append(1))
            wait_for(lambda: clocks, 60, what="the observer to hear the clock over TLS")
            for _ in range(50):
                obs.put(K.topic("robot1", "cmd_vel"), b"not a command")
                time.sleep(0.01)
            sub.undeclare()
        finally:
            obs.close()
        _, perr = _finish(plant, 90)
        assert plant.returncode == 0, perr
        st = json.load(open(stats))
        assert st["sim_time_s"] == pytest.approx(3.0)
        assert st["members_seen"] == ["wheel_schedule_robot1"]
        # the observer's puts were denied by the router: the plant never saw them
        assert st["rejected"].get("robot1/cmd_vel", 0) == 0, st["rejected"]
        assert exposure_problems([router.pid, plant.pid]) == []
    finally:
        for p in (ctrl, plant, router):
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGINT)
                _finish(p, 20)
