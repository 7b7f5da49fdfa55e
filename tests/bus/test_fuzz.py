"""Bad input, fuzzed: world and scenario files, command lines, and every key a process listens to.

* Loaders (in-process, hypothesis): random TOML-ish documents and random mutations of the
  shipped worlds through ``plant.world.parse_world`` / ``load_world`` and
  ``diffbot.launch.scenario.load_scenario``: only ``WorldError`` ever escapes; a world that loads
  also builds and steps with finite state.
* Command lines: wrong types, unknown keys, missing files, negative radii, zero or negative
  time steps, overlapping robots, names that would change key expressions: exit 2, one
  ``file:key: reason`` line, no traceback.
* The bus (slow, one lockstep run for the module: plant + odometry node + square_path):
  random bytes, truncated CDR, valid messages with NaN / inf / huge / negative values, wrong
  frames and joint names, stamps from the past, the future or off the tick grid, on
  ``<robot>/cmd_vel``, ``<robot>/wheel_cmd``, ``sim/ack/*``, ``sim/reset`` (queries),
  ``sim/clock``, ``<robot>/joint_states`` and ``<robot>/odom``. After every example the
  lockstep run must still advance (every member still acks: good messages keep being
  served); at the end no process died, each counted what it rejected, and the robot's
  state is finite.
"""
from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from bus import codec
from bus.keys import Keys
from diffbot.launch.scenario import load_scenario
from plant.world import WORLDS_DIR, WorldError, load_world, parse_world, tomllib

from ..conftest import ROOT, examples, wait_for

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py): one test starts 55 processes at once, which a
#: lockstep neighbour at the same priority once felt
pytestmark = pytest.mark.background

K = Keys()
TICK_NS = 20_000_000

# ====================================================================== loaders

WORLD_KEYS = [
    "world", "materials", "floor", "walls", "objects", "robots", "name", "mode",
    "physics_step_s", "control_tick_s", "gravity_mps2", "collision_detector",
    "contact_solver", "seed", "extends", "size_m", "color", "material", "height_m",
    "thickness_m", "shape", "radius_m", "pose", "static", "mass_kg", "friction", "drive",
    "lidar", "camera", "encoders", "gps", "motion", "noise", "parts", "wheel_radius_m",
    "wheel_separation_m", "max_wheel_speed_radps", "cmd_timeout_s", "num_rays", "fov_rad",
    "max_range_m", "min_range_m", "rate_hz", "width", "height", "hfov_rad", "std",
    "webots_noise", "resolution", "command_noise_std_radps", "enabled", "wheel_material",
    "chassis_mass_kg", "wheel_mass_kg", "box", "cylinder", "sphere", "robot1", "x",
]
SPECIAL_FLOATS = [0.0, -0.0, -1.0, 1e-300, -1e-300, 1e308, -1e308, math.inf, -math.inf,
                  math.nan, 0.001, 0.02, 0.3, 1e9, 2.0 ** 63]
scalars = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-2**70, max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(SPECIAL_FLOATS),
    st.text(max_size=12), st.sampled_from(WORLD_KEYS),
)
toml_values = st.recursive(
    scalars,
    lambda children: st.one_of(
        st.lists(children, max_size=5),
        st.dictionaries(st.sampled_from(WORLD_KEYS) | st.text(max_size=8), children,
                        max_size=5)),
    max_leaves=25)
documents = st.dictionaries(st.sampled_from(WORLD_KEYS) | st.text(max_size=8), toml_values,
                            max_size=8)


def _base_worlds() -> list[dict]:
    out = []
    for f in sorted(os.listdir(WORLDS_DIR)):
        if f.endswith(".toml"):
            with open(os.path.join(WORLDS_DIR, f), "rb") as fh:
                out.append(tomllib.load(fh))
    return out


BASES = _base_worlds()


def _paths(node, prefix=()):
    """Every path into a nested dict/list document."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


@st.composite
def mutated_worlds(draw):
    """A shipped world with a few leaves replaced, removed or added: reaches deep checks."""
    doc = json.loads(json.dumps(draw(st.sampled_from(BASES))))   # deep copy
    for _ in range(draw(st.integers(1, 4))):
        paths = [p for p in _paths(doc) if p]
        path = draw(st.sampled_from(paths))
        parent = doc
        for step in path[:-1]:
            parent = parent[step]
        op = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        if op == "replace":
            parent[path[-1]] = draw(toml_values)
        elif op == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.sampled_from(WORLD_KEYS))] = draw(toml_values)
        else:
            parent.append(draw(toml_values))
    return doc


def _only_world_errors(fn, *args):
    try:
        return fn(*args)
    except WorldError as exc:
        msg = str(exc)
        assert msg.strip() and "\n" not in msg.strip(), f"not one line: {msg!r}"
        return None
    # any other exception fails the test with its traceback


def _builds_and_steps(spec) -> None:
    from plant.sim import Simulation
    sim = Simulation(spec)
    for name in sim.robots:
        sim.command_twist(name, 0.3, 0.5)
    sim.step_tick()
    assert sim.is_finite()


@settings(max_examples=examples(100), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(documents)
def test_world_parser_raises_only_world_errors_on_random_documents(doc):
    spec = _only_world_errors(parse_world, doc, "fuzz.toml")
    if spec is not None:
        _builds_and_steps(spec)


@settings(max_examples=examples(150), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated_worlds())
def test_world_parser_raises_only_world_errors_on_mutated_worlds(doc):
    spec = _only_world_errors(parse_world, doc, "fuzz.toml")
    if spec is not None and len(spec.objects) < 60:
        _builds_and_steps(spec)


# -- the same through files (TOML text, [world] extends, --set overrides, scenarios)

def to_toml(doc: dict) -> str | None:
    """A small TOML writer for fuzzed documents (None if TOML cannot say it: None values,
    NaN keys ...)."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int):
            return str(v) if -2**63 <= v < 2**63 else None
        if isinstance(v, float):
            if math.isnan(v):
                return "nan"
            if math.isinf(v):
                return "inf" if v > 0 else "-inf"
            return repr(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            items = [value(x) for x in v]
            return None if any(i is None for i in items) else "[" + ", ".join(items) + "]"
        if isinstance(v, dict):
            items = [(json.dumps(str(k)), value(x)) for k, x in v.items()]
            if any(i is None for _, i in items):
                return None
            return "{" + ", ".join(f"{k} = {i}" for k, i in items) + "}"
        return None
    lines = []
    for k, v in doc.items():
        text = value(v)
        if text is None:
            return None
        lines.append(f"{json.dumps(str(k))} = {text}")
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def scratch():
    d = tempfile.mkdtemp(prefix="dbf-")
    yield d
    shutil.rmtree(d, ignore_errors=True)


extending = st.builds(
    lambda base, rest, world: {**rest, "world": {"extends": base, **world}},
    st.sampled_from(["empty", "living_room", "nope", "", ".", 3, ["empty"]]),
    st.dictionaries(st.sampled_from(["objects", "robots", "floor", "walls", "materials"]),
                    toml_values, max_size=3),
    st.dictionaries(st.sampled_from(WORLD_KEYS), toml_values, max_size=2))


@settings(max_examples=examples(150), deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(doc=st.one_of(mutated_worlds(), documents, extending),
       overrides=st.lists(st.text(max_size=30) | st.sampled_from([
           "world.mode=kinematic", "robots.robot1.pose=[1, 2]", "floor.size_m=-1",
           "robots.nobody.pose=[0,0,0]", "world=3", "=", "a.b.c=[", "objects=1",
           "world.extends=3", "world.extends=\"empty\""]), max_size=3))
def test_world_files_and_overrides_raise_only_world_errors(scratch, doc, overrides):
    text = to_toml(doc)
    assume(text is not None)
    path = os.path.join(scratch, "fuzz_world.toml")
    with open(path, "w") as f:
        f.write(text)
    _only_world_errors(load_world, path, overrides)


SCENARIO_KEYS = ["scenario", "process", "world", "mode", "duration_s", "analysis", "robot",
                 "plant_args", "description", "name", "command", "required", "ends_run",
                 "sync", "interactive", "lockstep", "square", "empty"]
scenario_values = st.recursive(
    scalars | st.sampled_from(SCENARIO_KEYS),
    lambda children: st.one_of(
        st.lists(children, max_size=4),
        st.dictionaries(st.sampled_from(SCENARIO_KEYS), children, max_size=5)),
    max_leaves=20)


@settings(max_examples=examples(150), deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(doc=st.dictionaries(st.sampled_from(SCENARIO_KEYS), scenario_values, max_size=4)
       | st.builds(lambda s, ps: {"scenario": s, "process": ps},
                   st.dictionaries(st.sampled_from(SCENARIO_KEYS), scenario_values, max_size=6),
                   st.lists(st.dictionaries(st.sampled_from(SCENARIO_KEYS), scenario_values,
                                            max_size=6), max_size=3)),
       raw=st.none() | st.binary(max_size=60))
def test_scenario_loader_raises_only_world_errors(scratch, doc, raw):
    path = os.path.join(scratch, "fuzz_scenario.toml")
    if raw is not None:
        with open(path, "wb") as f:
            f.write(raw)
    else:
        text = to_toml(doc)
        assume(text is not None)
        with open(path, "w") as f:
            f.write(text)
    _only_world_errors(load_scenario, path)


def test_decoder_raises_only_codec_errors():
    """Random bytes, truncated and bit-flipped CDR of every message type on the bus."""
    from bus.keys import CLOCK_TYPE, TOPICS
    rng = np.random.default_rng(0)
    samples = {
        CLOCK_TYPE: codec.clock(123 * TICK_NS),
        "geometry_msgs/msg/TwistStamped": codec.twist_stamped(TICK_NS, 0.2, 0.1),
        "sensor_msgs/msg/JointState": codec.joint_state(TICK_NS, ["a", "b"], [1, 2], [3, 4]),
        "nav_msgs/msg/Odometry": codec.odometry(TICK_NS, 1, 2, 0.3, 0.1, 0.2),
        "geometry_msgs/msg/PointStamped": codec.point_stamped(TICK_NS, 1, 2, 3),
        "sensor_msgs/msg/LaserScan": codec.laser_scan(0, -1, 1, 0.1, 0.1, 0.01, 10,
                                                      np.ones(21)),
        "sensor_msgs/msg/Image": codec.image(0, np.zeros((4, 5, 3), np.uint8)),
    }
    types = {t.msgtype for t in TOPICS.values()} | {CLOCK_TYPE}
    for msgtype in sorted(types):
        good = codec.encode(samples[msgtype]) if msgtype in samples else b""
        cases = [bytes(rng.integers(0, 256, n, dtype=np.uint8)) for n in (0, 1, 4, 9, 64, 999)]
        cases += [good[:i] for i in range(len(good))]
        for _ in range(200):
            b = bytearray(good or b"\x00\x01\x00\x00" + bytes(20))
            b[rng.integers(0, len(b))] ^= 1 << int(rng.integers(0, 8))
            cases.append(bytes(b))
        for data in cases:
            try:
                codec.decode(data, msgtype)
            except codec.CodecError:
                pass


# ====================================================================== command lines

def _diffbot(*args: str) -> tuple[int, str]:
    """``diffbot ARGS`` as a process of its own: (exit code, stderr)."""
    p = subprocess.run([sys.executable, "-m", "diffbot.cli", *args], cwd=ROOT, text=True,
                       capture_output=True, stdin=subprocess.DEVNULL, start_new_session=True,
                       timeout=90)
    return p.returncode, p.stderr


def _refusals(commands: list[list[str]]) -> list[tuple[int, str]]:
    """(exit code, stderr) of ``diffbot ARGS`` for each of ``commands``, each in a process
    of its own forked from one interpreter that imported the command line once
    (tests/support/forked_cli.py: ~0.3 s of CPU less per command). The first is also run as a
    process started afresh, and must give the same (but for its log lines' times)."""
    r = subprocess.run([sys.executable, "-m", "tests.support.forked_cli"], input=json.dumps(commands),
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    got = [tuple(x) for x in json.loads(r.stdout)]
    assert len(got) == len(commands)
    fresh, forked = (f"{code}\n" + re.sub(r"(?m)^\d\d:\d\d:\d\d ", "", err)   # (log times)
                     for code, err in (_diffbot(*commands[0]), got[0]))
    assert forked == fresh, "a forked command differs from the process"
    return got


EMPTY_ROBOT = '[[robots]]\nname = "robot1"\npose = [0.0, 0.0, 0.0]\n'
BAD_WORLDS = {
    # file text -> what the one error line must say (after "FILE:")
    "wrong_type": ('[world]\ncontrol_tick_s = "fast"\n' + EMPTY_ROBOT,
                   "world.control_tick_s: expected a number"),
    "unknown_key": ('[world]\ncontrol_tick = 0.02\n' + EMPTY_ROBOT,
                    "world.control_tick: unknown key (did you mean 'control_tick_s'?)"),
    "negative_radius": ('[[objects]]\nname = "pot"\nshape = "cylinder"\nradius_m = -0.2\n'
                        'height_m = 0.5\n' + EMPTY_ROBOT,
                        "objects[0].radius_m: must be > 0"),
    "negative_wheel": ('[[robots]]\nname = "robot1"\n[robots.drive]\nwheel_radius_m = -0.12\n',
                       "robots[0].drive.wheel_radius_m: must be > 0"),
    "zero_step": ("[world]\nphysics_step_s = 0.0\n" + EMPTY_ROBOT,
                  "world.physics_step_s: must be > 0"),
    "negative_tick": ("[world]\ncontrol_tick_s = -0.02\n" + EMPTY_ROBOT,
                      "world.control_tick_s: must be > 0"),
    "overlap": (EMPTY_ROBOT + '[[robots]]\nname = "robot2"\npose = [0.2, 0.1, 0.0]\n',
                "robots: robots 'robot1' and 'robot2' overlap"),
    "bad_robot_name": ('[[robots]]\nname = "robot/*"\n', "robots[0].name: invalid robot name"),
    "not_toml": ("[world\n", " not valid TOML"),
}
BAD_SCENARIOS = {
    "wrong_type": ('[scenario]\nworld = "empty"\nduration_s = "long"\n',
                   "scenario.duration_s: expected a number"),
    "unknown_key": ('[scenario]\nworld = "empty"\nmdoe = "fast"\n',
                    "scenario.mdoe: unknown key (did you mean 'mode'?)"),
    "negative_duration": ('[scenario]\nworld = "empty"\nduration_s = -5\n',
                          "scenario.duration_s: must be > 0"),
    "process_not_list": ('[scenario]\nworld = "empty"\n[process]\nname = "x"\n',
                         "process: expected an array of tables"),
    "bad_process_name": ('[scenario]\nworld = "empty"\n[[process]]\nname = "a*"\n'
                         'command = ["controller", "odometry"]\n',
                         "process[0].name: invalid process name 'a*'"),
    "bad_command": ('[scenario]\nworld = "empty"\n[[process]]\nname = "x"\ncommand = "go"\n',
                    "process[0].command: expected a non-empty list of strings"),
}


@pytest.mark.slow
def test_bad_world_and_scenario_files_exit_2_with_file_key_reason(tmp_path):
    runs = []
    for tag, (text, want) in BAD_WORLDS.items():
        path = tmp_path / f"{tag}.toml"
        path.write_text(text)
        runs.append((f"plant world {tag}", f"{path}:{want}",
                     ["plant", "--world", str(path), "--endpoint",
                      f"unixsock-stream/{tmp_path}/never.sock"]))
    for tag, (text, want) in BAD_SCENARIOS.items():
        path = tmp_path / f"scenario_{tag}.toml"
        path.write_text(text)
        runs.append((f"run scenario {tag}", f"{path}:{want}",
                     ["run", str(path), "--out", str(tmp_path / "out")]))
    world = tmp_path / "overlap.toml"
    world.write_text(BAD_WORLDS["overlap"][0])
    scen = tmp_path / "uses_bad_world.toml"
    scen.write_text(f'[scenario]\nworld = "{world}"\n')
    runs.append(("run scenario with a bad world", f"{world}:robots: robots 'robot1'",
                 ["run", str(scen), "--out", str(tmp_path / "out")]))
    runs.append(("plant missing world", "no-such-world.toml: no such world file",
                 ["plant", "--world", "no-such-world.toml"]))
    runs.append(("run missing scenario", "no-such.toml: no such scenario",
                 ["run", "no-such.toml"]))
    runs.append(("plant missing zenoh config", "nope.json5: no such Zenoh config file",
                 ["plant", "--world", "empty", "--zenoh-config", "nope.json5"]))
    runs.append(("plant bad override", "robots[0].pose: expected a list of 3 numbers",
                 ["plant", "--world", "empty", "--set", "robots.robot1.pose=[1]"]))
    failures = []
    for (what, want, _), (code, err) in zip(runs, _refusals([argv for _, _, argv in runs])):
        lines = [ln for ln in err.strip().splitlines() if ln.strip()]
        if code != 2 or "Traceback" in err or len(lines) != 1 or want not in err:
            failures.append(f"{what}: exit {code}, stderr:\n{err}")
    assert not failures, "\n\n".join(failures)


BAD_NAMES = ["*", "**", "$x", "a/b", "", "robot 1", "sim", "x" * 65, "a*b", "../x"]


@pytest.mark.slow
def test_names_that_would_change_key_expressions_are_refused_with_exit_2(tmp_path):
    ep = f"unixsock-stream/{tmp_path}/never.sock"
    runs = []
    for i, name in enumerate(BAD_NAMES):
        cases = [("controller --robot", ["controller", "square_path", "--robot", name]),
                 ("controller --name", ["controller", "odometry", "--name", name]),
                 ("controller --namespace", ["controller", "teleop", "--namespace", name]),
                 ("plant --namespace", ["plant", "--world", "empty", "--namespace", name]),
                 ("run --namespace", ["run", "drive-test", "--namespace", name, "--out",
                                      str(tmp_path / f"out{i}")])]
        if name:
            cases.append(("fmu-node --robot", ["fmu-node", "odometry", "--robot", name]))
        else:         # an empty --namespace is the default: no prefix
            cases = cases[:2]
        for what, argv in cases:
            runs.append((f"{what} {name!r}",
                         [*argv, "--endpoint", ep] if argv[0] != "run" else argv))
    failures = []
    for (what, _), (code, err) in zip(runs, _refusals([argv for _, argv in runs])):
        if code != 2 or "Traceback" in err or "invalid" not in err:
            failures.append(f"{what}: exit {code}, stderr:\n{err[-600:]}")
    assert not failures, "\n\n".join(failures)


# ====================================================================== the bus

class LiveRun:
    """One lockstep run for the module: plant + Python odometry node + square_path, and a
    session of the test that injects bad input and watches the clock and ground truth."""

    NODES = {"odometry_robot1": ("controller", "odometry"),
             "square_path_robot1": ("controller", "square_path", "--laps", "1000",
                                    "--side", "1.0")}

    def __init__(self) -> None:
        from bus.session import open_session
        self.dir = tempfile.mkdtemp(prefix="dbz-")
        self.endpoint = f"unixsock-stream/{self.dir}/bus.sock"
        self.procs: dict[str, subprocess.Popen] = {}
        self._start("plant", "plant", "--world", "empty", "--mode", "lockstep", "--expect",
                    ",".join(self.NODES))
        for name, argv in self.NODES.items():
            self._start(name, *argv)
        self.session = open_session("fuzz", self.endpoint)
        self.lock = threading.Lock()
        self.ticks = 0
        self.t_ns = -1
        self.bad_truth: list = []
        self.subs = [self.session.declare_subscriber(K.clock, self._on_clock),
                     self.session.declare_subscriber(K.topic("robot1", "ground_truth"),
                                                     self._on_gt)]
        self.seq = 1 << 40
        self.stopped = False
        wait_for(lambda: self.ticks > 20, 90, what="the lockstep run to start")

    def _start(self, name, *argv) -> None:
        log = open(os.path.join(self.dir, f"{name}.log"), "wb")
        self.procs[name] = subprocess.Popen(
            [sys.executable, "-m", "diffbot.cli", *argv, "--endpoint", self.endpoint,
             "--stats", os.path.join(self.dir, f"{name}.json")], cwd=ROOT,
            stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            env=dict(os.environ, PYTHONUNBUFFERED="1"), start_new_session=True)

    def _on_clock(self, s) -> None:
        try:
            t = codec.msg_stamp_ns(codec.decode(s.payload.to_bytes(), "rosgraph_msgs/msg/Clock"))
        except codec.CodecError:
            return
        att = codec.parse_attachment(s.attachment.to_bytes() if s.attachment else None)
        if att is not None and att[0] < (1 << 40):       # the plant's, not ours
            with self.lock:
                self.ticks += 1
                self.t_ns = t

    def _on_gt(self, s) -> None:
        m = codec.decode(s.payload.to_bytes(), "nav_msgs/msg/Odometry")
        p, q, tw = m.pose.pose.position, m.pose.pose.orientation, m.twist.twist
        vals = (p.x, p.y, p.z, q.x, q.y, q.z, q.w, tw.linear.x, tw.angular.z)
        if not all(math.isfinite(v) for v in vals) or abs(p.x) > 50 or abs(p.y) > 50:
            with self.lock:
                self.bad_truth.append(vals)

    def now(self) -> int:
        with self.lock:
            return max(self.t_ns, 0)

    def put(self, key: str, payload: bytes, attachment: bytes | None) -> None:
        self.session.put(key, payload, attachment=attachment)

    def log(self, name: str) -> str:
        with open(os.path.join(self.dir, f"{name}.log"), "rb") as f:
            return f.read().decode("utf-8", "replace")

    def still_going(self, what) -> None:
        """Every process alive and the lockstep run advancing (every member acks)."""
        with self.lock:
            n0 = self.ticks
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline:
            with self.lock:
                if self.ticks >= n0 + 3:
                    break
            time.sleep(0.005)
        dead = {n: p.returncode for n, p in self.procs.items() if p.poll() is not None}
        assert not dead, f"after {what}: died {dead}\n" + "\n".join(
            self.log(n)[-2000:] for n in dead)
        with self.lock:
            assert self.ticks >= n0 + 3, f"lockstep stalled after {what} (logs in {self.dir}):" \
                + "".join(f"\n--- {n}\n" + self.log(n)[-1500:] for n in self.procs)
            assert not self.bad_truth, f"robot state not finite / absurd: {self.bad_truth[:3]}"

    def stop(self) -> dict[str, dict]:
        self.stopped = True
        # the plant first: its members see the end (a member stopped before it is lost to
        # a lockstep plant, which then ends the run with exit 1, docs/PROTOCOL.md)
        for name in ["plant"] + list(self.NODES):
            p = self.procs[name]
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)
        for sub in self.subs:
            sub.undeclare()
        self.session.close()
        out = {}
        for name in self.procs:
            try:
                with open(os.path.join(self.dir, f"{name}.json")) as f:
                    out[name] = json.load(f)
            except (OSError, ValueError):
                out[name] = {}
        return out

    def cleanup(self, keep: bool = False) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.kill()
                p.wait(5)
        if not keep:
            shutil.rmtree(self.dir, ignore_errors=True)


@pytest.fixture(scope="module")
def _live_runs():
    runs: list[LiveRun] = []
    yield runs
    for run in runs:
        run.cleanup(keep=bool(os.environ.get("DIFFBOT_KEEP_FUZZ_LOGS")))


@pytest.fixture
def live(_live_runs):
    """The module's lockstep run, started again if a test has stopped it (the final
    count does): so the tests pass in any order."""
    if not _live_runs or _live_runs[-1].stopped:
        _live_runs.append(LiveRun())
    return _live_runs[-1]


# -- what goes on the wire

weird_floats = st.one_of(st.sampled_from(SPECIAL_FLOATS + [0.2, -0.2, 1.0, 5.0, -50.0]),
                         st.floats(allow_nan=True, allow_infinity=True))
STAMPS = ["now", "now", "zero", "past", "far_past", "future", "far_future", "off_grid",
          "bad_nanosec", "negative"]
names = st.one_of(st.just(["left_wheel_joint", "right_wheel_joint"]),
                  st.just(["right_wheel_joint", "left_wheel_joint"]),
                  st.lists(st.sampled_from(["left_wheel_joint", "right_wheel_joint", "", "l",
                                            "wheel", "\x00", "é" * 40]), max_size=4),
                  st.lists(st.text(max_size=20), max_size=3))
frames = st.sampled_from(["", "base_link", "world", "odom", "laser", "\x00", "x" * 300])


def _time(kind: str, now: int):
    T = codec.T["builtin_interfaces/msg/Time"]
    if kind == "bad_nanosec":
        return T(sec=now // 10**9, nanosec=2_000_000_000)
    if kind == "negative":
        return T(sec=-5, nanosec=0)
    t = {"now": now, "zero": 0, "past": max(0, now - 40 * TICK_NS),
         "far_past": max(0, now - 10**11) // TICK_NS * TICK_NS, "future": now + 3 * TICK_NS,
         "far_future": now + 10**12, "off_grid": now + 1234}[kind]
    return codec.time_msg(t)


@st.composite
def messages(draw, kind: str):
    """A function now_ns -> (payload, attachment) for a message of ``kind``."""
    how = draw(st.sampled_from(["valid", "valid", "valid", "bytes", "truncated", "flipped"]))
    stamp = draw(st.sampled_from(STAMPS))
    frame = draw(frames)
    f = draw(st.lists(weird_floats, min_size=8, max_size=8))
    jnames = draw(names)
    n_pos = draw(st.integers(0, 3))
    att_kind = draw(st.sampled_from(["none", "ours", "garbage"]))
    raw = draw(st.binary(max_size=200))
    cut = draw(st.integers(0, 400))
    flip = draw(st.integers(0, 10**6))

    def build(now: int, seq: int):
        if kind == "twist":
            m = codec.twist_stamped(0, f[0], f[1], frame_id=frame)
            m.twist.linear.y, m.twist.angular.x = f[2], f[3]
        elif kind == "joint_state":
            m = codec.joint_state(0, jnames, f[:n_pos], f[3:3 + n_pos])
        elif kind == "odom":
            q = (0.0, 0.0, f[5], f[6]) if n_pos == 3 else (0.0, 0.0, 0.0, 1.0)
            m = codec.odometry(0, f[0], f[1], 0.0, f[3], f[4], frame_id=frame, quaternion=q)
        else:
            m = codec.clock(0)
        if kind == "clock":
            m.clock = _time(stamp, now)
        else:
            m.header.stamp = _time(stamp, now)
        good = codec.encode(m)
        if how == "valid":
            payload = good
        elif how == "bytes":
            payload = raw
        elif how == "truncated":
            payload = good[:cut % max(1, len(good))]
        else:
            b = bytearray(good)
            b[flip % len(b)] ^= 1 << (flip % 8)
            payload = bytes(b)
        t_ns = codec.stamp_ns(m.header.stamp if kind != "clock" else m.clock) \
            if stamp not in ("bad_nanosec", "negative") else now
        att = {"none": None, "ours": codec.attachment(seq, max(0, t_ns)),
               "garbage": raw[:16]}[att_kind]
        return payload, att
    return build


FUZZ = settings(max_examples=examples(100), deadline=None,
                suppress_health_check=[HealthCheck.too_slow,
                                       HealthCheck.function_scoped_fixture])


def _inject(live, key, builds):
    for build in builds:
        live.seq += 1
        payload, att = build(live.now(), live.seq)
        live.put(key, payload, att)


@pytest.mark.slow
@FUZZ
@given(key=st.sampled_from(["cmd_vel", "wheel_cmd"]),
       twists=st.lists(messages("twist"), min_size=1, max_size=4),
       wheels=st.lists(messages("joint_state"), min_size=1, max_size=4))
def test_plant_commands(live, key, twists, wheels):
    _inject(live, K.topic("robot1", key), twists if key == "cmd_vel" else wheels)
    live.still_going(f"bad {key}")


MEMBER_NAMES = ["square_path_robot1", "odometry_robot1", "nobody", "plant", "é", "x" * 255]


@pytest.mark.slow
@FUZZ
@given(node=st.sampled_from(["square_path_robot1", "odometry_robot1", "nobody", "plant"]),
       acks=st.lists(st.one_of(
           st.tuples(st.binary(max_size=40), st.none() | st.binary(max_size=40)),
           st.tuples(st.sampled_from(STAMPS), st.integers(0, 255), st.integers(0, 65535),
                     st.sampled_from(MEMBER_NAMES), st.binary(max_size=8))),
           min_size=1, max_size=4))
def test_plant_acks(live, node, acks):
    """Forged, malformed and stray ACKs on sim/ack/<node> (docs/PROTOCOL.md): random bytes,
    and well-formed trailers with any flags, counts, names and stamps."""
    for a in acks:
        if len(a) == 2:
            payload, att = a
        else:
            kind, flags, n_plant, who, payload = a
            t = _time(kind, live.now())
            live.seq += 1
            att = codec.attachment(live.seq, max(0, t.sec) * 10**9 + t.nanosec, flags, n_plant,
                                   who)
        live.put(K.ack(node), payload, att)
    live.still_going(f"bad acks from {node}")


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=8),
    lambda c: st.lists(c, max_size=4) | st.dictionaries(
        st.sampled_from(["seed", "poses", "robot1", "robot2", "x"]), c, max_size=4),
    max_leaves=12)


@pytest.mark.slow
@settings(max_examples=examples(60), deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(req=st.one_of(
    st.binary(max_size=80),
    json_values.map(lambda v: json.dumps(v).encode()),
    st.builds(lambda seed, poses: json.dumps({"seed": seed, "poses": poses}).encode(),
              st.integers(-5, 2**64) | st.floats() | st.text(max_size=3),
              st.dictionaries(st.sampled_from(["robot1", "robot2"]),
                              st.lists(weird_floats.filter(lambda v: not math.isnan(v)),
                                       max_size=4), max_size=2))))
def test_plant_reset_queries(live, req):
    replies = list(live.session.get(K.reset, payload=req, timeout=10.0))
    assert len(replies) == 1, "the plant answers every reset query"
    r = replies[0]
    raw = (r.ok or r.err).payload.to_bytes()
    try:
        body = json.loads(raw)
    except ValueError:
        raise AssertionError(f"reply {raw!r} to {req!r}; plant log:\n"
                             f"{live.log('plant')[-3000:]}") from None
    assert ("ok" in body) if r.ok is not None else ("error" in body)
    live.still_going(f"reset {req[:60]!r}")


@pytest.mark.slow
@FUZZ
@given(clocks=st.lists(messages("clock"), min_size=1, max_size=4))
def test_nodes_clock(live, clocks):
    _inject(live, K.clock, clocks)
    live.still_going("bad clocks")


@pytest.mark.slow
@FUZZ
@given(topic=st.sampled_from(["joint_states", "odom"]),
       js=st.lists(messages("joint_state"), min_size=1, max_size=4),
       odom=st.lists(messages("odom"), min_size=1, max_size=4))
def test_nodes_inputs(live, topic, js, odom):
    _inject(live, K.topic("robot1", topic), js if topic == "joint_states" else odom)
    live.still_going(f"bad {topic}")


def _one_bad_sample_of_each(live) -> None:
    """One malformed message on every key the fuzz tests above aim at, so the counts
    below do not depend on those tests having run first (or on what Hypothesis drew)."""
    for topic in ("cmd_vel", "wheel_cmd", "joint_states", "odom"):
        live.put(K.topic("robot1", topic), b"\x00\x01\x02", None)
    live.put(K.clock, b"\x07", None)
    live.put(K.ack("nobody"), b"", None)                  # an ACK with no attachment
    replies = list(live.session.get(K.reset, payload=b"not json", timeout=10.0))
    assert len(replies) == 1 and replies[0].err is not None, replies


@pytest.mark.slow
def test_after_the_fuzz_nobody_died_every_reject_was_counted(live):
    _one_bad_sample_of_each(live)
    live.still_going("the fuzz")
    wait_for(lambda: live.ticks > 120, 60, what="120 ticks of the run")   # whatever ran before
    stats = live.stop()
    codes = {n: p.returncode for n, p in live.procs.items()}
    assert codes == {n: 0 for n in live.procs}, codes
    rejected = {n: st.get("rejected", {}) for n, st in stats.items()}
    plant = rejected["plant"]
    for reason in ("robot1/cmd_vel", "robot1/wheel_cmd", "reset"):
        assert plant.get(reason, 0) > 0, (reason, plant)
    # bad ACKs are lockstep protocol problems (docs/PROTOCOL.md), counted apart
    protocol = stats["plant"].get("protocol_errors", {})
    assert sum(n for why, n in protocol.items() if why.startswith("sim/ack/")) > 0, protocol
    assert rejected["odometry_robot1"].get("joint_states", 0) > 0, rejected
    assert rejected["odometry_robot1"].get("clock", 0) > 0, rejected
    assert rejected["square_path_robot1"].get("odom", 0) > 0, rejected
    assert stats["square_path_robot1"]["ticks"] > 100
    for name in live.procs:
        log = live.log(name)
        assert "Traceback" not in log, log[-3000:]
        assert log.count("rejected") < 200, f"{name}: warnings not rate limited"
