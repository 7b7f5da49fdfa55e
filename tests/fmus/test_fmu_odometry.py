"""The odometry FMUs (fmus/): build, validate, simulate with two importers, rebuild from sources.

The FMUs are built once per session into a temporary directory with the system C
compiler (the ``built_fmus`` fixture of tests/conftest.py). The reference trajectory is the closed-form
arc solution of the unicycle for piecewise-constant wheel speeds, written here
independently of the C code's sinc form.
"""

from __future__ import annotations

import ctypes
import math
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.simulation import instantiate_fmu  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from fmus import build as fmu_build  # noqa: E402

from ..conftest import CI  # noqa: E402

#: xdist_group: with test_fmu_node, one worker builds the session's FMUs (conftest.built_fmus)
#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = [pytest.mark.xdist_group("fmus"), pytest.mark.background]
VERSIONS = (2, 3)
R, D = 0.12, 0.36  # default wheel_radius, wheel_separation (m)
VR = {"omega_left": 1, "omega_right": 2, "wheel_radius": 3, "wheel_separation": 4, "x0": 5, "y0": 6,
      "theta0": 7, "x": 8, "y": 9, "theta": 10, "der(x)": 11, "der(y)": 12, "der(theta)": 13,
      "v": 14, "omega": 15}
POSE_TOL = 1e-9  # m and rad
BINARY = "odometry" + (".dylib" if sys.platform == "darwin" else ".so")

# The 60 s drive: (duration s, v m/s, omega rad/s) -> wheel speeds held over each segment.
DRIVE = [
    (8.0, 0.5, 0.0),     # straight ahead
    (8.0, 0.4, 0.5),     # arc to the left
    (6.0, 0.0, 1.2),     # spin in place, counter-clockwise
    (8.0, 0.3, -0.4),    # arc to the right
    (4.0, 0.0, -0.9),    # spin in place, clockwise
    (6.0, -0.25, 0.0),   # straight backwards
    (8.0, -0.2, 0.3),    # arc backwards
    (4.0, 0.0, 0.0),     # stop
    (8.0, 0.6, 2e-4),    # very gentle curve
]
STOP_TIME = sum(seg[0] for seg in DRIVE)


def wheel_speeds(v: float, omega: float) -> tuple[float, float]:
    """(omega_left, omega_right) in rad/s for a body twist (v, omega)."""
    if v == 0.0:  # spin in place: exactly opposite wheel speeds, so that v is exactly 0
        right = omega * D / 2 / R
        return -right, right
    return (v - omega * D / 2) / R, (v + omega * D / 2) / R


def body_twist(omega_left: float, omega_right: float) -> tuple[float, float]:
    """(v, omega) from the wheel speeds, the model's kinematics."""
    return R * (omega_right + omega_left) / 2, R * (omega_right - omega_left) / D


def arc(x: float, y: float, theta: float, v: float, omega: float, t: float) -> tuple[float, float, float]:
    """Closed-form pose after driving t seconds with constant (v, omega)."""
    if omega == 0.0:
        return x + v * t * math.cos(theta), y + v * t * math.sin(theta), theta
    return (x + v / omega * (math.sin(theta + omega * t) - math.sin(theta)),
            y - v / omega * (math.cos(theta + omega * t) - math.cos(theta)),
            theta + omega * t)


def segments():
    """[(t_start, duration, omega_left, omega_right, v, omega, start pose)] of DRIVE."""
    out, t, pose = [], 0.0, (0.0, 0.0, 0.0)
    for duration, v_cmd, w_cmd in DRIVE:
        wl, wr = wheel_speeds(v_cmd, w_cmd)
        v, w = body_twist(wl, wr)
        out.append((t, duration, wl, wr, v, w, pose))
        pose = arc(*pose, v, w, duration)
        t += duration
    return out


def reference_pose(times) -> np.ndarray:
    segs = segments()
    poses = []
    for t in times:
        for t0, duration, _, _, v, w, pose in segs:
            if t <= t0 + duration + 1e-12:
                break
        poses.append(arc(*pose, v, w, t - t0))
    return np.array(poses)


def input_signals() -> np.ndarray:
    """fmpy input table: each segment's value at its start and end time (step changes at repeated times)."""
    rows = []
    for t0, duration, wl, wr, *_ in segments():
        rows += [(t0, wl, wr), (t0 + duration, wl, wr)]
    return np.array(rows, dtype=[("time", np.float64), ("omega_left", np.float64), ("omega_right", np.float64)])


def max_pose_error(result) -> tuple[float, float, float]:
    ref = reference_pose(result["time"])
    return tuple(float(np.max(np.abs(result[name] - ref[:, i]))) for i, name in enumerate(("x", "y", "theta")))


def run(command, **kwargs) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    # console scripts (cmake, fmutool) of the running interpreter's environment, even if it is not activated
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    return subprocess.run(command, capture_output=True, text=True, env=env, timeout=300, **kwargs)


# ---------------------------------------------------------------- fixtures


@pytest.fixture(scope="session")
def fmus(built_fmus) -> dict[int, Path]:
    return built_fmus


@pytest.fixture(scope="module")
def unzipped(fmus, tmp_path_factory) -> dict[int, str]:
    return {v: extract(str(fmus[v]), unzipdir=str(tmp_path_factory.mktemp(f"unzipped{v}"))) for v in VERSIONS}


class LogCapture:
    """Logger callbacks for fmpy that record (status, message)."""

    def __init__(self):
        self.messages: list[tuple[int, str]] = []

    def fmi2(self, env, instance_name, status, category, message):
        self.messages.append((status, message.decode()))

    def fmi3(self, env, status, category, message):
        self.messages.append((status, message.decode()))

    def logger(self, version):
        return self.fmi2 if version == 2 else self.fmi3

    def text(self) -> str:
        return "\n".join(m for _, m in self.messages)


def instantiate(unzipdir, version, fmi_type="CoSimulation", log=None, guid=None, debug_logging=False):
    md = read_model_description(unzipdir)
    if guid is not None:
        md.guid = guid
    return instantiate_fmu(unzipdir, md, fmi_type, debug_logging=debug_logging,
                           logger=log.logger(version) if log else None)


def initialize(fmu, version):
    if version == 2:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
    else:
        fmu.enterInitializationMode(startTime=0.0)
        fmu.exitInitializationMode()


def set_real(fmu, version, vrs, values):
    return fmu.setReal(vrs, values) if version == 2 else fmu.setFloat64(vrs, values)


def get_real(fmu, version, vrs):
    return fmu.getReal(vrs) if version == 2 else fmu.getFloat64(vrs)


# ---------------------------------------------------------------- build


def test_build_writes_both_fmus_with_binary_and_sources(fmus):
    fmi2_platform, fmi3_platform = fmu_build.platform_dirs()
    expected = {
        2: {f"binaries/{fmi2_platform}/{BINARY}", "modelDescription.xml",
            "sources/config.h", "sources/model.h", "sources/model.c", "sources/fmi2Functions.c"},
        3: {f"binaries/{fmi3_platform}/{BINARY}", "modelDescription.xml", "sources/buildDescription.xml",
            "sources/config.h", "sources/model.h", "sources/model.c", "sources/fmi3Functions.c"},
    }
    for version in VERSIONS:
        assert fmus[version].name == f"odometry_fmi{version}.fmu"
        with zipfile.ZipFile(fmus[version]) as zf:
            names = set(zf.namelist())
        assert names == expected[version]  # in particular no FMI headers in sources/


@pytest.mark.slow            # gcc, both FMUs again
def test_build_is_deterministic(fmus, tmp_path):
    again = fmu_build.build_fmus(tmp_path)
    for version in VERSIONS:
        assert again[f"fmi{version}"].read_bytes() == fmus[version].read_bytes()


@pytest.mark.slow            # gcc, every FMU of fmus/ in a process of its own
def test_cli_prints_paths(tmp_path):
    result = run([sys.executable, "-m", "fmus.build", "--out", str(tmp_path)],
                 cwd=Path(fmu_build.__file__).resolve().parents[1])
    assert result.returncode == 0, result.stderr
    paths = result.stdout.split()
    assert paths[:2] == [str(tmp_path / "odometry_fmi2.fmu"), str(tmp_path / "odometry_fmi3.fmu")]
    # then the test models of fmus/models (docs/fmu.md)
    assert paths[2:] == [str(tmp_path / fmu_build.fmu_name(m, v)) for m in fmu_build.TEST_MODELS
                         for v in fmu_build.model_versions(m)]


def test_missing_compiler_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    with pytest.raises(fmu_build.FmuBuildError, match="no C compiler found: install gcc or set CC"):
        fmu_build.build_fmus(tmp_path / "out")
    assert fmu_build.main(["--out", str(tmp_path / "out")]) == 1
    assert "no C compiler found: install gcc or set CC" in capsys.readouterr().err
    monkeypatch.setenv("CC", "no-such-compiler-xyz")
    with pytest.raises(fmu_build.FmuBuildError, match="no C compiler found"):
        fmu_build.build_fmus(tmp_path / "out")


@pytest.mark.parametrize("version", VERSIONS)
def test_exports_every_fmi_function_and_nothing_else(unzipped, version):
    headers = Path(fmu_build.fmi_headers_dir())
    text = (headers / f"fmi{version}Functions.h").read_text()
    names = re.findall(rf"FMI{version}_Export\s+\w+TYPE\s+(\w+)\s*;", text)
    assert len(names) == (44 if version == 2 else 75)
    platform_dir = fmu_build.platform_dirs()[version - 2]
    lib = ctypes.CDLL(os.path.join(unzipped[version], "binaries", platform_dir, BINARY))
    missing = [name for name in names if not hasattr(lib, name)]
    assert missing == []
    for internal in ("setStartValues", "calculateValues", "getFloat64", "doStep", "logError"):
        assert not hasattr(lib, internal), internal


# ---------------------------------------------------------------- validation


@pytest.mark.slow
@pytest.mark.parametrize("version", VERSIONS)
def test_fmpy_validate_finds_no_problem(fmus, version):
    assert validate_fmu(str(fmus[version])) == []
    result = run([sys.executable, "-m", "fmpy", "validate", str(fmus[version])])
    assert result.returncode == 0, result.stdout + result.stderr
    assert "No problems found." in result.stdout


@pytest.mark.parametrize("version", VERSIONS)
def test_model_description(fmus, version):
    md = read_model_description(str(fmus[version]), validate_variable_names=True, validate_model_structure=True)
    assert md.fmiVersion == f"{version}.0"
    assert md.coSimulation.modelIdentifier == md.modelExchange.modelIdentifier == "odometry"
    assert md.guid == "{88c50c21-a284-4ff3-b41a-9ebe1bbb929c}"
    variables = {v.name: v for v in md.modelVariables}
    for name, vr in VR.items():
        assert variables[name].valueReference == vr
    assert [variables[n].unit for n in ("omega_left", "omega_right", "x", "y", "theta", "v", "omega")] == \
        ["rad/s", "rad/s", "m", "m", "rad", "m/s", "rad/s"]
    assert [variables[n].causality for n in ("omega_left", "omega_right")] == ["input", "input"]
    assert {v.name for v in md.modelVariables if v.causality == "output"} == {"x", "y", "theta", "v", "omega"}
    assert {v.name: float(v.start) for v in md.modelVariables if v.causality == "parameter"} == \
        {"wheel_radius": 0.12, "wheel_separation": 0.36, "x0": 0.0, "y0": 0.0, "theta0": 0.0}
    assert [d.variable.name for d in md.derivatives] == ["der(x)", "der(y)", "der(theta)"]
    assert [d.variable.derivative.name for d in md.derivatives] == ["x", "y", "theta"]
    assert md.numberOfContinuousStates == 3


@pytest.mark.slow
@pytest.mark.parametrize("version", VERSIONS)
def test_fmutool_check_reports_compliant(fmus, version):
    pytest.importorskip("fmu_manipulation_toolbox", reason="pip install fmu-manipulation-toolbox")
    code = ("import sys; from fmu_manipulation_toolbox.cli.fmutool import fmutool; "
            "sys.argv = ['fmutool'] + sys.argv[1:]; sys.exit(fmutool())")
    result = run([sys.executable, "-c", code, "-input", str(fmus[version]), "-check"])
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    assert f"compliant with FMI-{version}.0" in output
    assert f"No semantic error against the FMI-{version} standard" in output
    assert "ERROR" not in output


# ---------------------------------------------------------------- simulation


@pytest.mark.parametrize("version", VERSIONS)
def test_cosimulation_matches_closed_form_arcs(fmus, version):
    result = simulate_fmu(str(fmus[version]), fmi_type="CoSimulation", stop_time=STOP_TIME,
                          input=input_signals(), output=["x", "y", "theta", "v", "omega"], output_interval=0.01)
    assert result["time"][-1] == pytest.approx(STOP_TIME)
    errors = max_pose_error(result)
    print(f"FMI {version} CoSimulation, h = 0.01 s: max |error| x, y, theta = {errors}")
    assert max(errors) < POSE_TOL
    # outputs v and omega follow the wheel speeds
    for t0, duration, _, _, v, w, _ in segments():
        i = np.searchsorted(result["time"], t0 + duration / 2)
        assert result["v"][i] == pytest.approx(v, abs=1e-15)
        assert result["omega"][i] == pytest.approx(w, abs=1e-15)


@pytest.mark.parametrize("version", VERSIONS)
def test_model_exchange_matches_closed_form_arcs(fmus, version):
    # CVode (BDF) with relative_tolerance 1e-12 (absolute = 1e-12 * nominal 1.0); fmpy stops and restarts
    # the solver at the input steps (the repeated times in the input table).
    result = simulate_fmu(str(fmus[version]), fmi_type="ModelExchange", solver="CVode", relative_tolerance=1e-12,
                          stop_time=STOP_TIME, input=input_signals(), output=["x", "y", "theta"],
                          output_interval=0.1)
    assert result["time"][-1] == pytest.approx(STOP_TIME)
    errors = max_pose_error(result)
    print(f"FMI {version} ModelExchange, CVode rtol 1e-12: max |error| x, y, theta = {errors}")
    assert max(errors) < POSE_TOL


@pytest.mark.parametrize("version", VERSIONS)
def test_one_large_step_is_exact(unzipped, version):
    fmu = instantiate(unzipped[version], version)
    try:
        set_real(fmu, version, [VR["x0"], VR["y0"], VR["theta0"]], [1.0, -2.0, 0.7])
        initialize(fmu, version)
        assert get_real(fmu, version, [VR["x"], VR["y"], VR["theta"]]) == [1.0, -2.0, 0.7]
        wl, wr = 3.0, 7.5
        set_real(fmu, version, [VR["omega_left"], VR["omega_right"]], [wl, wr])
        fmu.doStep(0.0, 20.0)  # 20 s in one step: omega * h = 30 rad
        v, w = body_twist(wl, wr)
        expected = arc(1.0, -2.0, 0.7, v, w, 20.0)
        assert get_real(fmu, version, [VR["x"], VR["y"], VR["theta"]]) == pytest.approx(expected, abs=1e-12)
        fmu.terminate()
    finally:
        fmu.freeInstance()


@pytest.mark.parametrize("version", VERSIONS)
def test_near_zero_yaw_rate_uses_the_stable_form(unzipped, version):
    fmu = instantiate(unzipped[version], version)
    try:
        initialize(fmu, version)
        wl = 5.0
        wr = wl + 1e-9  # omega = r * 1e-9 / d ~ 3.3e-10 rad/s: omega * h / 2 < 1e-9
        set_real(fmu, version, [VR["omega_left"], VR["omega_right"]], [wl, wr])
        for i in range(1000):
            fmu.doStep(i * 0.01, 0.01)
        v, w = body_twist(wl, wr)
        t = 10.0
        # second-order expansion of the arc in omega (the remainder is ~ v omega^2 t^3 < 1e-17 m)
        expected = (v * t, v * w * t * t / 2, w * t)
        assert get_real(fmu, version, [VR["x"], VR["y"], VR["theta"]]) == pytest.approx(expected, abs=1e-12)
    finally:
        fmu.freeInstance()


@pytest.mark.parametrize("version", VERSIONS)
def test_cosimulation_step_matches_the_python_reference_odometry(unzipped, version):
    odometry = pytest.importorskip("controllers.odometry", reason="the project's Python reference odometry")
    rng = np.random.default_rng(7)
    h, n = 0.02, 3000
    speeds = np.repeat(rng.uniform(-8.0, 8.0, size=(n // 50, 2)), 50, axis=0)  # changes every second
    speeds[500:550, 1] = speeds[500:550, 0]           # a straight piece
    speeds[900:950, 1] = -speeds[900:950, 0]          # a spin in place
    fmu = instantiate(unzipped[version], version)
    try:
        initialize(fmu, version)
        pose = (0.0, 0.0, 0.0)
        worst = 0.0
        for i, (wl, wr) in enumerate(speeds):
            set_real(fmu, version, [VR["omega_left"], VR["omega_right"]], [wl, wr])
            fmu.doStep(i * h, h)
            pose = odometry.arc_step(*pose, dl=wl * h, dr=wr * h, r=R, d=D)
            got = get_real(fmu, version, [VR["x"], VR["y"], VR["theta"]])
            worst = max(worst, *(abs(a - b) for a, b in zip(got, pose)))
        print(f"FMI {version}: max |FMU - controllers.odometry.arc_step| over {n} steps = {worst:.3g}")
        assert worst < 1e-12
    finally:
        fmu.freeInstance()


def test_libcosim_gives_the_same_trajectory(fmus):
    pytest.importorskip("libcosimpy", reason="pip install libcosimpy (DNV libcosim, FMI 2 only)")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.WARNING)
    step_ns = 10_000_000  # 10 ms
    execution = CosimExecution.from_step_size(step_ns)
    slave = CosimLocalSlave(fmu_path=str(fmus[2]), instance_name="odometry")
    index = execution.add_local_slave(slave)
    manipulator = CosimManipulator.create_override()
    execution.add_manipulator(manipulator)
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)

    times, poses = [], []
    for t0, duration, wl, wr, *_ in segments():
        assert manipulator.slave_real_values(index, [VR["omega_left"], VR["omega_right"]], [wl, wr])
        for k in range(1, int(duration) + 1):  # sample every second
            assert execution.step(100)
            times.append(t0 + k)
            poses.append(observer.last_real_values(index, [VR["x"], VR["y"], VR["theta"]]))
    assert execution.status().current_time == int(STOP_TIME * 1e9)
    errors = np.max(np.abs(np.array(poses) - reference_pose(times)), axis=0)
    print(f"libcosim FMI 2 CoSimulation, h = 0.01 s: max |error| x, y, theta = {errors}")
    assert np.max(errors) < POSE_TOL


# ---------------------------------------------------------------- rebuild from sources


def strip_binaries(src: Path, dst: Path) -> None:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            if not item.filename.startswith("binaries/"):
                zout.writestr(item, zin.read(item.filename))


@pytest.mark.slow            # cmake + the C compiler
@pytest.mark.parametrize("version", VERSIONS)
def test_fmpy_compile_rebuilds_from_sources(fmus, version, tmp_path):
    if not shutil.which("cmake", path=os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", "")):
        why = "`fmpy compile` needs cmake (pip install cmake; the [test] extra has it)"
        if CI:
            pytest.fail(why)
        pytest.skip(why)
    rebuilt = tmp_path / fmus[version].name
    strip_binaries(fmus[version], rebuilt)
    with zipfile.ZipFile(rebuilt) as zf:
        assert not [n for n in zf.namelist() if n.startswith("binaries/")]
    # fmpy compile: CMake with fmpy/c-code (the FMI headers) and sources/ on the include path
    result = run([sys.executable, "-m", "fmpy", "compile", str(rebuilt)])
    assert result.returncode == 0, result.stdout + result.stderr
    with zipfile.ZipFile(rebuilt) as zf:
        assert f"binaries/{fmu_build.platform_dirs()[version - 2]}/{BINARY}" in zf.namelist()
    assert validate_fmu(str(rebuilt)) == []
    kwargs = dict(fmi_type="CoSimulation", stop_time=STOP_TIME, input=input_signals(),
                  output=["x", "y", "theta"], output_interval=0.01)
    original = simulate_fmu(str(fmus[version]), **kwargs)
    again = simulate_fmu(str(rebuilt), **kwargs)
    for name in ("x", "y", "theta"):
        # identical up to the compiler's freedom (optimisation level, FMA contraction on some targets)
        assert np.max(np.abs(again[name] - original[name])) <= 1e-12
    assert max(max_pose_error(again)) < POSE_TOL


# ---------------------------------------------------------------- errors and FMU state


@pytest.mark.parametrize("version", VERSIONS)
def test_wrong_guid_fails_cleanly(unzipped, version):
    log = LogCapture()
    with pytest.raises(Exception, match="[Ff]ailed to instantiate"):
        instantiate(unzipped[version], version, log=log, guid="{00000000-0000-0000-0000-000000000000}")
    word = "GUID" if version == 2 else "instantiationToken"
    assert any(status == 3 and f"wrong {word}" in message and "{00000000-" in message
               for status, message in log.messages), log.messages


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("fmi_type", ["CoSimulation", "ModelExchange"])
def test_nan_input_is_an_error_naming_the_variable(unzipped, version, fmi_type):
    log = LogCapture()
    fmu = instantiate(unzipped[version], version, fmi_type, log=log)
    try:
        initialize(fmu, version)
        with pytest.raises(FMICallException) as info:
            set_real(fmu, version, [VR["omega_left"]], [float("nan")])
        assert info.value.status == 3
        assert 'Variable "omega_left" (value reference 1): value nan is not finite.' in log.text()
        with pytest.raises(FMICallException):
            set_real(fmu, version, [VR["omega_right"]], [float("inf")])
        assert '"omega_right"' in log.text()
        # the rejected value left the instance as it was
        assert get_real(fmu, version, [VR["omega_left"], VR["omega_right"]]) == [0.0, 0.0]
        set_real(fmu, version, [VR["omega_left"]], [1.0])
    finally:
        fmu.freeInstance()


@pytest.mark.parametrize("version", VERSIONS)
def test_bad_value_reference_and_wrong_state_are_errors(unzipped, version):
    log = LogCapture()
    fmu = instantiate(unzipped[version], version, log=log)
    try:
        with pytest.raises(FMICallException):  # before initialization
            fmu.doStep(0.0, 0.01)
        assert f"fmi{version}DoStep() must not be called in state Instantiated." in log.text()
        initialize(fmu, version)
        with pytest.raises(FMICallException):
            get_real(fmu, version, [99])
        assert "Unknown value reference 99." in log.text()
        with pytest.raises(FMICallException):
            set_real(fmu, version, [VR["wheel_radius"]], [0.2])  # fixed parameter after initialization
        assert 'Variable "wheel_radius" (value reference 3) is a fixed parameter' in log.text()
        with pytest.raises(FMICallException):
            set_real(fmu, version, [VR["x"]], [1.0])  # an output
        assert 'Variable "x" (value reference 8) cannot be set.' in log.text()
        with pytest.raises(FMICallException):
            fmu.doStep(5.0, 0.01)  # not the FMU's current time
        assert "does not match" in log.text()
        with pytest.raises(FMICallException):
            if version == 2:
                fmu.fmi2GetDirectionalDerivative(fmu.component, None, 0, None, 0, None, None)
            else:
                fmu.fmi3GetDirectionalDerivative(fmu.component, None, 0, None, 0, None, 0, None, 0)
        assert "is not supported by this FMU" in log.text()
        fmu.doStep(0.0, 0.01)  # still usable
    finally:
        fmu.freeInstance()


def test_invalid_parameter_value_is_an_error(unzipped):
    log = LogCapture()
    fmu = instantiate(unzipped[2], 2, log=log)
    try:
        with pytest.raises(FMICallException):
            fmu.setReal([VR["wheel_separation"]], [0.0])
        assert 'Variable "wheel_separation" (value reference 4): value 0 must be > 0.' in log.text()
    finally:
        fmu.freeInstance()


@pytest.mark.parametrize("version", VERSIONS)
def test_interface_type_is_checked(unzipped, version):
    log = LogCapture()
    fmu = instantiate(unzipped[version], version, "ModelExchange", log=log)
    try:
        initialize(fmu, version)
        do_step = getattr(fmu.dll, f"fmi{version}DoStep")  # not bound by fmpy for Model Exchange
        do_step.restype = ctypes.c_int
        do_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                            ctypes.c_int if version == 2 else ctypes.c_bool] + [ctypes.c_void_p] * (4 if version == 3 else 0)
        assert do_step(fmu.component, 0.0, 0.01, 1, *([None] * (4 if version == 3 else 0))) == 3
        assert f"fmi{version}DoStep() is only available for Co-Simulation." in log.text()
    finally:
        fmu.freeInstance()


@pytest.mark.parametrize("version", VERSIONS)
def test_debug_logging_reports_mode_changes(unzipped, version):
    log = LogCapture()
    fmu = instantiate(unzipped[version], version, log=log, debug_logging=True)
    try:
        initialize(fmu, version)
        fmu.terminate()
    finally:
        fmu.freeInstance()
    assert (0, f"fmi{version}ExitInitializationMode()") in log.messages
    assert (0, f"fmi{version}Terminate()") in log.messages


def test_fmi3_scheduled_execution_is_refused(unzipped):
    from fmpy.fmi3 import FMU3ScheduledExecution

    log = LogCapture()
    md = read_model_description(unzipped[3])
    fmu = FMU3ScheduledExecution(guid=md.guid, unzipDirectory=unzipped[3], modelIdentifier="odometry")
    with pytest.raises(Exception, match="[Ff]ailed to instantiate"):
        fmu.instantiate(logMessage=log.fmi3)
    assert "Scheduled Execution is not supported by this FMU." in log.text()
    fmu.freeLibrary()


@pytest.mark.parametrize("version", VERSIONS)
def test_fmu_state_roundtrip(unzipped, version):
    fmu = instantiate(unzipped[version], version)
    try:
        initialize(fmu, version)
        set_real(fmu, version, [VR["omega_left"], VR["omega_right"]], [2.0, 3.0])
        fmu.doStep(0.0, 1.0)
        if version == 2:
            get_state, set_state, free_state = fmu.getFMUstate, fmu.setFMUstate, fmu.freeFMUstate
            serialize, deserialize = fmu.serializeFMUstate, fmu.deSerializeFMUstate
        else:
            get_state, set_state, free_state = fmu.getFMUState, fmu.setFMUState, fmu.freeFMUState
            serialize, deserialize = fmu.serializeFMUState, fmu.deserializeFMUState
        state = get_state()
        blob = serialize(state)
        fmu.doStep(1.0, 1.0)
        after = get_real(fmu, version, [VR["x"], VR["y"], VR["theta"]])
        set_state(state)
        fmu.doStep(1.0, 1.0)
        assert get_real(fmu, version, [VR["x"], VR["y"], VR["theta"]]) == after
        restored = deserialize(blob)
        set_state(restored)
        fmu.doStep(1.0, 1.0)
        assert get_real(fmu, version, [VR["x"], VR["y"], VR["theta"]]) == after
        free_state(state)
        free_state(restored)
    finally:
        fmu.freeInstance()


# ---------------------------------------------------------------- many small steps
# (what a step costs is measured by `diffbot bench` (fmus/bench.py), not asserted here)


@pytest.mark.parametrize("version", VERSIONS)
def test_twenty_thousand_fmpy_steps_stay_on_the_closed_form_arc(unzipped, version):
    fmu = instantiate(unzipped[version], version)
    try:
        initialize(fmu, version)
        n, h = 20000, 0.01
        inputs, outputs = [VR["omega_left"], VR["omega_right"]], [VR["x"], VR["y"], VR["theta"]]
        for i in range(n):
            set_real(fmu, version, inputs, [4.0, 4.5])
            fmu.doStep(i * h, h)
        pose = get_real(fmu, version, outputs)
        want = arc(0.0, 0.0, 0.0, *body_twist(4.0, 4.5), n * h)     # 200 s, 5.3 turns
        assert max(abs(a - b) for a, b in zip(pose, want)) < 1e-8, (pose, want)
    finally:
        fmu.freeInstance()
