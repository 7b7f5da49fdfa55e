"""The DART plant exported as a co-simulation FMU (``diffbot fmu export-plant``): FMI
masters load it and drive the robot, its lidar is the plant's scan to the bit, it leaks
nothing over many instances, and a missing Python environment is a clean FMI error."""
from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from fmus.build import fmi_headers_dir, find_c_compiler

# slow: each test exports (compiles) and runs the plant; xdist_group: with
# tests/network/test_netns.py, on the worker that runs conftest.square_seed0
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("square_seed0")]

ROOT = Path(__file__).resolve().parents[2]
ROBOT = "robot1"
TICK_S = 0.02
RAMP_M = 0.2 ** 2 / (2 * 2.0)          # reaching 0.2 m/s at living_room's 2 m/s^2 limit


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    out = tmp_path_factory.mktemp("plant_fmu")
    paths = {}
    for fmi in (3, 2):
        result = subprocess.run([sys.executable, "-m", "diffbot.cli", "fmu", "export-plant",
                                 "--fmi", str(fmi), "--out", str(out / f"robot{fmi}.fmu")],
                                cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, result.stderr
        paths[fmi] = Path(result.stdout.strip())
    return paths


#: the folders Slave extracted FMUs to during the running test (removed after it)
_EXTRACTED: list[str] = []


@pytest.fixture(autouse=True)
def _remove_extracted():
    yield
    while _EXTRACTED:
        shutil.rmtree(_EXTRACTED.pop(), ignore_errors=True)


class Slave:
    """An fmpy instance of the plant FMU with its log and its variables by name."""

    def __init__(self, path: Path, fmi: int, unzipped: str | None = None) -> None:
        from fmpy import extract, read_model_description
        self.md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.dir = unzipped or extract(str(path))
        if unzipped is None:
            _EXTRACTED.append(self.dir)
        self.fmi, self.log, self.t = fmi, [], 0.0
        kw = dict(guid=self.md.guid, unzipDirectory=self.dir,
                  modelIdentifier=self.md.coSimulation.modelIdentifier,
                  instanceName="plant")
        if fmi == 3:
            from fmpy.fmi3 import FMU3Slave
            self.fmu = FMU3Slave(**kw)
        else:
            from fmpy.fmi2 import FMU2Slave
            self.fmu = FMU2Slave(**kw)

    def instantiate(self) -> None:
        if self.fmi == 3:
            self.fmu.instantiate(logMessage=lambda env, status, cat, msg:
                                 self.log.append(msg.decode()))
        else:
            self.fmu.instantiate()

    def start(self, **params) -> "Slave":
        self.instantiate()
        if self.fmi == 2:
            self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        for name, value in params.items():
            self.set(name, value)
        self.fmu.exitInitializationMode()
        return self

    def set(self, name: str, value) -> None:
        f = {bool: "Boolean", int: "Int32" if self.fmi == 3 else "Integer",
             float: "Float64" if self.fmi == 3 else "Real"}[type(value)]
        getattr(self.fmu, f"set{f}")([self.vr[name]], [value])

    def get(self, *names: str) -> list[float]:
        getter = self.fmu.getFloat64 if self.fmi == 3 else self.fmu.getReal
        return list(getter([self.vr[n] for n in names]))

    def step(self, seconds: float, h: float = TICK_S) -> None:
        for _ in range(int(round(seconds / h))):
            self.fmu.doStep(self.t, h)
            self.t += h

    def free(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()


@pytest.mark.parametrize("fmi", [3, 2])
def test_fmpy_drives_the_robot_0_40_m_in_2_s(fmus, fmi):
    from fmpy import simulate_fmu
    out = [f"{ROBOT}.{k}" for k in ("x", "y", "odom_x", "odom_y")]
    r = simulate_fmu(str(fmus[fmi]), stop_time=2.0, output_interval=TICK_S,
                     start_values={f"{ROBOT}.v": 0.2}, output=out)
    x, y, ox, oy = (r[k] for k in out)
    assert r["time"][-1] == pytest.approx(2.0)
    moved = math.hypot(x[-1] - x[0], y[-1] - y[0])
    print(f"FMI {fmi}: 2 s at 0.2 m/s: {moved:.4f} m (the speed ramp costs {RAMP_M:.3f} m)")
    assert 0.40 * 0.98 - RAMP_M <= moved <= 0.40 * 1.02
    assert abs(y[-1] - y[0]) < 0.005
    # odometry from the (noise-free) encoders follows the true pose within wheel slip
    assert math.hypot(ox[-1] - x[-1], oy[-1] - y[-1]) < 0.01


def plant_scan(ticks: int, v: float, seed: int = 0) -> np.ndarray:
    """The plant's own scan (plant.tick.Tick, noise off) after ``ticks`` ticks at ``v``."""
    from bus.controller import Twist
    from fmus.plant_fmu import silence
    from plant.tick import Tick
    from plant.world import load_world
    spec = load_world("living_room")
    spec.seed = seed
    silence(spec)
    tick = Tick(spec, disabled=("camera",))
    for _ in range(ticks):
        list(tick.messages())
        tick.drive(ROBOT, Twist(v, 0.0))
        tick.step()
    scans = [m for robot, topic, m in tick.messages() if topic == "scan" and robot == ROBOT]
    assert scans, "the lidar is due at this tick"
    return np.asarray(scans[0].ranges, dtype=np.float64)


@pytest.mark.parametrize("fmi", [3, 2])
def test_lidar_output_is_the_plants_scan_to_the_bit(fmus, fmi):
    s = Slave(fmus[fmi], fmi).start(noise=False, seed=3)
    try:
        s.set(f"{ROBOT}.v", 0.3)
        s.step(1.0, h=0.1)                 # 50 ticks, in steps of five
        rays = 180
        if fmi == 3:
            scan = np.array(s.fmu.getFloat64([s.vr[f"{ROBOT}.scan"]], nValues=rays))
        else:
            scan = np.array(s.get(*(f"{ROBOT}.scan[{k + 1}]" for k in range(rays))))
    finally:
        s.free()
    ref = plant_scan(50, 0.3, seed=3)
    assert scan.shape == ref.shape == (rays,)
    assert np.isfinite(scan).all() and scan.min() > 0.1
    assert scan.tobytes() == ref.tobytes()


def test_fmpy_validate_reports_no_problem(fmus):
    from fmpy.validation import validate_fmu
    for fmi, path in fmus.items():
        assert validate_fmu(str(path)) == [], f"FMI {fmi}"
        with zipfile.ZipFile(path) as zf:
            xml = zf.read("modelDescription.xml").decode()
        assert 'needsExecutionTool="true"' in xml and "tool-coupling" in xml


def test_a_step_that_is_not_whole_ticks_is_refused_with_a_message(fmus):
    from fmpy.fmi1 import FMICallException
    s = Slave(fmus[3], 3).start()
    try:
        with pytest.raises(FMICallException):
            s.fmu.doStep(0.0, 0.03)
        assert any("not a whole number of 20 ms control ticks" in m for m in s.log), s.log
        s.step(0.04)                       # whole ticks still go
        assert s.get("time") == [pytest.approx(0.04)]
    finally:
        s.free()


def test_reset_starts_the_same_run_again(fmus):
    s = Slave(fmus[3], 3).start()
    try:
        s.set(f"{ROBOT}.v", 0.2)
        s.set(f"{ROBOT}.w", 0.5)
        s.step(0.5)
        first = s.get(f"{ROBOT}.x", f"{ROBOT}.y", f"{ROBOT}.yaw")
        s.fmu.reset()
        s.t = 0.0
        s.fmu.enterInitializationMode()
        s.fmu.exitInitializationMode()
        assert s.get(f"{ROBOT}.x", f"{ROBOT}.y") == [-1.0, -1.0]   # the start pose again
        s.set(f"{ROBOT}.v", 0.2)
        s.set(f"{ROBOT}.w", 0.5)
        s.step(0.5)
        assert s.get(f"{ROBOT}.x", f"{ROBOT}.y", f"{ROBOT}.yaw") == first
    finally:
        s.free()


def test_start_pose_parameters_place_the_robot(fmus):
    s = Slave(fmus[3], 3).start(**{f"{ROBOT}.x0": 0.5, f"{ROBOT}.y0": 0.25,
                                   f"{ROBOT}.yaw0": math.pi / 2})
    try:
        x, y, yaw, ox, oy, oyaw = s.get(*(f"{ROBOT}.{k}" for k in
                                          ("x", "y", "yaw", "odom_x", "odom_y", "odom_yaw")))
        assert (x, y, ox, oy, oyaw) == pytest.approx((0.5, 0.25, 0.5, 0.25, math.pi / 2), abs=1e-6)
        assert yaw == pytest.approx(math.pi / 2, abs=1e-6)
    finally:
        s.free()


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


@pytest.mark.timeout(600)
def test_instantiate_and_free_100_times_leaves_nothing_behind(fmus):
    from fmpy import extract
    unzipped = extract(str(fmus[3]))

    def cycle():
        s = Slave(fmus[3], 3, unzipped).start()
        s.set(f"{ROBOT}.v", 0.2)
        s.step(0.04)
        s.free()

    for _ in range(5):
        cycle()                            # imports, caches, allocator pools
    rss, fds, threads = _rss_mb(), os.listdir("/proc/self/fd"), os.listdir("/proc/self/task")
    children = _children()
    for _ in range(100):
        cycle()
    grown = _rss_mb() - rss
    print(f"100 instantiate/initialize/step/free cycles: RSS {rss:.1f} MB -> +{grown:.2f} MB")
    assert grown < 8.0
    assert len(os.listdir("/proc/self/fd")) == len(fds)
    # no thread of the FMU left (another test's thread in this worker may end meanwhile)
    assert set(os.listdir("/proc/self/task")) <= set(threads)
    assert _children() == children
    shutil.rmtree(unzipped, ignore_errors=True)


def test_a_freed_instance_leaves_nothing_to_the_garbage_collector(fmus):
    """Freeing an instance frees its world by reference counting: no object of the plant is
    left in a reference cycle, so freeing needs no gc.collect() of the master's whole
    process (it took ~25 ms a free in a test process, more in a big master)."""
    import gc
    from fmpy import extract
    unzipped = extract(str(fmus[3]))
    Slave(fmus[3], 3, unzipped).start().free()          # imports, caches
    gc.collect()
    gc.disable()
    try:
        s = Slave(fmus[3], 3, unzipped).start()
        s.set(f"{ROBOT}.v", 0.2)
        s.step(0.4)
        s.free()
        del s
        gc.set_debug(gc.DEBUG_SAVEALL)
        gc.collect()
        ours = [type(o).__module__ + "." + type(o).__qualname__ for o in gc.garbage
                if type(o).__module__.split(".")[0] in ("plant", "fmus", "bus", "dartpy")]
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
        gc.enable()
    shutil.rmtree(unzipped, ignore_errors=True)
    assert not ours, sorted(set(ours))


def _children() -> set[str]:
    me = str(os.getpid())
    out = set()
    for pid in os.listdir("/proc"):
        try:
            with open(f"/proc/{pid}/stat") as f:
                if pid.isdigit() and f.read().rsplit(")", 1)[1].split()[1] == me:
                    out.add(pid)
        except OSError:
            continue
    return out


def _with_cfg(path: Path, dest: Path, **cfg) -> Path:
    """A copy of the FMU with these resources/plant.cfg entries."""
    with zipfile.ZipFile(path) as zin, zipfile.ZipFile(dest, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "resources/plant.cfg":
                lines = dict(line.split("=", 1) for line in data.decode().splitlines())
                lines.update(cfg)
                data = "".join(f"{k}={v}\n" for k, v in lines.items()).encode()
            zout.writestr(item, data)
    return dest


@pytest.fixture(scope="module")
def c_host(tmp_path_factory):
    exe = tmp_path_factory.mktemp("host") / "fmi3_host"
    subprocess.run([*find_c_compiler(), "-std=gnu99", "-O1", "-I", str(fmi_headers_dir()),
                    str(ROOT / "tests" / "support" / "fmi3_host.c"), "-o", str(exe), "-ldl"],
                   check=True, timeout=120)
    return exe


def _run_c_host(c_host, fmu: Path, tmp_path: Path, steps: int, python: str = sys.executable):
    from fmpy import read_model_description
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    d = tmp_path / fmu.stem
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(d)
    binary = next((d / "binaries").glob("*/diffbot_plant.so"))
    return subprocess.run([str(c_host), str(binary), str(d / "resources"), md.guid,
                           str(vr[f"{ROBOT}.v"]), str(vr[f"{ROBOT}.x"]), str(vr[f"{ROBOT}.y"]),
                           "0.2", str(steps)], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "DIFFBOT_FMU_PYTHON": python})


def test_a_c_master_without_python_runs_the_fmu(fmus, c_host, tmp_path):
    """The tool-coupling path proper: the shim loads libpython into a host that has none."""
    result = _run_c_host(c_host, fmus[3], tmp_path, 100)
    assert result.returncode == 0, result.stdout + result.stderr
    x, y = map(float, result.stdout.split()[-2:])
    s = Slave(fmus[3], 3).start()
    try:
        s.set(f"{ROBOT}.v", 0.2)
        s.step(2.0)
        assert [x, y] == s.get(f"{ROBOT}.x", f"{ROBOT}.y")   # the same run, bit for bit
    finally:
        s.free()


def test_a_c_master_without_a_usable_python_gets_a_logged_error(fmus, c_host, tmp_path):
    """The Python chosen is named with the rule that chose it, and what is wrong with it."""
    gone = "/nonexistent/venv/bin/python"
    result = _run_c_host(c_host, fmus[3], tmp_path, 1, python=gone)
    assert result.returncode == 3, result.stdout + result.stderr
    assert "named by $DIFFBOT_FMU_PYTHON: " + gone + ") is missing" in result.stdout, \
        result.stdout
    bound = _with_cfg(fmus[3], tmp_path / "bound.fmu", python=gone)   # a bound export, moved
    result = _run_c_host(c_host, bound, tmp_path, 1, python="")
    assert result.returncode == 3, result.stdout + result.stderr
    assert "exported bound to: " + gone + ") is missing" in result.stdout, result.stdout


def test_libcosim_runs_the_fmi2_plant(fmus):
    pytest.importorskip("libcosimpy", reason="pip install libcosimpy (DNV libcosim, FMI 2 only)")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave
    from fmpy import read_model_description
    vr = {v.name: v.valueReference for v in read_model_description(str(fmus[2])).modelVariables}
    log_output_level(CosimLogLevel.WARNING)
    execution = CosimExecution.from_step_size(int(TICK_S * 1e9))
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=str(fmus[2]), instance_name="plant"))
    manipulator = CosimManipulator.create_override()
    execution.add_manipulator(manipulator)
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    xy = [vr[f"{ROBOT}.x"], vr[f"{ROBOT}.y"]]
    assert manipulator.slave_real_values(index, [vr[f"{ROBOT}.v"]], [0.2])
    assert execution.step(1)
    start = observer.last_real_values(index, xy)
    assert execution.step(100)
    end = observer.last_real_values(index, xy)
    moved = math.hypot(end[0] - start[0], end[1] - start[1])
    print(f"libcosim FMI 2: 100 ticks at 0.2 m/s: {moved:.4f} m")
    assert 0.40 * 0.98 - RAMP_M <= moved <= 0.40 * 1.02


def _ecospy():
    try:
        import ecospy
    except (ImportError, OSError) as e:      # its binary needs libtbb.so.12 (apt: libtbb12)
        pytest.skip(f"ecospy cannot load here: {e}")
    return ecospy


@pytest.mark.parametrize("fmi", [3, 2])
def test_ecos_runs_the_plant(fmus, fmi):
    ecospy = _ecospy()
    with ecospy.EcosSimulationStructure() as ss:
        ss.add_model("plant", str(fmus[fmi]))
        with ecospy.EcosSimulation(structure=ss, step_size=TICK_S) as sim:
            sim.set_real(f"plant::{ROBOT}.v", 0.2)
            sim.init()
            start = [sim.get_real(f"plant::{ROBOT}.{k}") for k in "xy"]
            sim.step(100)
            end = [sim.get_real(f"plant::{ROBOT}.{k}") for k in "xy"]
            assert sim.get_time() == pytest.approx(2.0)
            sim.terminate()
    moved = math.hypot(end[0] - start[0], end[1] - start[1])
    print(f"Ecos FMI {fmi}: 2 s at 0.2 m/s: {moved:.4f} m")
    assert 0.40 * 0.98 - RAMP_M <= moved <= 0.40 * 1.02


@pytest.mark.timeout(900)
def test_the_ssp_square_has_the_odometry_error_of_diffbot_run_square(fmus, tmp_path,
                                                                     square_seed0):
    """The study's square as an SSP (plant FMU -> odometry FMU, the square path as the
    master's logic) under libcosim, against the same square on the bus."""
    import json
    sys.path.insert(0, str(ROOT / "examples" / "fmi"))
    try:
        from plant_square import square
    finally:
        sys.path.remove(str(ROOT / "examples" / "fmi"))
    odometry = ROOT / "fmus" / "build" / "odometry_fmi2.fmu"
    if not odometry.exists():
        from fmus.build import build_fmu
        odometry = build_fmu(2, tmp_path)
    ssp = square(str(fmus[2]), "libcosim", str(tmp_path / "square.ssp"), str(odometry))
    # `diffbot run square` (seed 0, the default; its recorder changes no metric)
    ref = square_seed0["summary"]["metrics"][ROBOT]
    err, length = ref["final_odom_error_m"], ref["path_length_m"]
    print(f"square: SSP under libcosim {ssp}; diffbot run square: error {err:.5f} m, "
          f"path {length:.3f} m")
    assert ssp["path_length_m"] == pytest.approx(length, rel=0.01)
    assert ssp["final_odom_error_m"] < 0.01
    assert abs(ssp["final_odom_error_m"] - err) < 0.001


def test_outputs_stay_readable_after_terminate_and_two_instances_do_not_mix(fmus):
    a, b = Slave(fmus[3], 3).start(), Slave(fmus[3], 3).start()
    try:
        a.set(f"{ROBOT}.v", 0.2)
        b.set(f"{ROBOT}.w", 0.5)          # b turns in place while a drives straight
        for _ in range(10):
            a.step(0.02)
            b.step(0.02)
        ax, ayaw = a.get(f"{ROBOT}.x", f"{ROBOT}.yaw")
        bx, byaw = b.get(f"{ROBOT}.x", f"{ROBOT}.yaw")
        assert ax > -0.97 and abs(ayaw) < 1e-3
        assert abs(bx + 1.0) < 1e-3 and byaw > 0.05
        a.fmu.terminate()
        assert a.get(f"{ROBOT}.x", f"{ROBOT}.yaw") == [ax, ayaw]
        assert list(a.fmu.getBoolean([a.vr[f"{ROBOT}.contact"]])) == [False]
        a.fmu.freeInstance()
    finally:
        b.free()


def test_encoder_noise_is_the_plants_draw_for_draw(tmp_path):
    """With the world's noise on, the readings are the plant's at the same seed; off, exact."""
    from bus.controller import Twist
    from plant.tick import Tick
    from plant.world import load_world
    noisy = "robots.robot1.encoders.noise={std = 0.01}"
    path = tmp_path / "noisy.fmu"
    result = subprocess.run([sys.executable, "-m", "diffbot.cli", "fmu", "export-plant",
                             "--set", noisy, "--out", str(path)], cwd=ROOT,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    names = (f"{ROBOT}.wheel_angle_left", f"{ROBOT}.wheel_angle_right")
    got = {}
    for noise in (True, False):
        s = Slave(path, 3).start(seed=5, noise=noise)
        try:
            s.set(f"{ROBOT}.v", 0.2)
            s.step(0.2)
            got[noise] = s.get(*names)
        finally:
            s.free()
    spec = load_world("living_room", [noisy])
    spec.seed = 5
    tick = Tick(spec, disabled=("camera",))
    for _ in range(10):
        list(tick.messages())
        tick.drive(ROBOT, Twist(0.2, 0.0))
        tick.step()
    joints = [m for r, t, m in tick.messages() if r == ROBOT and t == "joint_states"][0]
    assert got[True] == [float(p) for p in joints.position]
    exact = tick.sim.state(ROBOT).enc_pos
    assert got[False] == pytest.approx(list(exact), abs=1e-4)   # no noise: the true angles
    assert got[True] != pytest.approx(got[False], abs=1e-4)


def test_export_refuses_an_unknown_robot_with_a_message(capsys):
    from fmus.plant_export import main
    assert main(["--robots", "robot9", "--out", "/nonexistent/x.fmu"]) == 1
    assert "has no robot 'robot9'" in capsys.readouterr().err
