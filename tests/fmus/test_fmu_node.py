"""`diffbot fmu-node`: any co-simulation FMU on the bus, driven by a TOML mapping file.

The odometry FMU on the node must give the Python reference (controllers.odometry) to
1e-9, fed synthetic samples and over the real bus; configuration errors are one line and
exit code 2; bad samples at run time are counted and the node keeps publishing.
The FMUs are built once per session into a temporary directory (tests/conftest.py).
"""
from __future__ import annotations

import json
import math
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import zipfile
from pathlib import Path

import numpy as np
import pytest

from bus import codec
from bus.keys import Keys
from bus.controller import Observation
from bus.protocol import PROTOCOL_VERSION
from controllers.odometry import integrate
from fmus import fmu as fmu_mod
from fmus import fmu_node

from ..conftest import ROOT, require_built_fmus, wait_for
from ..support import patience

#: xdist_group: with test_fmu_odometry, one worker builds the session's FMUs (conftest.built_fmus)
#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = [pytest.mark.xdist_group("fmus"), pytest.mark.background]
K = Keys()
TOL = 1e-9
R, D = 0.12, 0.36
POSE0 = (0.4, -0.3, 0.8)
#: odometry is in <robot>/odom (REP 105): it starts at the origin whatever the start pose
ODOM0 = (0.0, 0.0, 0.0)
INFO = {"protocol": PROTOCOL_VERSION, "mode": "lockstep", "control_tick_s": 0.02,
        "robots": {"robot1": {"wheel_radius_m": R, "wheel_separation_m": D, "pose": list(POSE0),
                              "topics": {"joint_states": 1}}}}
TICK_NS = 20_000_000
MAPPING = Path(ROOT) / "fmus" / "odometry" / "mapping.toml"


@pytest.fixture(scope="session")
def fmus(built_fmus) -> dict[int, Path]:
    return built_fmus


# ---------------------------------------------------------------- helpers

def pose_of(msg) -> tuple[float, float, float]:
    p = msg.pose.pose
    return p.position.x, p.position.y, codec.quaternion_to_yaw(p.orientation)


def pose_error(msg, ref) -> float:
    """max |x - x_ref|, |y - y_ref|, |yaw - theta_ref| (angle difference wrapped)."""
    x, y, yaw = pose_of(msg)
    dth = math.remainder(yaw - ref[2], 2 * math.pi)
    return max(abs(x - ref[0]), abs(y - ref[1]), abs(dth))


def encoder_run(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Encoder angles (rad) of a wandering drive: straight, arcs, spins, reversing."""
    rng = np.random.default_rng(seed)
    wl = rng.normal(0.05, 0.08, n)
    wr = rng.normal(0.05, 0.08, n)
    wr[n // 3: n // 2] = -wl[n // 3: n // 2]          # spin in place
    wr[n // 2: n // 2 + 50] = wl[n // 2: n // 2 + 50]  # straight
    return np.cumsum(wl), np.cumsum(wr)


def obs(k: int, left, right, t0_ns: int = 1_000_000_000) -> Observation:
    t = t0_ns + k * TICK_NS
    return Observation(t, "robot1", {"joint_states": codec.joint_state(
        t, ["left_wheel_joint", "right_wheel_joint"], position=[left, right])})


def make_node(fmu: Path, mapping: Path | None = None) -> fmu_node.FmuNode:
    node = fmu_node.open_node(fmu, mapping)
    node.configure(INFO, "robot1")
    return node


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def without_cosimulation(src: Path, dst: Path) -> Path:
    """A copy of an FMU whose model description offers Model Exchange only."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                start, end = text.index("<CoSimulation"), text.index("</CoSimulation>")
                data = (text[:start] + text[end + len("</CoSimulation>"):]).encode()
            zout.writestr(item, data)
    return dst


# ---------------------------------------------------------------- unit: same numbers

@pytest.mark.parametrize("version", (2, 3))
def test_node_gives_the_reference_odometry(fmus, version):
    left, right = encoder_run(1500)
    ref = integrate(left, right, R, D, ODOM0)
    node = make_node(fmus[version])
    try:
        worst = 0.0
        for k in range(len(left)):
            out = node.step(obs(k, left[k], right[k]))
            msg = out["odom"]
            assert codec.msg_stamp_ns(msg) == 1_000_000_000 + k * TICK_NS
            assert (msg.header.frame_id, msg.child_frame_id) == ("robot1/odom", "robot1/base_link")
            worst = max(worst, pose_error(msg, ref[k]))
        assert worst < TOL
        # First sample: the start pose, at rest.
        assert node.steps == len(left) - 1
        assert msg.twist.twist.linear.x == pytest.approx(R * (np.diff(left)[-1] + np.diff(right)[-1])
                                                         / 2 / 0.02, abs=1e-9)
    finally:
        node.close()


@pytest.mark.parametrize("version", (2, 3))
def test_float_reads_and_writes_equal_fmpys_own_calls(fmus, version):
    """Fmu.read/write (C arrays built once per set of variables) give what fmpy's getReal /
    getFloat64 give, for sets read in turn; a refused call is an FmuCallError."""
    from fmpy.fmi1 import FMICallException
    f = fmu_mod.Fmu(fmus[version], "calls")
    try:
        ins = [f.bus_variable(n) for n in ("omega_left", "omega_right")]
        outs = [f.bus_variable(n) for n in ("x", "y", "theta", "v", "omega")]
        f.initialize(0.0, [])
        get = f.fmu.getReal if version == 2 else f.fmu.getFloat64
        for k in range(3):
            f.write(ins, [[0.5 + k], [1.5 - 2 * k]])
            f.do_step(0.02)
            assert f.read(outs) == [[x] for x in get([v.vr for v in outs])]
            assert f.read(outs[::-2]) == [[x] for x in get([v.vr for v in outs[::-2]])]
            assert f.read(ins) == [[0.5 + k], [1.5 - 2 * k]]

        def refuse(*args):
            raise FMICallException("fmi2SetReal", 3)
        setattr(f.fmu, "fmi2SetReal" if version == 2 else "fmi3SetFloat64", refuse)
        with pytest.raises(fmu_mod.FmuCallError, match="set \\((Real|Float64)\\) failed with status 3"):
            f.write(ins, [[0.0], [0.0]])
    finally:
        f.close()


def test_first_sample_publishes_the_start_pose_and_speed_zero(fmus):
    node = make_node(fmus[2])
    try:
        msg = node.step(obs(0, 123.0, -45.0))["odom"]
        assert pose_error(msg, ODOM0) < 1e-15
        assert msg.twist.twist.linear.x == 0.0 and msg.twist.twist.angular.z == 0.0
    finally:
        node.close()


def test_bad_samples_are_skipped_and_the_next_good_one_covers_the_gap(fmus):
    left, right = encoder_run(200, seed=3)
    bad = {50: (math.nan, 1.0), 51: (1.0, math.inf), 120: (1e308, -1e308)}
    node = make_node(fmus[3])
    try:
        good = [k for k in range(len(left)) if k not in bad]
        ref = dict(zip(good, integrate(left[good], right[good], R, D, ODOM0)))
        last = None
        for k in range(len(left)):
            l, r = bad.get(k, (left[k], right[k]))
            msg = node.step(obs(k, l, r))["odom"]
            if k in bad:                # published again, with the new stamp, unchanged
                assert pose_of(msg) == pose_of(last)
                assert codec.msg_stamp_ns(msg) == 1_000_000_000 + k * TICK_NS
            else:
                assert pose_error(msg, ref[k]) < TOL
            last = msg
        assert node.rejects.counts["input"] == 3     # the huge one overflows the rate
        assert node.held == 3
    finally:
        node.close()


@pytest.mark.parametrize("snapshot", (True, False))
def test_failed_do_step_is_counted_and_rolled_back(fmus, snapshot):
    from fmpy.fmi1 import FMICallException
    left, right = encoder_run(100, seed=4)
    node = make_node(fmus[2])
    real = node.fmu.fmu.doStep
    calls = {"n": 0}

    def flaky(t, h, *a):
        calls["n"] += 1
        if calls["n"] == 30:
            raise FMICallException("fmi2DoStep", 3)
        return real(t, h, *a)
    node.fmu.fmu.doStep = flaky
    if not snapshot:
        node.fmu.can_snapshot = False
        node.fmu._free_snapshot()
    try:
        outs = [node.step(obs(k, left[k], right[k]))["odom"] for k in range(len(left))]
        assert node.rejects.counts["step"] == 1
        assert len(outs) == len(left)
        if snapshot:   # state kept: equals the reference that skips sample 30
            good = [k for k in range(len(left)) if k != 30]
            ref = integrate(left[good], right[good], R, D, ODOM0)
            assert node.rollbacks == 1
            assert max(pose_error(m, r) for m, r in zip([outs[k] for k in good], ref)) < TOL
        else:          # state lost: initialised again from the start pose, then goes on
            assert node.reinitialised == 1
            assert pose_of(outs[30]) == pose_of(outs[29])
            ref = integrate(left[[29, 31]], right[[29, 31]], R, D, ODOM0)
            assert pose_error(outs[31], ref[1]) < TOL
    finally:
        node.close()


def test_time_going_back_initialises_again(fmus):
    node = make_node(fmus[2])
    try:
        for k in range(20):
            node.step(obs(k, 0.1 * k, 0.2 * k))
        msg = node.step(obs(0, 5.0, 5.0, t0_ns=0))["odom"]
        assert pose_error(msg, ODOM0) < 1e-15
        msg = node.step(obs(1, 5.1, 5.1, t0_ns=0))["odom"]
        assert pose_of(msg)[0] != ODOM0[0]
    finally:
        node.close()


def test_parameters_come_from_sim_info(fmus):
    node = make_node(fmus[2])
    try:
        params = [node.fmu.bus_variable(n) for n in
                  ("wheel_radius", "wheel_separation", "x0", "y0", "theta0")]
        node.step(obs(0, 0.0, 0.0))
        assert node.fmu.read(params) == [[R], [D], *([p] for p in ODOM0)]
        with pytest.raises(fmu_node.FmuNodeError, match=r"mapping.toml:parameters.wheel_radius: "
                                                        r"sim/info has no robots.robot1.wheel_radius_m"):
            node.configure({"robots": {"robot1": {"wheel_separation_m": D, "pose": []}}},
                           "robot1")
        with pytest.raises(fmu_node.FmuNodeError, match=r"parameters.wheel_radius: -1 is "
                                                        r"outside the bounds of 'wheel_radius' "
                                                        r"\[0, inf\] declared by the FMU"):
            node.fmu.reset()
            node.configure({"robots": {"robot1": {"wheel_radius_m": -1.0, "wheel_separation_m": D,
                                                  "pose": [0, 0, 0]}}}, "robot1")
        with pytest.raises(fmu_node.FmuNodeError, match="refused the parameters"):
            node.fmu.reset()
            node.configure({"robots": {"robot1": {"wheel_radius_m": R, "wheel_separation_m": 0.0,
                                                  "pose": [0, 0, 0]}}}, "robot1")
    finally:
        node.close()


# ---------------------------------------------------------------- configuration errors

GOOD_INPUT = """
[[input]]
variable = "omega_left"
topic = "joint_states"
field = "position[0]"
transform = "rate"
"""
GOOD_OUTPUT = """
[output]
topic = "odom"
message = "odometry"
x = "x"
y = "y"
yaw = "theta"
"""


def bad_mappings(tmp: Path) -> dict[str, tuple[Path, str]]:
    """name -> (mapping file, regex of the one-line error)."""
    def m(name, text):
        return write(tmp / f"{name}.toml", text)
    return {
        "unknown key": (m("unknown_key", GOOD_INPUT.replace("transform", "transfrom") + GOOD_OUTPUT),
                        r"unknown_key.toml:input\[0\].transfrom: unknown key"),
        "missing variable": (m("missing_var", GOOD_INPUT.replace('"omega_left"', '"omega_lft"')
                               + GOOD_OUTPUT),
                             r"missing_var.toml:input\[0\].variable: the FMU odometry_fmi2.fmu "
                             r"has no variable 'omega_lft'"),
        "output not an output": (m("not_output", GOOD_INPUT + GOOD_OUTPUT.replace('x = "x"',
                                                                                  'x = "nothing"')),
                                 r"not_output.toml:output.x: the FMU odometry_fmi2.fmu has no "
                                 r"variable 'nothing'"),
        "input is an output": (m("in_out", GOOD_INPUT.replace('"omega_left"', '"x"') + GOOD_OUTPUT),
                               r"in_out.toml:input\[0\].variable: variable 'x' of "
                               r"odometry_fmi2.fmu has causality 'output'"),
        "bad field": (m("bad_field", GOOD_INPUT.replace("position[0]", "positon[0]") + GOOD_OUTPUT),
                      r"bad_field.toml:input\[0\].field: sensor_msgs/msg/JointState has no "
                      r"field 'positon'"),
        "bad transform": (m("bad_tf", GOOD_INPUT.replace('"rate"', '"derivative"') + GOOD_OUTPUT),
                          r"bad_tf.toml:input\[0\].transform: must be one of value, rate"),
        "unknown parameter": (m("bad_param", GOOD_INPUT + GOOD_OUTPUT
                                + '[parameters]\nwheel_radus = 0.1\n'),
                              r"bad_param.toml:parameters.wheel_radus: the FMU odometry_fmi2.fmu "
                              r"has no variable 'wheel_radus' \(did you mean|has no variable"),
        "wrong message for topic": (m("wrong_msg", GOOD_INPUT + GOOD_OUTPUT.replace(
            '"odometry"', '"twist"')), r"wrong_msg.toml:output.message: twist builds "),
        "not toml": (m("not_toml", "[[input]\nvariable ="), r"not_toml.toml: not valid TOML"),
    }


def extraction_folders() -> set[Path]:
    """This process's FMU extraction folders (fmus/fmu.py: TMP_ROOT/<pid>-*)."""
    return set(fmu_mod.TMP_ROOT.glob(f"{os.getpid()}-*"))


def test_mapping_errors_name_file_key_and_variable(fmus, tmp_path):
    before = extraction_folders()
    for name, (path, pattern) in bad_mappings(tmp_path).items():
        with pytest.raises(fmu_node.FmuNodeError) as err:
            fmu_node.open_node(fmus[2], path)
        msg = str(err.value)
        assert "\n" not in msg, name
        assert re.search(pattern, msg), f"{name}: {msg}"
    # a refused FMU leaves no folder behind (a master trying mappings one by one)
    assert extraction_folders() <= before


def test_shipped_mapping_is_found_from_the_model_identifier(fmus):
    before = extraction_folders()
    node = fmu_node.open_node(fmus[3])
    try:
        assert Path(node.mapping.path) == MAPPING
        assert node.inputs == ["joint_states"] and node.name == "odometry"
        assert len(extraction_folders() - before) == 1
    finally:
        node.close()
    assert extraction_folders() <= before, "closing the node removes its FMU's folder"


def test_fmu_paths_resolve_from_any_directory(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    require_built_fmus()
    built = Path(ROOT) / "fmus" / "build" / "odometry_fmi2.fmu"
    assert fmu_node.resolve_fmu("fmus/build/odometry_fmi2.fmu") == built.resolve()
    assert fmu_node.resolve_fmu("odometry") == built.resolve()
    monkeypatch.setattr(fmu_node, "BUILD_DIR", tmp_path / "nobuild")
    with pytest.raises(fmu_node.FmuNodeError, match="diffbot fmu build.*make setup"):
        fmu_node.resolve_fmu("odometry")
    with pytest.raises(fmu_node.FmuNodeError, match="no such FMU file"):
        fmu_node.resolve_fmu(str(tmp_path / "elsewhere.fmu"))


@pytest.mark.slow
def test_cli_errors_are_one_line_exit_2_no_traceback(fmus, tmp_path):
    not_fmu = write(tmp_path / "notes.fmu", "not a zip")
    no_cs = without_cosimulation(fmus[2], tmp_path / "me_only.fmu")
    maps = bad_mappings(tmp_path)
    cases = {
        "wrong file": ([str(not_fmu)], r"notes.fmu: not an FMU"),
        "no such file": ([str(tmp_path / "absent.fmu")], r"absent.fmu: no such FMU file"),
        "no co-simulation": ([str(no_cs)], r"me_only.fmu: the FMU has no co-simulation interface"),
        "unknown key": ([str(fmus[2]), "--mapping", str(maps["unknown key"][0])],
                        maps["unknown key"][1]),
        "missing variable": ([str(fmus[3]), "--mapping", str(maps["missing variable"][0])],
                             maps["missing variable"][1].replace("fmi2", "fmi3")),
    }
    running = {name: subprocess.Popen([sys.executable, "-m", "diffbot.cli", "fmu-node", *argv,
                                       "--endpoint", f"unixsock-stream/{tmp_path}/none.sock"],
                                      cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                      text=True)
               for name, (argv, _) in cases.items()}
    for name, p in running.items():
        out, err = p.communicate(timeout=60)
        lines = err.strip().splitlines()
        assert p.returncode == 2, f"{name}: exit {p.returncode}\n{err}"
        assert len(lines) == 1 and "Traceback" not in err, f"{name}:\n{err}"
        assert re.search(cases[name][1], lines[0]), f"{name}: {lines[0]}"
        assert " ERROR " in lines[0]


# ---------------------------------------------------------------- over the bus

class Tap:
    """Records decoded messages of some robot1 topics, keyed by stamp."""

    def __init__(self, session, topics):
        self.lock = threading.Lock()
        self.msgs: dict[str, dict[int, object]] = {t: {} for t in topics}
        self.subs = [session.declare_subscriber(K.topic("robot1", t), self._cb(t)) for t in topics]

    def _cb(self, topic):
        from bus.keys import TOPICS

        def on(sample):
            m = codec.decode(sample.payload.to_bytes(), TOPICS[topic].msgtype)
            with self.lock:
                self.msgs[topic][codec.msg_stamp_ns(m)] = m
        return on

    def last(self, topic) -> int:
        with self.lock:
            return max(self.msgs[topic], default=-1)

    def copy(self, topic) -> dict[int, object]:
        with self.lock:
            return dict(self.msgs[topic])


@pytest.mark.slow
def test_fmu_node_on_the_bus_equals_the_reference_every_tick(procs, endpoint, bus, fmus, tmp_path):
    stats = tmp_path / "odo.json"
    plant = procs.diffbot("plant", "--world", "living_room", "--mode", "lockstep",
                          "--expect", "odometry_robot1,square_path_robot1",
                          "--endpoint", endpoint, name="plant")
    s = bus()
    tap = Tap(s, ["joint_states", "odom"])
    info = wait_for(lambda: _info(s), 30, what="sim/info")
    odo = procs.diffbot("fmu-node", str(fmus[2]), "--robot", "robot1", "--endpoint", endpoint,
                        "--stats", str(stats), name="fmu")
    square = procs.diffbot("controller", "square_path", "--robot", "robot1", "--side", "1.5",
                           "--endpoint", endpoint, name="square")
    # 20 s of simulated time: the first leg, the first turn and part of the second leg (45 s
    # on the clock of the three processes: not counting their waits for a CPU).
    patience.wait_until(lambda: tap.last("odom") >= 20_000_000_000, 45, plant.pid, odo.pid,
                        square.pid, step=0.2, what="odom up to t=20 s")
    odo.send_signal(signal.SIGINT)
    assert odo.wait(10) == 0, procs.log(odo)
    js, od = tap.copy("joint_states"), tap.copy("odom")
    stamps = sorted(od)
    assert stamps[0] == min(js), "the node's first odom is the plant's first tick"
    assert stamps == sorted(t for t in js if t <= stamps[-1]), "one odom per tick, none missing"
    enc = np.array([js[t].position[:2] for t in stamps])
    # odometry in robot1/odom: from the origin, whatever the start pose (REP 105)
    pose0 = ODOM0
    ref = integrate(enc[:, 0], enc[:, 1], info["robots"]["robot1"]["wheel_radius_m"],
                    info["robots"]["robot1"]["wheel_separation_m"], pose0)
    errors = np.array([pose_error(od[t], ref[i]) for i, t in enumerate(stamps)])
    print(f"fmu-node vs reference over {len(stamps)} ticks: max |error| {errors.max():.3g}")
    assert errors.max() < TOL
    assert abs(ref[-1, 2] - pose0[2]) > 1.0, "the run includes the first 90 degree turn"
    st = json.loads(stats.read_text())
    assert st["fmu"]["steps"] == len(stamps) - 1 and st["rejected"] == {}
    # the node was an --expect member stopped mid-run: the plant, with no rejoin timeout,
    # ends the run at once and exits 1 (docs/PROTOCOL.md section 4, "Lost members")
    assert procs.wait(plant, 30, "the plant's end") == 1
    assert "lost lockstep member odometry_robot1" in procs.log(plant)


def _info(session):
    for reply in session.get(K.info, timeout=1.0):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
    return None


@pytest.mark.slow
def test_bad_joint_states_on_the_bus_are_counted_and_the_node_keeps_publishing(
        procs, endpoint, fmus, tmp_path):
    """The test is the plant here: it serves sim/info, publishes joint_states and the clock
    tick by tick and waits for the node's lockstep ACK (on its odom, docs/PROTOCOL.md), so
    each bad sample lands on its tick."""
    from bus.session import open_session
    stats = tmp_path / "odo.json"
    s = open_session("plant", endpoint)
    acks: queue.Queue = queue.Queue()
    odom: dict[int, object] = {}

    def on_odom(smp):
        m = codec.decode(smp.payload.to_bytes(), "nav_msgs/msg/Odometry")
        odom.setdefault(codec.msg_stamp_ns(m), m)
        att = codec.parse_attachment(smp.attachment.to_bytes())
        if att.flags & codec.ACK and att.node == "odometry_robot1" and att.n_plant == 1:
            acks.put(att.t_ns)
    keep = [
        s.declare_queryable(K.info, lambda q: q.reply(K.info, json.dumps(INFO))),
        s.declare_subscriber(K.topic("robot1", "odom"), on_odom),
        s.liveliness().declare_token(K.alive("plant")),
    ]
    try:
        node = procs.diffbot("fmu-node", str(fmus[2]), "--robot", "robot1", "--endpoint",
                             endpoint, "--stats", str(stats), name="fmu")
        wait_for(lambda: list(s.liveliness().get(K.sync("odometry_robot1"), timeout=0.5)),
                 30, what="the node's lockstep token")
        left, right = encoder_run(80, seed=7)
        bad = {10: [math.nan, 0.0], 11: [0.0, math.nan], 20: [math.inf, 1.0], 40: [1.0]}
        garbage = {30: b"\x00\x01garbage", 31: b""}
        js_key = K.topic("robot1", "joint_states")
        for k in range(len(left)):
            t = k * TICK_NS
            if k in garbage:          # undecodable: rejected, the node waits for a good one
                s.put(js_key, garbage[k])
            pos = bad.get(k, [left[k], right[k]])
            s.put(js_key, codec.encode(codec.joint_state(t, ["l", "r"], position=pos)))
            s.put(K.clock, codec.encode(codec.clock(t)))
            assert acks.get(timeout=10) == t
        wait_for(lambda: len(odom) == len(left), 5, what="the last odom")
        assert node.poll() is None, "the node is alive"
        node.send_signal(signal.SIGINT)
        assert node.wait(10) == 0
    finally:
        for k in keep:
            k.undeclare()
        s.close()
    assert sorted(odom) == [k * TICK_NS for k in range(len(left))], "odom on every tick"
    good = [k for k in range(len(left)) if k not in bad]
    ref = dict(zip(good, integrate(left[good], right[good], R, D, ODOM0)))
    assert max(pose_error(odom[k * TICK_NS], ref[k]) for k in good) < TOL
    st = json.loads(stats.read_text())
    assert st["rejected"]["input"] == len(bad)
    assert st["rejected"]["joint_states"] == len(garbage)
    assert st["fmu"]["held"] == len(bad)
    log = procs.log(node)
    assert "rejected input" in log and "Traceback" not in log
    assert log.count("rejected input") < len(bad)        # rate limited


# ---------------------------------------------------------------- example and benchmarks

def test_fmpy_example_replays_a_recorded_trajectory(fmus, tmp_path, capsys):
    sys.path.insert(0, str(Path(ROOT) / "fmus" / "examples"))
    try:
        import fmpy_trajectory
    finally:
        sys.path.pop(0)
    left, right = encoder_run(400, seed=5)
    t = np.arange(len(left)) * 0.02
    pose = integrate(left, right, R, D, POSE0)
    gps = pose[:, :2] + np.random.default_rng(0).normal(0, 0.002, (len(t), 2))
    gps[-1] = pose[-1, :2] + (0.003, 0.004)
    csv = tmp_path / "trajectory.csv"
    rows = np.column_stack([t, pose, gps, left, right])
    np.savetxt(csv, rows, delimiter=",", fmt="%.9f", comments="",
               header="t_s,odom_x_m,odom_y_m,odom_theta_rad,gps_x_m,gps_y_m,"
                      "enc_left_rad,enc_right_rad")
    assert fmpy_trajectory.main([str(tmp_path), "--fmu", str(fmus[3])]) == 0
    out = capsys.readouterr().out
    assert "final error FMU - GPS: 0.0050 m" in out
    vs_odom = float(re.search(r"max \|FMU - recorded odometry\|: (\S+) m", out).group(1))
    assert vs_odom < 1e-8
    assert (tmp_path / "fmu_vs_gps.png").stat().st_size > 10_000


@pytest.mark.slow
def test_bench_functions_return_seconds():
    from fmus import bench
    items = bench.benchmarks()
    assert len(items) >= 4
    for name, desc, fn in items:
        s1, s2 = fn(10), fn(1000)
        assert 0 < s1 and 0 < s2 < 5, name
