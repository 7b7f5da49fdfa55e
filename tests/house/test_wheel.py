"""The project as a wheel (docs/install.md): its build compiles the plant's C kernels and the
odometry FMUs into it, and installed into a fresh virtual environment outside the clone it
runs a scenario and the Gymnasium environment from any folder, with nothing of the clone
on its paths.

The wheel is built from a copy of the clone's files (the build writes build/ and *.egg-info
beside its sources), installed with the project's uv from uv's cache, which `make setup`
has filled (the index is asked only if something is not in it)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.background]

ROOT = Path(__file__).resolve().parents[2]
UV = Path(sys.executable).with_name("uv")


def _source_copy(dest: Path) -> Path:
    """The clone's tracked and new (not ignored) files, copied to ``dest``."""
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                            cwd=ROOT, capture_output=True, check=True).stdout
    for name in filter(None, listed.decode().split("\0")):
        src = ROOT / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    return dest


def clean_env(venv: Path) -> dict[str, str]:
    """The environment of a user whose shell has ``venv`` activated: none of the clone's
    folders on PATH or PYTHONPATH."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME", "PYTHONSTARTUP")}
    path = [p for p in env.get("PATH", "").split(os.pathsep)
            if p and not Path(p).resolve().is_relative_to(ROOT)]
    env["PATH"] = os.pathsep.join([str(venv / "bin"), *path])
    env["VIRTUAL_ENV"] = str(venv)
    return env


def _uv(*args: str) -> subprocess.CompletedProcess:
    """uv from its cache only (what `make setup` put there), else asking the index too."""
    at = 2 if args[0] == "pip" else 1                 # after the (sub)command's name
    r = subprocess.run([str(UV), *args[:at], "--offline", *args[at:]], capture_output=True,
                       text=True, timeout=600)
    if r.returncode != 0:
        r = subprocess.run([str(UV), *args], capture_output=True, text=True, timeout=600)
    return r


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """{"wheel", "venv", "python", "env", "cwd"}: the wheel built from a copy of the clone and
    installed with its ``learn`` extra into a fresh venv; ``cwd`` a folder outside the clone."""
    if not UV.is_file():
        pytest.skip(f"{UV} missing (`make setup` installs uv)")
    base = tmp_path_factory.mktemp("wheel")
    src = _source_copy(base / "src")
    dist = base / "dist"
    r = _uv("build", "--wheel", "--out-dir", str(dist), str(src))
    assert r.returncode == 0, r.stderr[-3000:]
    wheel, = dist.glob("*.whl")
    venv = base / "venv"
    subprocess.run([str(UV), "venv", "-q", "--python", sys._base_executable, str(venv)],
                   check=True, timeout=120)
    python = venv / "bin" / "python"
    r = _uv("pip", "install", "-q", "--python", str(python), f"{wheel}[learn]")
    assert r.returncode == 0, r.stderr[-3000:]
    cwd = base / "elsewhere"
    cwd.mkdir()
    return {"wheel": wheel, "venv": venv, "python": python, "env": clean_env(venv), "cwd": cwd}


def test_wheel_holds_the_compiled_kernels_and_fmus(installed):
    """The build compiled them (the clone's own builds are not copied: build/ is not tracked);
    one wheel for every Python 3 of the platform."""
    wheel = installed["wheel"]
    assert "-py3-none-" in wheel.name, wheel.name
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in ("plant/kernels/build/libplant_kernels.so",
                 "controllers/kernels/build/libcontroller_kernels.so", "fmus/build/odometry_fmi2.fmu",
                 "fmus/build/odometry_fmi3.fmu", "plant/worlds/living_room.toml",
                 "diffbot/launch/scenarios/square.toml", "diffbot/envs/__init__.py",
                 "fmus/plant_guest.py", "fmus/plant_wrapper/plant_python.c",
                 "fmus/models/square/model.c"):
        assert name in names, f"{name} not in {wheel.name}"
    assert not any(n.startswith("tests/") for n in names)


def test_installed_wheel_runs_square_and_avoid_outside_the_clone(installed):
    """`diffbot run square` (its odometry FMU node, its controller, the plant's kernels) and
    diffbot/Avoid-v0, from a folder outside the clone, import the installed package only."""
    env, cwd, venv = installed["env"], installed["cwd"], installed["venv"]
    out = cwd / "square"
    r = subprocess.run([str(venv / "bin" / "diffbot"), "run", "square", "--duration", "1", "--out", str(out)],
                       cwd=cwd, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sim_time_s"] >= 1.0 - 1e-9, summary
    assert summary["exit_codes"] == {"plant": 0, "odometry_robot1": 0, "square_path_robot1": 0}
    assert summary["message_counts"]["robot1/odom"] > 0, summary   # the odometry FMU's node
    assert (out / "trajectory.csv").stat().st_size > 0
    script = (
        "import gymnasium as gym, numpy as np, diffbot, diffbot.envs, plant.kernels as k\n"
        "env = gym.make('diffbot/Avoid-v0')\n"
        "obs, _ = env.reset(seed=3)\n"
        "for _ in range(10):\n"
        "    obs, reward, term, trunc, info = env.step(env.action_space.sample())\n"
        "assert np.isfinite(reward), reward\n"
        "k.library()\n"
        "import controllers.kernels as ck\n"
        "ck.library()\n"
        "print(diffbot.__file__)\n")
    r = subprocess.run([str(installed["python"]), "-c", script], cwd=cwd, env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    where = Path(r.stdout.strip()).resolve()
    assert where.is_relative_to(venv.resolve()) and not where.is_relative_to(ROOT), where


HOST_SCRIPT = '''\
import sys
r, s = "the host's r", "the host's s"      # names the FMU's loader once took from __main__
import plant                               # the host's own plant.py, beside this script
from fmpy import simulate_fmu
fmu = sys.argv[1]
result = simulate_fmu(fmu, stop_time=0.4, step_size=0.02, start_values={"robot1.v": 0.2},
                      output=["robot1.x", "robot1.odom_x"])
import plant as again
assert plant.WHO == again.WHO == "host", plant
assert (r, s) == ("the host's r", "the host's s"), (r, s)
assert not {"Guest", "load", "locate"} & set(globals()), sorted(globals())   # its own namespace
ours = sorted(k for k in sys.modules if k.split(".")[0] in ("fmus", "bus", "diffbot")
              or k.startswith("plant."))
assert not ours, ours                     # the FMU's modules are not left in the host's
print(result["robot1.x"][-1] - result["robot1.x"][0], result["robot1.odom_x"][-1])
'''


def test_an_exported_plant_fmu_runs_from_the_wheel_and_leaves_its_host_alone(installed,
                                                                              tmp_path):
    """The FMU exported in the clone, copied elsewhere, simulated by fmpy of the fresh venv
    (the clone's paths nowhere in reach) beside a host plant.py, under a host script whose
    globals stay its own; and run by a C master with no Python, which finds the fresh venv's
    Python through VIRTUAL_ENV."""
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "fmu", "export-plant", "--fmi", "3",
                        "--out", str(tmp_path / "robot.fmu")], cwd=ROOT, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    cwd = tmp_path / "host"
    cwd.mkdir()
    fmu = shutil.copy(tmp_path / "robot.fmu", cwd / "robot.fmu")
    (cwd / "plant.py").write_text('WHO = "host"\n')
    (cwd / "host.py").write_text(HOST_SCRIPT)
    r = subprocess.run([str(installed["python"]), "host.py", "robot.fmu"], cwd=cwd,
                       env=installed["env"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    moved, odom_x = map(float, r.stdout.split())
    assert 0.03 < moved < 0.09, moved     # 0.2 m/s for 0.4 s, less the acceleration ramp

    from fmus.build import fmi_headers_dir, find_c_compiler
    from fmpy import read_model_description
    host = tmp_path / "fmi3_host"
    subprocess.run([*find_c_compiler(), "-std=gnu99", "-O1", "-I", str(fmi_headers_dir()),
                    str(ROOT / "tests" / "support" / "fmi3_host.c"), "-o", str(host), "-ldl"],
                   check=True, timeout=120)
    md = read_model_description(fmu)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unzipped = tmp_path / "unzipped"
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(unzipped)
    binary, = (unzipped / "binaries").glob("*/diffbot_plant.so")
    r = subprocess.run([str(host), str(binary), str(unzipped / "resources"), md.guid,
                        str(vr["robot1.v"]), str(vr["robot1.odom_x"]), str(vr["robot1.y"]),
                        "0.2", "20"], cwd=cwd, env=installed["env"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert float(r.stdout.split()[-2]) == odom_x, (r.stdout, odom_x)   # the same run, to the bit
