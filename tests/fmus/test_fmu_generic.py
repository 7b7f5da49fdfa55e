"""`diffbot fmu-node MODEL.fmu` with no mapping: every output on fmu/<instance>/<variable>.

The test models (fmus/models: stairs, an FMI 2 Integer counter; bouncing, an FMI 3 ball
with Float64 h, v; gain, FMI 3 y = k u) are built once per session. On the bus and off it
the values must be fmpy's simulate_fmu of the same FMU to the bit; two FMU nodes chained
through fmu/ keys in a scenario file run in lockstep; configuration errors are one line
and exit 2.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import threading
import zipfile
from pathlib import Path

import pytest

from bus import codec
from bus.keys import BadName, Keys, check_fmu_topic, escape_variable, unescape_variable
from bus.controller import Observation
from bus.protocol import PROTOCOL_VERSION
from fmus import build as fmu_build
from fmus import fmu as fmu_mod
from fmus import fmu_node

from ..conftest import ROOT, wait_for

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background

K = Keys()
TICK_NS = 20_000_000
INFO = {"protocol": PROTOCOL_VERSION, "mode": "lockstep", "control_tick_s": 0.02,
        "robots": {"robot1": {"topics": {}}}}


@pytest.fixture(scope="session")
def models(tmp_path_factory) -> dict[str, Path]:
    return fmu_build.build_test_fmus(tmp_path_factory.mktemp("models"))


def fmpy_values(path: Path, var: str, stop: float, dt: float, **start) -> dict[int, object]:
    """fmpy's simulate_fmu at its communication points: {j: value at t = j dt}."""
    import fmpy
    r = fmpy.simulate_fmu(str(path), stop_time=stop, step_size=dt, output_interval=dt,
                          start_values=start, output=[var])
    return {j: r[var][j] for j in range(len(r))}


def at_tick(ref: dict[int, object], t_ns: int, dt: float):
    """The value the node publishes at tick t: fmpy's at the last FMU step at or before t."""
    return ref[int(math.floor(t_ns * 1e-9 / dt + 1e-9))]


# ---------------------------------------------------------------- keys

@pytest.mark.parametrize("name, segment", [
    ("h", "h"), ("der(x)", "der%28x%29"), ("a.b[1]", "a.b%5B1%5D"), ("info", "%69nfo"),
    ("x y/z*", "x%20y%2Fz%2A"), ("ü", "%C3%BC"), ("wheel_radius", "wheel_radius")])
def test_variable_names_are_escaped_by_the_documented_rule(name, segment):
    assert escape_variable(name) == segment
    assert unescape_variable(segment) == name
    assert K.fmu("ball", name) == f"fmu/ball/{segment}"
    assert check_fmu_topic(f"fmu/ball/{segment}")


def test_keys_that_are_not_escaped_variables_are_refused():
    for bad in ("fmu/ball/der(x)", "fmu/ball/info", "fmu/*/h", "fmu/ball", "fmu/ball/h/x"):
        with pytest.raises(BadName):
            check_fmu_topic(bad)
    assert Keys("ns").fmu_info("ball") == "ns/fmu/ball/info"


# ---------------------------------------------------------------- off the bus: fmpy's bits

def run_offline(path: Path, stop: float, **kw) -> tuple[fmu_node.FmuNode, dict[int, dict]]:
    node = fmu_node.open_node(path, **kw)
    node.configure(INFO, "robot1")
    outs = {}
    for k in range(int(round(stop / 0.02)) + 1):
        outs[k * TICK_NS] = node.step(Observation(k * TICK_NS, "robot1", {}))
    return node, outs


@pytest.mark.parametrize("model, var, stop", [("stairs_fmi2", "counter", 4.0),
                                              ("bouncing_fmi3", "h", 2.0),
                                              ("bouncing_fmi3", "v", 2.0)])
def test_outputs_equal_fmpy_to_the_bit(models, model, var, stop):
    node, outs = run_offline(models[model], stop)
    try:
        dt = node.step_size
        assert dt == {"stairs_fmi2": 0.2, "bouncing_fmi3": 0.01}[model]
        ref = fmpy_values(models[model], var, stop, dt)
        key = f"fmu/{node.fmu.model_identifier}/{var}"
        got = {t: o[key].data for t, o in outs.items()}
        assert all(got[t] == at_tick(ref, t, dt) for t in got), "not bit-identical to fmpy"
        kind = {"counter": "std_msgs/msg/Int32", "h": "std_msgs/msg/Float64",
                "v": "std_msgs/msg/Float64"}[var]
        assert outs[0][key].__msgtype__ == kind
        # several doSteps per tick (0.01 s in a 20 ms tick), or one every 10 ticks (0.2 s)
        assert node.fmu_steps == round(stop / dt)
    finally:
        node.close()


def test_parameters_and_step_size_from_the_command_line(models):
    node, outs = run_offline(models["bouncing_fmi3"], 1.0, start_values={"e": "0.5"},
                             step="tick")
    try:
        assert node.step_size is None and node.fmu_steps == 50
        # one doStep of h = t_k - t_(k-1) per tick: fmpy's steps of 0.02 s up to rounding
        ref = fmpy_values(models["bouncing_fmi3"], "h", 1.0, 0.02, e=0.5)
        assert max(abs(o["fmu/bouncing/h"].data - ref[t // TICK_NS])
                   for t, o in outs.items()) < 1e-12
        other = fmpy_values(models["bouncing_fmi3"], "h", 1.0, 0.02)     # e = 0.7
        assert abs(outs[10 ** 9]["fmu/bouncing/h"].data - other[50]) > 0.01
    finally:
        node.close()


def test_info_lists_variables_types_units_keys_and_time_base(models):
    node, _ = run_offline(models["bouncing_fmi3"], 0.1)
    try:
        info = json.loads(json.dumps(node.info()))
        assert info["instance"] == "bouncing" and info["fmi_version"] == "3.0"
        assert info["step_size_s"] == 0.01 and info["start"] == "bus time"
        by = {v["name"]: v for v in info["variables"]}
        assert by["h"] == {**by["h"], "key": "fmu/bouncing/h", "type": "std_msgs/msg/Float64",
                           "unit": "m", "direction": "output", "fmi_type": "Float64"}
    finally:
        node.close()


def test_chained_input_is_read_from_another_node_s_key(models):
    node = fmu_node.open_node(models["gain_fmi3"], connect={"u": "fmu/bouncing/h"},
                              start_values={"k": "2"})
    try:
        node.configure(INFO, "robot1")
        assert node.inputs == ["fmu/bouncing/h"]
        assert node.topics["fmu/bouncing/h"].awaited
        for k, h in enumerate((1.0, 0.75, 0.5)):
            msg = codec.T["std_msgs/msg/Float64"](data=h)
            out = node.step(Observation(k * TICK_NS, "robot1", {"fmu/bouncing/h": msg}))
            assert out["fmu/gain/y"].data == 2 * h
    finally:
        node.close()


def test_unconnected_inputs_read_their_own_key_and_hold(models):
    node = fmu_node.open_node(models["gain_fmi3"])
    try:
        node.configure(INFO, "robot1")
        assert node.inputs == ["fmu/gain/u"] and not node.topics["fmu/gain/u"].awaited
        u = codec.T["std_msgs/msg/Float64"](data=3.0)
        assert node.step(Observation(0, "robot1", {}))["fmu/gain/y"].data == 0.0
        assert node.step(Observation(TICK_NS, "robot1", {"fmu/gain/u": u}))["fmu/gain/y"].data == 3.0
        assert node.step(Observation(2 * TICK_NS, "robot1", {}))["fmu/gain/y"].data == 3.0
    finally:
        node.close()


# ---------------------------------------------------------------- errors

def one_line_error(*args: str) -> str:
    p = subprocess.run([sys.executable, "-m", "diffbot.cli", "fmu-node", *args], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    return lines[0]


@pytest.mark.slow
def test_parameter_outside_its_bounds_exits_2_naming_variable_and_bounds(models):
    line = one_line_error(str(models["bouncing_fmi3"]), "--param", "e=2.0")
    assert "--param e=2.0: 2 is outside the bounds of 'e' [0, 1] declared by the FMU" in line


@pytest.mark.slow
def test_missing_binary_names_the_platforms_shipped_and_how_to_compile(models, tmp_path):
    src = models["stairs_fmi2"]
    other = tmp_path / "stairs_other.fmu"
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(other, "w") as zout:
        for item in zin.infolist():
            name = item.filename
            if name.startswith("binaries/"):
                name = "binaries/win64/stairs.dll"
            zout.writestr(name, zin.read(item))
    line = one_line_error(str(other))
    assert "no binary for this platform (linux64); it ships win64" in line
    assert f"`fmpy compile {other}`" in line


def test_zenoh_errors_carry_no_rust_source_paths():
    from bus.session import zenoh_error
    exc = RuntimeError("Unable to connect to any of [Single(unixsock-stream//tmp/b.sock)]. "
                       "Timeout! at /root/.cargo/git/checkouts/zenoh-9c599d5ef3e0480e/cc83980/"
                       "zenoh/src/net/runtime/orchestrator.rs:388.")
    assert zenoh_error(exc) == "nothing answered there (timed out)"


@pytest.mark.slow
def test_extraction_folders_of_killed_nodes_are_swept(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    root = tmp_path / "x"
    (root / f"{dead.pid}-abc").mkdir(parents=True)
    (root / f"{os.getpid()}-mine").mkdir()
    assert fmu_mod.sweep_tmp(root) == [root / f"{dead.pid}-abc"]
    assert sorted(p.name for p in root.iterdir()) == [f"{os.getpid()}-mine"]


# ---------------------------------------------------------------- on the bus

class Tap:
    """fmu/ values by stamp (from the attachment), decoded as ``types[key]``."""

    def __init__(self, session, types: dict[str, str]):
        self.lock = threading.Lock()
        self.values: dict[str, dict[int, object]] = {k: {} for k in types}
        self.subs = [session.declare_subscriber(k, self._cb(k, t)) for k, t in types.items()]

    def _cb(self, key, msgtype):
        def on(sample):
            a = codec.parse_attachment(sample.attachment.to_bytes())
            m = codec.decode(sample.payload.to_bytes(), msgtype)
            with self.lock:
                self.values[key][a.t_ns] = m.data
        return on

    def copy(self, key) -> dict[int, object]:
        with self.lock:
            return dict(self.values[key])


def query_json(session, key):
    for reply in session.get(key, timeout=2.0):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
    return None


@pytest.mark.slow
def test_stairs_and_bouncing_on_the_bus_equal_fmpy_in_lockstep(procs, endpoint, bus, models):
    procs.diffbot("plant", "--world", "living_room", "--mode", "lockstep", "--disable", "camera",
                  "--expect", "Stair,bouncing", "--endpoint", endpoint, name="plant")
    s = bus()
    tap = Tap(s, {"fmu/Stair/counter": "std_msgs/msg/Int32",
                  "fmu/bouncing/h": "std_msgs/msg/Float64"})
    for path, extra in ((models["stairs_fmi2"], ("--instance", "Stair")),
                        (models["bouncing_fmi3"], ())):
        procs.diffbot("fmu-node", str(path), *extra, "--endpoint", endpoint, name=path.stem)
    wait_for(lambda: max(tap.copy("fmu/bouncing/h"), default=0) >= 3_000_000_000, 60,
             step=0.2, what="fmu/bouncing/h up to t=3 s")
    info = query_json(s, K.fmu_info("Stair"))
    assert info["step_size_s"] == 0.2 and info["variables"][0]["key"] == "fmu/Stair/counter"
    listed = subprocess.run([sys.executable, "-m", "diffbot.cli", "topics", "--json",
                             "--duration", "1", "--endpoint", endpoint], cwd=ROOT,
                            capture_output=True, text=True, timeout=60)
    table = json.loads(listed.stdout)
    types = {r["key"]: r["type"] for r in table["topics"]}
    assert types["fmu/Stair/counter"] == "std_msgs/msg/Int32"
    assert types["fmu/bouncing/v"] == "std_msgs/msg/Float64"
    assert {i["instance"] for i in table["fmus"]} == {"Stair", "bouncing"}
    twin = procs.diffbot("fmu-node", str(models["bouncing_fmi3"]), "--name", "twin",
                         "--endpoint", endpoint, name="twin")
    assert twin.wait(60) == 2
    assert "instance 'bouncing' is on the bus already (bouncing): give this one another " \
           "--instance" in procs.log(twin)
    for key, model, var, dt in (("fmu/Stair/counter", "stairs_fmi2", "counter", 0.2),
                                ("fmu/bouncing/h", "bouncing_fmi3", "h", 0.01)):
        got = tap.copy(key)
        stamps = sorted(t for t in got if t <= 3_000_000_000)
        assert stamps[0] == 0 and stamps == list(range(0, stamps[-1] + 1, TICK_NS)), key
        ref = fmpy_values(models[model], var, 3.0, dt)
        bad = [t for t in stamps if got[t] != at_tick(ref, t, dt)]
        assert not bad, f"{key}: {len(bad)} ticks differ from fmpy, first at {bad[0]} ns"


CHAIN = """
[scenario]
description = "two FMU nodes chained on the bus: bouncing.h -> gain.u, y = 2 h"
world = "living_room"
mode = "lockstep"
coupling = "sequential"
duration_s = 2.0
plant_args = ["--disable", "camera"]

[[process]]
name = "bouncing"
command = ["fmu-node", "{bouncing}"]

[[process]]
name = "gain"
command = ["fmu-node", "{gain}", "--connect", "u=fmu/bouncing/h", "--param", "k=2"]
"""


@pytest.mark.slow
def test_two_fmu_nodes_chained_in_a_scenario_file_run_in_lockstep(procs, endpoint, bus,
                                                                     models, tmp_path):
    scenario = tmp_path / "chain.toml"
    scenario.write_text(CHAIN.format(bouncing=models["bouncing_fmi3"], gain=models["gain_fmi3"]))
    mcap = tmp_path / "chain.mcap"
    run = procs.diffbot("run", str(scenario), "--endpoint", endpoint, "--out",
                        str(tmp_path / "out"), "--record", str(mcap), name="run")
    s = wait_for(lambda: _try_connect(bus), 30, step=0.2, what="the run's plant")
    tap = Tap(s, {"fmu/bouncing/h": "std_msgs/msg/Float64", "fmu/gain/y": "std_msgs/msg/Float64"})
    assert run.wait(120) == 0, procs.log(run)
    h, y = tap.copy("fmu/bouncing/h"), tap.copy("fmu/gain/y")
    common = sorted(set(h) & set(y))
    assert len(common) > 20, (len(h), len(y))
    # sequential lockstep: gain's tick k reads bouncing's tick k
    assert all(y[t] == 2 * h[t] for t in common)
    ref = fmpy_values(models["bouncing_fmi3"], "h", 2.0, 0.01)
    assert all(h[t] == at_tick(ref, t, 0.01) for t in common), "not fmpy's h"
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["sim_time_s"] == pytest.approx(2.0, abs=0.05)
    # the recording has the fmu/ keys with their types (asked from the nodes' info)
    from bridges.mcapfile import Recorded, iter_recording
    rec = Recorded(str(mcap))
    recorded = {}
    for m in iter_recording(str(mcap), rec):
        ch = rec.channels[m.channel_id]
        if ch.topic.lstrip("/") == "fmu/gain/y":
            schema = rec.schemas[ch.schema_id].name
            recorded[m.log_time] = codec.decode(m.data, schema).data
    assert schema == "std_msgs/msg/Float64" and len(recorded) > 20
    assert all(recorded[t] == y[t] for t in set(recorded) & set(y))


def _try_connect(bus):
    try:
        return bus()
    except Exception:
        return None


def test_late_joiner_starts_at_bus_time_or_waits_for_zero(models, caplog):
    late = {**INFO, "time_ns": 7_580_000_000}
    node = fmu_node.open_node(models["bouncing_fmi3"])
    try:
        with caplog.at_level("INFO"):
            node.configure(late, "robot1")
        assert "joins at t=7.580 s: its model starts at the current bus time" in caplog.text
        out = node.step(Observation(7_600_000_000, "robot1", {}))
        assert out["fmu/bouncing/h"].data == 1.0 and node.info()["started_at_s"] == pytest.approx(7.6)
    finally:
        node.close()
    node = fmu_node.open_node(models["bouncing_fmi3"], from_zero=True)
    try:
        node.configure(late, "robot1")
        assert node.step(Observation(7_600_000_000, "robot1", {})) is None
        assert node.step(Observation(7_620_000_000, "robot1", {})) is None
        assert node.step(Observation(0, "robot1", {}))["fmu/bouncing/h"].data == 1.0  # reset
        assert node.info()["started_at_s"] == 0.0
    finally:
        node.close()


def test_boolean_string_and_array_variables_on_their_keys(models):
    """signals (FMI 3): Boolean, String and Float64[3] inputs, Float64[3], String and Int32
    outputs, as Bool, String, Float64MultiArray and Int32 messages."""
    path = models["signals_fmi3"]
    node, outs = run_offline(path, 0.2)
    try:
        assert sorted(node.inputs) == ["fmu/signals/enable", "fmu/signals/prefix", "fmu/signals/u"]
        types = {t: node.topics[t].msgtype for t in node.inputs}
        assert types == {"fmu/signals/enable": "std_msgs/msg/Bool",
                         "fmu/signals/prefix": "std_msgs/msg/String",
                         "fmu/signals/u": "std_msgs/msg/Float64MultiArray"}
        ref = fmpy_values(path, "y", 0.2, 0.005)
        last = outs[200_000_000]
        y = last["fmu/signals/y"]
        assert y.__msgtype__ == "std_msgs/msg/Float64MultiArray"
        assert [d.size for d in y.layout.dim] == [3]
        assert all(list(o["fmu/signals/y"].data) == list(at_tick(ref, t, 0.005))
                   for t, o in outs.items()), "not fmpy's y"
        assert last["fmu/signals/label"].data == "ball on"
        assert last["fmu/signals/count"].data == 40
        # round trip through CDR, as on the bus
        assert list(codec.decode(codec.encode(y), y.__msgtype__).data) == list(y.data)
        # inputs: a Bool, a String and an array; a wrong-sized array is rejected and held
        T = codec.T
        u = node.outputs["y"]
        msgs = {"fmu/signals/enable": T["std_msgs/msg/Bool"](data=False),
                "fmu/signals/prefix": T["std_msgs/msg/String"](data="arm "),
                "fmu/signals/u": fmu_node.Variable.message(node.fmu.bus_variable("u"),
                                                           [9.0, 9.0, 9.0])}
        out = node.step(Observation(220_000_000, "robot1", msgs))
        assert out["fmu/signals/label"].data == "arm off"
        assert list(out["fmu/signals/y"].data) == u          # not enabled: y holds
        msgs = {"fmu/signals/enable": T["std_msgs/msg/Bool"](data=True),
                "fmu/signals/u": fmu_node.Variable.message(node.fmu.bus_variable("gain"), [1.0])}
        out = node.step(Observation(240_000_000, "robot1", msgs))
        assert node.rejects.counts["input"] == 1
        h = 0.02 / 4
        assert list(out["fmu/signals/y"].data) == pytest.approx(
            [u[k] + 4 * 2.0 * 9.0 * h for k in range(3)], abs=1e-12)
    finally:
        node.close()


def test_protocol_page_and_fmu_page_give_the_keys_of_the_code():
    protocol = (Path(ROOT) / "docs" / "PROTOCOL.md").read_text()
    page = (Path(ROOT) / "docs" / "fmu.md").read_text()
    for key in ("fmu/<instance>/<variable>", "fmu/<instance>/info"):
        assert f"| `{key}` |" in protocol and f"| `{key}` |" in page
    for name in ("der(x)", "a.b[1]", "info"):       # the rule's examples are the code's
        assert f"`{name}` is" in page or f"named `{name}`" in page
        assert escape_variable(name) in page
    assert "](docs/fmu.md)" in (Path(ROOT) / "README.md").read_text()    # linked from the front door


@pytest.mark.slow
def test_a_sigkilled_node_s_extraction_folder_is_removed_by_the_next_start(models, tmp_path):
    sock = tmp_path / "nobody.sock"
    p = subprocess.Popen([sys.executable, "-m", "diffbot.cli", "fmu-node",
                          str(models["gain_fmi3"]), "--wait", "--endpoint",
                          f"unixsock-stream/{sock}"], cwd=ROOT, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert "waiting" in p.stderr.readline() + p.stderr.readline()   # FMU extracted
        left = wait_for(lambda: list(fmu_mod.TMP_ROOT.glob(f"{p.pid}-*")), 10,
                        what="the node's extraction folder")
    finally:
        p.kill()
        p.wait(10)
    assert all(d.is_dir() for d in left), "SIGKILL leaves it behind"
    node = fmu_node.open_node(models["gain_fmi3"])          # the next start sweeps it
    node.close()
    assert not any(d.exists() for d in left)


def test_mapping_file_feeds_an_input_from_another_node_s_key_of_another_type(models, tmp_path):
    mapping = tmp_path / "gain.toml"
    mapping.write_text('[[input]]\nvariable = "u"\ntopic = "fmu/Stair/counter"\n'
                       'type = "Int32"\n\n[parameters]\nk = 0.5\n')
    node = fmu_node.open_node(models["gain_fmi3"], mapping)
    try:
        node.configure(INFO, "robot1")
        assert node.topics["fmu/Stair/counter"].msgtype == "std_msgs/msg/Int32"
        assert node.generic_topics == ["fmu/gain/y"]          # no [output]: on its key
        counter = codec.T["std_msgs/msg/Int32"](data=3)
        out = node.step(Observation(0, "robot1", {"fmu/Stair/counter": counter}))
        assert out["fmu/gain/y"].data == 1.5
    finally:
        node.close()
    mapping.write_text('[[input]]\nvariable = "u"\ntopic = "fmu/Stair/counter"\n'
                       'field = "data"\n')
    with pytest.raises(fmu_node.FmuNodeError, match=r"gain.toml:input\[0\].field: "
                                                    r"fmu/Stair/counter carries one FMU "
                                                    r"variable: no field"):
        fmu_node.open_node(models["gain_fmi3"], mapping)
