"""What a master sees of the plant FMU beyond stepping it: that it names no path of the
exporting machine and checks the package version it runs on; its FMU state (a rollback steps
again to the bit, FMI 3 and 2; a serialized state goes into another instance, not into
another FMU); its model description (ranges, metadata, documentation, the scan counter, the
scan as scalars for FMI 3). On an FMU with every noise stream of robot1 on."""
from __future__ import annotations

import csv
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from tests.fmus.test_plant_fmu import (ROBOT, ROOT, TICK_S, Slave, _remove_extracted,  # noqa: F401
                                  _with_cfg)

# slow: the module exports (compiles) the FMU and runs it
pytestmark = [pytest.mark.slow, pytest.mark.background]


def _sets() -> list[str]:
    return [a for x in NOISY for a in ("--set", x)]


#: every noise stream of robot1 on: encoder readings, lidar ranges, commanded wheel speeds
NOISY = ["robots.robot1.encoders.noise={std = 0.01}", "robots.robot1.lidar.noise={std = 0.02}",
         "robots.robot1.motion.command_noise_std_radps=0.05"]


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    """The plant FMU (FMI 3 and 2) with every noise stream of robot1 on."""
    out = tmp_path_factory.mktemp("noisy_plant_fmu")
    paths = {}
    for fmi in (3, 2):
        result = subprocess.run([sys.executable, "-m", "diffbot.cli", "fmu", "export-plant",
                                 "--fmi", str(fmi), *_sets(), "--out", str(out / f"noisy{fmi}.fmu")],
                                cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, result.stderr
        paths[fmi] = Path(result.stdout.strip())
    return paths


def test_no_path_of_this_machine_is_inside_the_fmu(fmus):
    """It travels: neither its files nor its binary name the clone, the venv or libpython."""
    here = [str(ROOT), sys.prefix, sys.base_prefix, os.path.realpath(sys.executable)]
    with zipfile.ZipFile(fmus[3]) as zf:
        for name in zf.namelist():
            data = zf.read(name)
            assert not any(h.encode() in data for h in here), (name, here)
        cfg = zf.read("resources/plant.cfg").decode()
    assert cfg.splitlines() == ["package=diffbot-cosim", "package_version=0.1.0"], cfg


def test_an_incompatible_package_version_is_a_clean_fmi_error(fmus, tmp_path):
    """The host's Python has diffbot-cosim 0.1.x; an FMU exported with 9.9 says what it needs."""
    other = _with_cfg(fmus[3], tmp_path / "other.fmu", package_version="9.9.0")
    s = Slave(other, 3)
    with pytest.raises(Exception, match="Failed to instantiate"):
        s.instantiate()
    assert any("exported with 9.9.0 and needs 9.9.x" in m and "host's own Python" in m
               for m in s.log), s.log


def _state_calls(s: Slave):
    """(get, set, free, serialize, deserialize) of fmpy's FMI 3 or FMI 2 slave."""
    f, v = s.fmu, "State" if s.fmi == 3 else "state"
    return (getattr(f, f"getFMU{v}"), getattr(f, f"setFMU{v}"), getattr(f, f"freeFMU{v}"),
            getattr(f, f"serializeFMU{v}"),
            getattr(f, "deserializeFMUState" if s.fmi == 3 else "deSerializeFMUstate"))


@pytest.mark.parametrize("fmi", [3, 2])
def test_a_rollback_steps_again_to_the_bit(fmus, fmi):
    """getFMUState, 20 steps, setFMUState and the same 20 steps: the same outputs to the bit
    (pose, odometry, noisy encoder readings, noisy lidar, contact; the commands' noise on);
    so too from the state serialized and deserialized into a second instance that never
    ran (started with another seed and the noise off: the state brings its own)."""
    s = Slave(fmus[fmi], fmi).start(seed=7)
    get_state, set_state, free_state, serialize, deserialize = _state_calls(s)
    outs = [v for v in s.md.modelVariables if v.causality == "output"]
    floats = [v.valueReference for v in outs if v.type in ("Float64", "Real") and not v.dimensions]
    flags = [v.valueReference for v in outs if v.type == "Boolean"]
    arrays = [(v.valueReference, int(v.dimensions[0].start)) for v in outs if v.dimensions]
    assert len(floats) > 100 if fmi == 2 else arrays, "the scan is among the outputs"
    get = s.fmu.getFloat64 if fmi == 3 else s.fmu.getReal
    setter = s.fmu.setFloat64 if fmi == 3 else s.fmu.setReal

    def run(slave, t0: float) -> list:
        seen = []
        for k in range(20):        # a turn that changes each tick: the limiters ramp
            setter([s.vr[f"{ROBOT}.v"], s.vr[f"{ROBOT}.w"]], [0.4, 0.8 - 0.1 * k])
            slave.fmu.doStep(t0 + k * TICK_S, TICK_S)
            seen.append((list(get(floats)), list(slave.fmu.getBoolean(flags)),
                         [list(get([vr], nValues=n)) for vr, n in arrays]))
        return seen

    try:
        s.set(f"{ROBOT}.v", 0.3)
        s.step(0.6)
        t0 = s.t
        state = get_state()
        first = run(s, t0)
        set_state(state)
        assert run(s, t0) == first
        data = serialize(state)
        free_state(state)
        other = Slave(fmus[fmi], fmi).start(noise=False)
        setter, get = (other.fmu.setFloat64, other.fmu.getFloat64) if fmi == 3 else \
            (other.fmu.setReal, other.fmu.getReal)
        restored = _state_calls(other)[4](data)
        _state_calls(other)[1](restored)
        try:
            assert run(other, t0) == first
        finally:
            _state_calls(other)[2](restored)
            other.free()
    finally:
        s.free()


def test_a_state_of_another_fmu_is_refused_with_a_message(fmus):
    s = Slave(fmus[3], 3).start()
    try:
        get_state, set_state, free_state, serialize, deserialize = _state_calls(s)
        data = bytearray(serialize(get_state()))
        data[data.index(b'"token":"') + 10] ^= 1            # another FMU's token
        with pytest.raises(Exception):
            deserialize(bytes(data))
        assert any("a state of another FMU" in m for m in s.log), s.log
    finally:
        s.free()


def test_the_model_description_says_what_a_master_needs(fmus):
    """Input ranges from the world's drive limits, the metadata, fixed steps, FMU state, the
    documentation page; fmutool -check (an independent checker) finds no error."""
    from fmpy import read_model_description
    from plant.world import load_world
    drive = load_world("living_room").robot(ROBOT).drive
    for fmi, path in fmus.items():
        md = read_model_description(str(path))
        by = {v.name: v for v in md.modelVariables}
        assert (float(by[f"{ROBOT}.v"].min), float(by[f"{ROBOT}.v"].max)) == \
            (-drive.max_linear_mps, drive.max_linear_mps)
        assert (float(by[f"{ROBOT}.w"].min), float(by[f"{ROBOT}.w"].max)) == \
            (-drive.max_angular_radps, drive.max_angular_radps)
        assert by[f"{ROBOT}.v"].declaredType.quantity == "Velocity"
        assert by[f"{ROBOT}.yaw"].declaredType.quantity == "Angle"
        assert md.author and md.license == "MIT" and md.version == "0.1.0"
        assert md.generationTool.startswith("diffbot-cosim 0.1.0") and md.generationDateAndTime
        cs = md.coSimulation
        assert cs.modelIdentifier == "diffbot_plant"
        assert not cs.canHandleVariableCommunicationStepSize
        assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
        with zipfile.ZipFile(path) as zf:
            page = zf.read("documentation/" + ("index.html" if fmi == 3 else "_main.html"))
        assert b"whole 20 ms ticks" in page and f"{ROBOT}.scan_count".encode() in page
        code = ("import sys; from fmu_manipulation_toolbox.cli.fmutool import fmutool; "
                "sys.argv = ['fmutool'] + sys.argv[1:]; sys.exit(fmutool())")
        r = subprocess.run([sys.executable, "-c", code, "-input", str(path), "-check"],
                           capture_output=True, text=True, timeout=120)
        output = r.stdout + r.stderr
        assert r.returncode == 0 and f"No semantic error against the FMI-{fmi}" in output \
            and "ERROR" not in output, output


def test_scan_count_changes_when_a_new_scan_arrives_and_a_command_out_of_range_warns(fmus):
    s = Slave(fmus[3], 3).start()
    try:
        counts, scans = [], []
        for _ in range(11):
            counts.append(s.fmu.getInt32([s.vr[f"{ROBOT}.scan_count"]])[0])
            scans.append(list(s.fmu.getFloat64([s.vr[f"{ROBOT}.scan"]], nValues=180)))
            s.set(f"{ROBOT}.w", 0.5)           # turning: every scan differs
            s.step(TICK_S)
        assert counts == [1] * 5 + [2] * 5 + [3]            # the 10 Hz lidar: every 5th tick
        assert all((a == b) == (c == d) for a, b, c, d in
                   zip(scans, scans[1:], counts, counts[1:])), "scan_count and the scan agree"
        s.set(f"{ROBOT}.v", 100.0)             # a warning, not an error
        assert any("robot1.v = 100.0 is outside its range [-0.5, 0.5]" in m for m in s.log), \
            s.log
    finally:
        s.free()


@pytest.fixture(scope="module")
def scalars_fmu(tmp_path_factory):
    """The same FMU (FMI 3) exported with --scan-scalars."""
    path = tmp_path_factory.mktemp("scalars") / "scalars.fmu"
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "fmu", "export-plant",
                        "--scan-scalars", *_sets(), "--out", str(path)], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return path


def test_scan_scalars_give_fmi3_the_fmi2_scan_to_the_bit(fmus, scalars_fmu):
    """--scan-scalars: no array left (a master asking every Float64 output in one call),
    each ray the array's value."""
    got = {}
    for name, fmu in (("array", fmus[3]), ("scalars", scalars_fmu)):
        s = Slave(fmu, 3).start()
        try:
            assert any(v.dimensions for v in s.md.modelVariables) == (name == "array")
            s.set(f"{ROBOT}.w", 0.5)
            s.step(0.2)
            got[name] = (list(s.fmu.getFloat64([s.vr[f"{ROBOT}.scan"]], nValues=180))
                         if name == "array" else
                         s.get(*[f"{ROBOT}.scan[{k}]" for k in range(1, 181)]))
        finally:
            s.free()
    assert got["array"] == got["scalars"]


def _ecos_cli(tmp_path: Path) -> Path:
    """Ecos's command line, from ecospy (skipped where its library cannot load)."""
    try:
        import ecospy
    except (ImportError, OSError) as e:      # its binary needs libtbb.so.12 (apt: libtbb12)
        pytest.skip(f"ecospy cannot load here: {e}")
    ecos = tmp_path / "ecos"                 # the wheel installs it without the x bit
    shutil.copy(Path(ecospy.__file__).parent / "binaries" / "ecos", ecos)
    ecos.chmod(0o755)
    return ecos


def _ecos_simulate(ecos: Path, path: Path, folder: Path, stop_s: float) -> list[dict]:
    """``ecos simulate`` of an FMU or SSP in ``folder``, as a C master with no Python (the
    plant FMU finds this venv's through VIRTUAL_ENV): its CSV's rows, {column: value}."""
    folder.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "DIFFBOT_FMU_PYTHON"}
    env["VIRTUAL_ENV"] = sys.prefix
    r = subprocess.run([str(ecos), "simulate", "--path", str(path), "--stopTime", str(stop_s),
                        "--stepSize", str(TICK_S)], cwd=folder, env=env, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    rows = list(csv.reader(open(next(folder.glob("*.csv")))))
    head = [h.strip() for h in rows[0]]
    return [{h: float(v) for h, v in zip(head, row) if h.endswith("[REAL]") and v.strip()}
            for row in rows[1:]]


@pytest.fixture(scope="module")
def square_ssp(tmp_path_factory):
    """``diffbot fmu export-ssp`` (FMI 2 and 3): plant, odometry and controller FMUs."""
    out = tmp_path_factory.mktemp("ssp")
    paths = {}
    for fmi in (2, 3):
        r = subprocess.run([sys.executable, "-m", "diffbot.cli", "fmu", "export-ssp", "--fmi",
                            str(fmi), "--out", str(out / f"square{fmi}.ssp")], cwd=ROOT,
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        paths[fmi] = Path(r.stdout.strip())
    return paths


def _first_leg(plant_xy: tuple, odom_xy: tuple, done: float) -> None:
    """After 10 s the controller has driven the 1.5 m first leg (from (-1, -1), heading +x)
    on the odometry FMU's pose and is turning; odometry and truth agree."""
    x, y = plant_xy
    assert 0.45 < x < 0.52 and abs(y + 1.0) < 0.05, plant_xy
    assert abs(odom_xy[0] - (x + 1.0)) < 0.005 and abs(odom_xy[1] - (y + 1.0)) < 0.005
    assert done == 0.0


@pytest.mark.parametrize("fmi", [2, 3])
def test_ecos_command_line_runs_the_square_ssp(square_ssp, fmi, tmp_path):
    """Ecos's own command line, a C master: the plant FMU finds this venv's Python through
    VIRTUAL_ENV; every output goes to its CSV."""
    rows = _ecos_simulate(_ecos_cli(tmp_path), square_ssp[fmi], tmp_path / "run", 10.0)
    end = rows[-1]
    _first_leg((end[f"plant::{ROBOT}.x[REAL]"], end[f"plant::{ROBOT}.y[REAL]"]),
               (end["odometry::x[REAL]"], end["odometry::y[REAL]"]), end["controller::done[REAL]"])
    assert any(r["controller::w[REAL]"] > 0.1 for r in rows[-50:])       # the first corner
    if fmi == 3:                      # the scan as scalars: the CSV holds the rays (as an array,
        rays = [end[f"plant::{ROBOT}.scan[{k}][REAL]"] for k in range(1, 181)]   # zeros)
        assert min(rays) > 0.1, rays


def test_libcosim_runs_the_square_ssp(square_ssp):
    pytest.importorskip("libcosimpy", reason="pip install libcosimpy (DNV libcosim, FMI 2 only)")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    log_output_level(CosimLogLevel.WARNING)
    ex = CosimExecution.from_ssp_file(str(square_ssp[2]), step_size=int(TICK_S * 1e9))
    observer = CosimObserver.create_last_value()
    ex.add_observer(observer)
    vr = {(s.index, v.name.decode()): v.reference for s in ex.slave_infos()
          for v in ex.slave_variables(s.index)}
    index = {s.name.decode(): s.index for s in ex.slave_infos()}
    assert ex.simulate_until(int(10e9))

    def last(slave: str, *names: str) -> list[float]:
        i = index[slave]
        return list(observer.last_real_values(i, [vr[(i, n)] for n in names]))
    _first_leg(last("plant", f"{ROBOT}.x", f"{ROBOT}.y"), last("odometry", "x", "y"),
               last("controller", "done")[0])
