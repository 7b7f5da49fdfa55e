"""Several machines, emulated: router, plant and controllers in three Linux network
namespaces joined by veth pairs, over mutual TLS through the shipped access control, in
lockstep; the recording must be byte for byte the one of the same run on loopback.
The machines are set up as docs/several-machines.md says: certificates from
``diffbot certs``, the shipped ``diffbot/launch/configs/*_tls.json5`` used as they are, pointed at
with ``DIFFBOT_CERTS`` and ``DIFFBOT_ROUTER``.

Topology (made here, as root, with names unique to this test run; addresses from
198.51.100.0/24, TEST-NET-2, which no host interface uses, only on these veth interfaces
inside these namespaces):

    plant ns  .2 --veth-- .1  router ns  .5 --veth-- .6  ctrl ns      (198.51.100.x/30)

The ctrl namespace routes 198.51.100.0/30 via .5, so every machine dials the router at one
address, 198.51.100.1, as the documentation's commands do.

The delay test adds 1 ms each way on every link: ``tc netem`` on the veth ends where
the kernel has ``sch_netem``, else each veth becomes two, through a fourth namespace
where a userspace wire (``tests/support/netwire.py``) forwards every frame 1 ms late:

    plant ns --veth-- [wire ns: netwire] --veth-- router ns --veth-- [wire ns] --veth-- ctrl ns

The router listens with TLS on both of its addresses (its certificate names both); plant,
recorder and controllers are Zenoh clients, each with its role's certificate. Everything is
deleted at the end, also on failure (deleting a namespace deletes its veth ends and every
address in it). ``Net``, ``tls_machines`` and ``start_router`` are the pieces a test of a
disturbed split run (a router blip) reuses.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import uuid

import pytest

from ..conftest import ROOT, Procs, wait_for

#: xdist_group: with tests/fmus/test_plant_fmu.py, on the worker that runs conftest.square_seed0
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("square_seed0")]

DURATION_S = "4"
SCHEDULE = "2:1,1;2:1,-1"
#: the router's address, as every machine dials it (DIFFBOT_ROUTER)
ROUTER = "198.51.100.1"
CONFIGS = os.path.join(ROOT, "diffbot", "launch", "configs")


def _why_no_netns() -> str | None:
    if os.geteuid() != 0:
        return "network namespaces need root"
    for tool in ("ip", "openssl"):
        if shutil.which(tool) is None:
            return f"no `{tool}` command (install iproute2 / openssl)"
    return None


def sh(*argv: str) -> None:
    subprocess.run(argv, check=True, capture_output=True, timeout=20)


class Net:
    """Three namespaces and two links; ``close`` removes all of it (and stops the wire).

    ``wire=True`` makes each link two veth pairs through a fourth namespace, where
    ``tests/support/netwire.py`` (a userspace delay wire) forwards the frames; ``set_delay_ms``
    then delays them there instead of with ``tc netem`` on the veth ends."""

    def __init__(self, wire: bool = False) -> None:
        self.tag = tag = uuid.uuid4().hex[:6]
        roles = ("router", "plant", "ctrl") + (("wire",) if wire else ())
        self.ns = {role: f"dbt-{role}-{tag}" for role in roles}
        self.made: list[str] = []
        self.wire_ifaces: list[str] = []
        self.wire_proc: subprocess.Popen | None = None
        self.links: list[tuple[str, str]] = []
        try:
            self._build(wire)
        except BaseException:
            self.close()
            raise

    def _build(self, wire: bool) -> None:
        tag = self.tag
        for ns in self.ns.values():
            sh("ip", "netns", "add", ns)
            self.made.append(ns)
            sh("ip", "-n", ns, "link", "set", "lo", "up")
        if wire:     # the wire's own stack stays quiet (no IPv6 autoconfiguration): best effort
            subprocess.run(["ip", "netns", "exec", self.ns["wire"], sys.executable, "-c",
                            "for k in ('all', 'default'): open(f'/proc/sys/net/ipv6/conf/{k}"
                            "/disable_ipv6', 'w').write('1')"], capture_output=True, timeout=20)
        for side, (r_ip, o_ip) in (("plant", (ROUTER, "198.51.100.2")),
                                   ("ctrl", ("198.51.100.5", "198.51.100.6"))):
            a, b = f"dbr{side[0]}{tag}", f"dbo{side[0]}{tag}"      # <= 15 characters
            if wire:
                wa, wb = f"dbwr{side[0]}{tag}", f"dbwo{side[0]}{tag}"
                for end, ns, w in ((a, self.ns["router"], wa), (b, self.ns[side], wb)):
                    sh("ip", "link", "add", end, "netns", ns, "type", "veth",
                       "peer", "name", w, "netns", self.ns["wire"])
                    sh("ip", "-n", self.ns["wire"], "link", "set", w, "up")
                self.wire_ifaces += [wa, wb]
            else:
                sh("ip", "link", "add", a, "netns", self.ns["router"], "type", "veth",
                   "peer", "name", b, "netns", self.ns[side])
            for ns, dev, ip in ((self.ns["router"], a, r_ip), (self.ns[side], b, o_ip)):
                sh("ip", "-n", ns, "addr", "add", f"{ip}/30", "dev", dev)
                sh("ip", "-n", ns, "link", "set", dev, "up")
            self.links += [(self.ns["router"], a), (self.ns[side], b)]
        sh("ip", "-n", self.ns["ctrl"], "route", "add", "198.51.100.0/30", "via", "198.51.100.5")

    @property
    def emulator(self) -> str:
        return "userspace wire (tests/support/netwire.py)" if "wire" in self.ns else "tc netem"

    def netem(self, delay: str) -> None:
        """``tc netem delay`` on every veth end: each hop gets ``delay`` both ways."""
        for ns, dev in self.links:
            sh("ip", "netns", "exec", ns, "tc", "qdisc", "replace", "dev", dev, "root",
               "netem", "delay", delay)

    def set_delay_ms(self, delay_ms: float, log_dir: str) -> None:
        """Each hop gets ``delay_ms`` both ways: netem on the veth ends, or the wire
        restarted with that delay (0 too: the reference goes through the same path)."""
        if "wire" not in self.ns:
            self.netem(f"{delay_ms}ms")
            return
        self.stop_wire()
        with open(os.path.join(log_dir, f"wire-{delay_ms}ms.log"), "wb") as log:
            self.wire_proc = p = subprocess.Popen(
                ["ip", "netns", "exec", self.ns["wire"], sys.executable, "-m",
                 "tests.support.netwire", *self.wire_ifaces, "--delay-ms", str(delay_ms),
                 "--realtime"],
                cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                start_new_session=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        p.log_path = log.name
        wait_for(lambda: "wire up" in self.wire_log() or p.poll() is not None, 20,
                 what="the delay wire")
        assert p.poll() is None, self.wire_log()

    def wire_log(self) -> str:
        with open(self.wire_proc.log_path, "rb") as f:
            return f.read().decode("utf-8", "replace")

    def stop_wire(self) -> str:
        """Stops the wire by PID (``ip netns exec`` execs: it is python's); its counters."""
        p, self.wire_proc = self.wire_proc, None
        if p is None:
            return ""
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)
        with open(p.log_path, "rb") as f:
            return f.read().decode("utf-8", "replace")

    def close(self) -> None:
        self.stop_wire()
        for ns in self.made:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=20)


def netprobe(ns: str, *args: str, timeout_s: float = 30) -> dict:
    """``tests/support/netprobe.py`` run in namespace ``ns``; its JSON line."""
    out = subprocess.run(["ip", "netns", "exec", ns, sys.executable, "-m", "tests.support.netprobe",
                          *args], cwd=ROOT, capture_output=True, timeout=timeout_s)
    assert out.returncode == 0, f"netprobe {' '.join(args)}: {out.stderr.decode()}"
    return json.loads(out.stdout.decode().strip().splitlines()[-1])


def tls_machines(d: str, router: str = ROUTER, port: int | None = None) -> dict:
    """The documented set-up: ``diffbot certs`` for the router's address, then the shipped
    configs; the extra arguments and environment of each kind of process (``port``: a
    DIFFBOT_PORT other than 7447, for a router on loopback)."""
    certs = os.path.join(d, "certs")
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "certs", "--out", certs,
                        "--router", router], cwd=ROOT, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    cfg = lambda role: ["--zenoh-config", os.path.join(CONFIGS, f"{role}_tls.json5")]  # noqa
    env = {"DIFFBOT_CERTS": certs, "DIFFBOT_ROUTER": router}
    if port:
        env["DIFFBOT_PORT"] = str(port)
    return {"router_args": cfg("router"), "plant_args": cfg("plant"), "node_args": cfg("node"),
            "rec_args": cfg("recorder"), "router_env": env, "plant_env": env, "ctrl_env": env}


def start_router(r: Procs, bus: dict, ns: str | None):
    """``diffbot router`` (in namespace ``ns``), waited for until it listens."""
    router = r.diffbot("router", *bus["router_args"], name="router", netns=ns,
                       env=bus["router_env"])
    wait_for(lambda: "listening on" in r.log(router) or router.poll() is not None, 30,
             what="the router")
    assert router.poll() is None, r.log(router)
    return router


def loopback(tmp: str) -> dict:
    sock = ["--endpoint", f"unixsock-stream/{tmp}/bus.sock"]
    return {"plant_args": sock, "node_args": sock, "rec_args": sock}


def run_drive(tmp: str, bus: dict, ns: dict, coupling: str = "sequential") -> tuple[str, dict]:
    """Plant (lockstep, empty world), recorder and a wheel schedule; returns the MCAP path
    and the plant's stats."""
    os.makedirs(tmp, exist_ok=True)
    r = Procs(tmp)
    mcap, stats = os.path.join(tmp, "run.mcap"), os.path.join(tmp, "plant.json")
    try:
        if "router_args" in bus:
            start_router(r, bus, ns.get("router"))
        plant = r.diffbot("plant", "--world", "empty", "--mode", "lockstep", "--coupling",
                          coupling, "--duration", DURATION_S, "--expect", "sched", "--stats",
                          stats, *bus["plant_args"], name="plant", netns=ns.get("plant"),
                          env=bus.get("plant_env"))
        rec = r.diffbot("record", mcap, "--compression", "none", *bus["rec_args"],
                        name="recorder", netns=ns.get("ctrl"), env=bus.get("ctrl_env"))
        wait_for(lambda: "recording" in r.log(rec) or rec.poll() is not None, 30,
                 what="the recorder")
        assert rec.poll() is None, r.log(rec)
        ctrl = r.diffbot("controller", "wheel_schedule", "--robot", "robot1", "--name",
                         "sched", "--schedule", SCHEDULE, *bus["node_args"], name="sched",
                         netns=ns.get("ctrl"), env=bus.get("ctrl_env"))
        assert plant.wait(90) == 0, r.log(plant)
        ctrl.wait(20)
        assert rec.wait(30) == 0, r.log(rec)
    finally:
        r.cleanup()
    with open(stats) as f:
        return mcap, json.load(f)


def messages(mcap: str) -> list[tuple[str, int, bytes]]:
    """(topic, sim time, payload) of every message, in a stable order (wall-clock
    publish times differ between runs and are left out)."""
    from mcap.reader import make_reader
    with open(mcap, "rb") as f:
        out = [(ch.topic, m.log_time, m.data) for _, ch, m in make_reader(f).iter_messages()]
    return sorted(out)


def _make_net(**kw) -> Net:
    why = _why_no_netns()
    if why:
        pytest.skip(why)
    try:
        return Net(**kw)
    except subprocess.CalledProcessError as exc:
        pytest.skip(f"cannot create network namespaces here: {exc.stderr.decode().strip()}")


@pytest.fixture
def net():
    n = _make_net()
    try:
        yield n
    finally:
        n.close()


@pytest.fixture
def delay_net():
    """(net, why the wire): veth pairs with ``tc netem`` where the kernel has it, else
    the same topology through the userspace delay wire."""
    n, why = _make_net(), ""
    try:
        n.netem("0ms")
    except subprocess.CalledProcessError as exc:
        n.close()
        why = f"tc netem: {exc.stderr.decode().strip()}"
        n = _make_net(wire=True)
    try:
        yield n, why
    finally:
        n.close()


def test_lockstep_over_tls_across_namespaces_is_byte_identical_to_loopback(tmp_path, net):
    remote = tls_machines(str(tmp_path))
    a, sa = run_drive(str(tmp_path / "loopback"), loopback(str(tmp_path)), {})
    b, sb = run_drive(str(tmp_path / "netns"), remote, net.ns)
    ma, mb = messages(a), messages(b)
    assert len(ma) > 500 and any(t.endswith("robot1/cmd_vel") or t.endswith("wheel_cmd")
                                 for t, _, _ in ma)
    assert ma == mb
    assert sa["sim_time_s"] == sb["sim_time_s"] == pytest.approx(float(DURATION_S))
    print(f"real-time factor: loopback {sa['real_time_factor']:.2f}, "
          f"3 namespaces + router + TLS {sb['real_time_factor']:.2f}")


def check_delay(net: Net, delay_ms: int) -> str:
    """Every link now takes at least ``delay_ms`` each way, loses nothing, and carries a
    1 MB TCP stream intact (GSO frames and checksum offload included)."""
    report = []
    for side in ("plant", "ctrl"):
        rtt = netprobe(net.ns[side], "ping", ROUTER, "-c", "100", "-i", "0.01")
        assert rtt["received"] == rtt["sent"], rtt
        assert rtt["min_ms"] >= 2 * delay_ms, rtt
        report.append(f"{side}<->router {rtt['min_ms']:.2f}/{rtt['avg_ms']:.2f}/"
                      f"{rtt['max_ms']:.2f}")
    sink = subprocess.Popen(["ip", "netns", "exec", net.ns["router"], sys.executable, "-m",
                             "tests.support.netprobe", "sink", ROUTER, "5001"],  # private netns
                            cwd=ROOT, stdout=subprocess.PIPE, stdin=subprocess.DEVNULL)
    try:
        assert sink.stdout.readline().strip() == b"listening"
        sent = netprobe(net.ns["plant"], "send", ROUTER, "5001", str(1 << 20))
        got = json.loads(sink.communicate(timeout=20)[0])
    finally:
        if sink.poll() is None:
            sink.kill()
            sink.wait(5)
    assert got == {k: sent[k] for k in ("bytes", "sha256")}
    return f"ping RTT min/avg/max ms: {', '.join(report)}; 1 MB TCP in {sent['seconds']:.2f} s"


def test_lockstep_with_1ms_delay_per_link_keeps_the_bytes(tmp_path, delay_net):
    """With 1 ms more each way on every link, lockstep gives the same bytes under both
    couplings; only the pace drops. The real-time factors are printed, with the same
    path undelayed for reference (speed is not asserted)."""
    net, why = delay_net
    print(f"\ndelay by {net.emulator}" + (f" ({why})" if why else ""))
    remote = tls_machines(str(tmp_path))
    rtf, msgs = {}, {}
    for delay_ms in (0, 1):
        net.set_delay_ms(delay_ms, str(tmp_path))
        if delay_ms:
            print(f"{delay_ms} ms per link: {check_delay(net, delay_ms)}")
        for coupling in ("sequential", "pipelined"):
            c, sc = run_drive(str(tmp_path / f"{coupling}-{delay_ms}ms"), remote, net.ns,
                              coupling)
            rtf[coupling, delay_ms] = sc["real_time_factor"]
            msgs[coupling, delay_ms] = messages(c)
            assert len(msgs[coupling, delay_ms]) > 500
        if "wire" in net.ns:
            print(f"wire at {delay_ms} ms:\n" + net.stop_wire().replace("wire up\n", ""))
    for coupling in ("sequential", "pipelined"):
        assert msgs[coupling, 1] == msgs[coupling, 0], coupling
    assert msgs["sequential", 0] != msgs["pipelined", 0]    # the coupling took effect
    print("real-time factor, " + ", ".join(
        f"{c} {rtf[c, 0]:.2f} -> {rtf[c, 1]:.2f}" for c in ("sequential", "pipelined"))
        + f" (undelayed -> 1 ms per link, {net.emulator})")


# ------------------------------------------------------------ the documented split run

DOC = os.path.join(ROOT, "docs", "several-machines.md")
#: the doc's machines -> this test's namespaces ("any": the host, no network needed)
MACHINE_NS = {"any": None, "router": "router", "plant": "plant", "robot": "ctrl"}


def doc_steps() -> list[tuple[str, dict, list[list[str]]]]:
    """The doc's ``# machine: NAME`` shell blocks, in order: (machine, exported variables,
    commands as argv lists; a trailing ``&`` and a ``2> FILE`` dropped: Procs keeps each
    process's log). The shell's own lines are left to the runner: ``until grep -q "INFO
    recording" ...`` is its wait for the recorder (run_doc_steps waits for the same line),
    ``wait`` its wait for the processes in the background (the test waits for each)."""
    import re
    import shlex
    text = open(DOC).read().split("## The square on three machines", 1)[1].split("\n## ", 1)[0]
    steps = []
    for block in re.findall(r"```sh\n(.*?)```", text, re.S):
        lines = block.replace("\\\n", " ").splitlines()
        m = re.match(r"# machine: (\w+)$", lines[0])
        assert m, f"a shell block without '# machine: NAME': {lines[0]}"
        env, cmds = {}, []
        for line in lines[1:]:
            argv = shlex.split(line, comments=True)
            if argv and argv[0] == "export":
                env.update(a.split("=", 1) for a in argv[1:])
            elif argv and argv[0] == "until":
                assert "INFO recording" in line and cmds[-1][1] == "record", line
            elif argv and argv != ["wait"]:
                if "2>" in argv:
                    i = argv.index("2>")
                    argv = argv[:i] + argv[i + 2:]
                cmds.append([a for a in argv if a != "&"])
        steps.append((m.group(1), env, cmds))
    return steps


def run_doc_steps(tmp: str, net: Net, r: Procs) -> dict:
    """Runs the doc's blocks as printed, each machine's in its namespace, with ``~`` the test
    directory and cwd the test directory (paths into the checkout made absolute); returns
    the processes by command name."""
    started = {}
    for machine, env, cmds in doc_steps():
        env = {k: v.replace("~", tmp) for k, v in env.items()}
        for argv in cmds:
            assert argv[0] == "diffbot", argv
            args = [a.replace("~", tmp) for a in argv[1:]]
            args = [os.path.join(ROOT, a) if "/" in a and os.path.exists(os.path.join(ROOT, a))
                    else a for a in args]
            if machine == "any":
                out = subprocess.run([sys.executable, "-m", "diffbot.cli", *args], cwd=tmp,
                                     capture_output=True, text=True, timeout=60)
                assert out.returncode == 0, out.stderr
                continue
            p = r.diffbot(*args, name=args[0], netns=net.ns[MACHINE_NS[machine]], env=env,
                          cwd=tmp)
            started[args[0]] = p
            ready = {"router": "listening on", "record": "INFO recording"}.get(args[0])
            if ready:
                wait_for(lambda: ready in r.log(p) or p.poll() is not None, 30,
                         what=f"`diffbot {args[0]}` on {machine}")
                assert p.poll() is None, r.log(p)
    return started


def test_documented_square_on_three_machines_records_what_one_machine_does(tmp_path, net,
                                                                           square_seed0):
    """docs/several-machines.md's commands, as printed, in three namespaces through the
    shipped mutual-TLS, access-controlled router: the square ends where `diffbot run
    square` ends, and the recorder (certificate "recorder") gets every topic, every
    message, byte for byte the one-machine recording."""
    tmp = str(tmp_path)
    summary = square_seed0["summary"]            # `diffbot run square --seed 0 --record`
    r = Procs(tmp)
    try:
        p = run_doc_steps(tmp, net, r)
        assert p["plant"].wait(300) == 0, r.log(p["plant"])
        for name in ("controller", "fmu-node", "record"):
            assert p[name].wait(30) == 0, r.log(p[name])
        router_log = r.log(p["router"])
    finally:
        r.cleanup()
    stats = json.load(open(os.path.join(tmp, "plant.json")))
    assert stats["sim_time_s"] == pytest.approx(summary["sim_time_s"])
    a, b = messages(square_seed0["mcap"]), messages(os.path.join(tmp, "square.mcap"))
    topics = sorted({t for t, _, _ in a})
    assert sorted({t for t, _, _ in b}) == topics
    assert b == a
    for cert in ("plant", "node", "recorder"):         # the router saw who came
        assert f"certificate '{cert}'" in router_log, router_log
    print(f"split square: t = {stats['sim_time_s']} s, {len(b)} messages on {len(topics)} "
          f"topics through the ACL'd router, identical to one machine; real-time factor "
          f"{stats['real_time_factor']:.2f} (one machine {summary['real_time_factor']:.2f})")
