"""`diffbot run`: the study's drive test and square, determinism, supervision, Ctrl-C."""
from __future__ import annotations

import glob
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from diffbot.launch.launcher import SOCKET_DIR_PREFIX

from ..conftest import ROOT, check_real_time_factor, wait_for

pytestmark = pytest.mark.slow


def diffbot_run(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "diffbot.cli", "run", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def _cmdline(pid: int | str) -> str | None:
    """A process's command line, or None if it is gone."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode("utf-8", "replace")
    except OSError:
        return None


def processes_mentioning(text: str) -> list[int]:
    """PIDs of live processes whose command line contains ``text``."""
    pids = []
    for d in os.listdir("/proc"):
        if not d.isdigit() or int(d) == os.getpid():
            continue
        cmd = _cmdline(d)
        if cmd is None or text not in cmd:
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                state = f.read().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            pids.append(int(d))
    return pids


def test_drive_test_matches_the_study(tmp_path):
    r = diffbot_run("drive-test", "--out", str(tmp_path), "--plots")
    assert r.returncode == 0, r.stderr
    s = json.load(open(tmp_path / "summary.json"))
    m = s["metrics"]
    assert m["steady_linear_velocity_mps"] == pytest.approx(0.120, rel=0.01)
    assert abs(m["steady_angular_velocity_radps"]) == pytest.approx(0.667, rel=0.02)
    assert (tmp_path / "velocity.png").stat().st_size > 10_000
    header = (tmp_path / "velocity.csv").read_text().splitlines()[0]
    assert header == "t_s,linear_velocity_mps,angular_velocity_radps"
    assert s["exit_codes"] == {"plant": 0, "wheel_schedule_robot1": 0}


@pytest.mark.xdist_group("square_seed0")      # (its worker runs the session's square)
@pytest.mark.parametrize("coupling", ["sequential", "pipelined"])
def test_square_closes_and_is_byte_identical_across_runs(tmp_path, coupling, request):
    """Two runs of one seed drive the same trajectory to the byte, the second with its
    members composed in the plant's process (`--compose`: the same bytes, for about half
    the CPU, over the whole square). The pipelined case's first run is the session's
    recorded square (conftest.square_seed0, the scenario's coupling): recording a run
    leaves it as it was."""
    outs = [tmp_path / "a", tmp_path / "b"]
    if coupling == "pipelined":
        outs[0] = Path(request.getfixturevalue("square_seed0")["out"])
    for out, compose in zip(outs, (("--plots",), ("--compose",))):
        if out.exists():
            continue
        r = diffbot_run("square", "--seed", "0", "--out", str(out), "--coupling", coupling,
                        *compose)
        assert r.returncode == 0, r.stderr
    second = json.load(open(outs[1] / "summary.json"))
    assert second["composed"] == ["odometry_robot1", "square_path_robot1"]
    # the second run drew no figures (DIFFBOT_PLOTS=0 here, as --no-plots): its data alone
    assert not list(outs[1].glob("*.png")) and (outs[1] / "paths.csv").exists()
    assert second["paths"]["files"] == ["paths.csv"]
    a, b = ((o / "trajectory.csv").read_bytes() for o in outs)
    assert len(a.splitlines()) > 1000
    assert a == b
    s = json.load(open(outs[0] / "summary.json"))
    m = s["metrics"]["robot1"]
    assert m["final_odom_error_m"] < 0.02
    assert m["path_closure_m"] < 0.05                 # the square closes
    assert m["path_length_m"] == pytest.approx(6.0, abs=0.1)
    assert s["mode"] == "lockstep" and s["seed"] == 0
    check_real_time_factor(s)
    assert s["coupling"] == coupling
    assert s["actuation_delay_ticks"] == s["node_input_delay_ticks"] == \
        (1 if coupling == "pipelined" else 0)
    assert s["message_counts"]["robot1/odom"] > 1000
    assert (outs[0] / "odometry_vs_gps.png").stat().st_size > 10_000
    assert all(code == 0 for code in s["exit_codes"].values()), s["exit_codes"]


def test_required_process_death_ends_the_run_and_names_it(tmp_path):
    scen = tmp_path / "broken.toml"
    scen.write_text("""
[scenario]
world = "empty"
mode = "lockstep"

[[process]]
name = "odometry_robot1"
command = ["controller", "odometry", "--robot", "robot1"]

[[process]]
name = "bad_controller"
command = ["controller", "wheel_schedule", "--schedule", "oops"]
""")
    r = diffbot_run(str(scen), "--out", str(tmp_path / "out"), timeout=60)
    assert r.returncode == 1
    assert "bad_controller failed with exit code 2" in r.stderr
    assert "bad schedule item 'oops'" in r.stderr           # its last stderr lines
    s = json.load(open(tmp_path / "out" / "summary.json"))
    assert s["exit_codes"]["bad_controller"] == 2
    assert not processes_mentioning(str(tmp_path))


def test_bad_scenario_file_is_one_line_exit_2(tmp_path):
    scen = tmp_path / "typo.toml"
    scen.write_text('[scenario]\nworld = "empty"\nmdoe = "fast"\n')
    r = diffbot_run(str(scen), "--out", str(tmp_path / "out"), timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"diffbot run: {scen}:scenario.mdoe: unknown key (did you mean 'mode'?)"]


def test_ctrl_c_stops_every_process_and_leaves_a_summary(tmp_path):
    out = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "diffbot.cli", "run", "square", "--mode",
                          "realtime", "--out", str(out)], cwd=ROOT, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, start_new_session=True)
    try:
        plant_log = out / "logs" / "plant.log"
        wait_for(lambda: plant_log.exists() and "running" in plant_log.read_text(), 60,
                 what="the plant to start running")
        time.sleep(1.0)
        p.send_signal(signal.SIGINT)
        t0 = time.monotonic()
        # the children (the launcher itself may still be writing plots)
        wait_for(lambda: set(processes_mentioning(str(out))) <= {p.pid}, 5,
                 what="children to go")
        assert time.monotonic() - t0 < 2.0 + 0.5      # children gone within 2 s
        _, err = p.communicate(timeout=30)
        assert not processes_mentioning(str(out))
    finally:
        if p.poll() is None:
            p.kill()
    err = err.decode(errors="replace")
    assert p.returncode == 130, err
    s = json.load(open(out / "summary.json"))
    assert s["end_reason"] == "interrupted (SIGINT)"
    # (a child the launcher had to SIGKILL: its stderr says which and how long after its
    # SIGINT, scenario_run.stop_all)
    assert s["exit_codes"]["plant"] == 0, (s["exit_codes"], err)
    assert s["sim_time_s"] > 0.5
    assert (out / "trajectory.csv").read_text().startswith("t_s,")


def test_a_sigkilled_launcher_leaves_no_process_behind(tmp_path):
    """SIGKILL cannot be caught: the kernel stops the launcher's children instead."""
    out = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "diffbot.cli", "run", "square", "--mode",
                          "realtime", "--out", str(out), "--record", str(tmp_path / "run.mcap")], cwd=ROOT,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True)
    try:
        plant_log = out / "logs" / "plant.log"
        wait_for(lambda: plant_log.exists() and "running" in plant_log.read_text(), 60,
                 what="the plant to start running")
        wait_for(lambda: len(processes_mentioning(str(out))) >= 4, 30,
                 what="the scenario's processes")
        sock_dirs = glob.glob(os.path.join(tempfile.gettempdir(),
                                           f"{SOCKET_DIR_PREFIX}{p.pid}-*"))
        assert len(sock_dirs) == 1, sock_dirs        # its bus socket's folder
        p.kill()
        p.wait(10)
        # (a node whose plant went at the same moment may spend a while closing its session)
        try:
            wait_for(lambda: not processes_mentioning(str(out)), 40, what="the children to go")
        except AssertionError as exc:         # name what is left now, not what was at the kill
            left = [(_cmdline(p) or "")[:120] for p in processes_mentioning(str(out))]
            raise AssertionError(f"{exc}: {left}") from None
        # SIGKILL left the folder; the next run removes it (here one that stops at once)
        assert os.path.isdir(sock_dirs[0])
        again = subprocess.run([sys.executable, "-m", "diffbot.cli", "run", "square",
                                "--duration", "0.1", "--out", str(tmp_path / "again")],
                               cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert again.returncode == 0, again.stderr
        assert not os.path.exists(sock_dirs[0]), "the dead launcher's socket folder is still there"
    finally:
        if p.poll() is None:
            p.kill()
        for pid in processes_mentioning(str(out)):
            os.kill(pid, signal.SIGKILL)
