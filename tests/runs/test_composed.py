"""Composed members: hosted in the plant's process, the same bytes as over processes.

A composed run's recording equals the all-process run's, payloads and stamps on every topic
(tests/support/compare_recordings.py), under both couplings, for square and follow, and with one
member composed and the other a process in the same run; members that cannot be composed
are refused with the reason."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from ..support.compare_recordings import compare
from ..conftest import ROOT

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background

#: one run's bound (a few simulated seconds: ~5-10 s alone, several times that on a busy
#: machine); a test's timeout is its runs' bounds together, so a slow run is waited for
#: and a hung one still fails
RUN_S = 150


def run(tmp_path, name: str, scenario: str, *args: str) -> tuple[str, dict]:
    """``diffbot run SCENARIO ARGS --record``: (the recording, its summary)."""
    path = tmp_path / f"{name}.mcap"
    out = tmp_path / name
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "run", scenario, "--out", str(out),
                        "--record", str(path), *args], cwd=ROOT, capture_output=True, text=True,
                       timeout=RUN_S)
    assert r.returncode == 0, f"run {name} exited {r.returncode}:\n{r.stderr[-3000:]}"
    return str(path), json.loads((out / "summary.json").read_text())


def same(a: str, b: str) -> None:
    lines = compare(a, b)
    assert lines and all(ln.startswith("same") for ln in lines), "\n".join(lines)


@pytest.mark.slow
@pytest.mark.timeout(4 * RUN_S)
@pytest.mark.parametrize("coupling", ["pipelined", "sequential"])
def test_a_composed_run_records_the_bytes_of_the_run_over_processes(tmp_path, coupling):
    common = ("--duration", "3", "--seed", "3", "--coupling", coupling)
    procs, sp = run(tmp_path, "procs", "square", *common)
    composed, sc = run(tmp_path, "composed", "square", *common, "--compose")
    same(procs, composed)
    assert sp["composed"] == [] and sc["composed"] == ["odometry_robot1", "square_path_robot1"]
    assert sc["message_counts"] == sp["message_counts"]
    assert sc["exit_codes"] == sp["exit_codes"] == {
        "plant": 0, "recorder": 0, "odometry_robot1": 0, "square_path_robot1": 0}
    # follow: two robots, a camera, the ball follower, the wanderer and the FMU node
    common = ("--duration", "2", "--seed", "1", "--coupling", coupling)
    same(run(tmp_path, "fprocs", "follow", *common)[0],
         run(tmp_path, "fcomposed", "follow", *common, "--compose")[0])


@pytest.mark.slow
@pytest.mark.timeout(2 * RUN_S)
def test_a_process_member_and_a_composed_one_in_one_run_give_the_same_bytes(tmp_path):
    """The square path composed, the odometry FMU node a process (``compose = false``): it
    reads the plant's joint_states over Zenoh and the composed square path reads its odom."""
    text = (ROOT_SCENARIO.read_text().replace('coupling = "pipelined"',
                                              'coupling = "pipelined"\ncompose = true')
            .replace('command = ["fmu-node", "fmus/build/odometry_fmi2.fmu", "--robot", "robot1"]',
                     'command = ["fmu-node", "fmus/build/odometry_fmi2.fmu", "--robot", "robot1"]'
                     '\ncompose = false'))
    assert text.count("compose = ") == 2
    mixed_toml = tmp_path / "mixed.toml"
    mixed_toml.write_text(text)
    common = ("--duration", "3", "--seed", "4")
    procs, _ = run(tmp_path, "procs", "square", *common)
    mixed, sm = run(tmp_path, "mixed", str(mixed_toml), *common)
    assert sm["composed"] == ["square_path_robot1"]
    same(procs, mixed)


@pytest.mark.slow
@pytest.mark.timeout(2 * RUN_S)
def test_a_composed_swarm_records_the_bytes_of_its_processes(tmp_path):
    """The swarm's avoid member composed takes each scan as the plant's values (not its
    bytes decoded): four robots over 2 s (seed 1: every robot's commands differ, so each
    follows its own scans) record the bytes of the same swarm over processes."""
    common = ("--robots", "4", "--physics", "kinematic", "--controller-processes", "1",
              "--duration", "2", "--seed", "1", "--no-plots")
    procs, sp = run(tmp_path, "procs", "swarm", *common)
    composed, sc = run(tmp_path, "composed", "swarm", *common, "--compose")
    same(procs, composed)
    assert sp["composed"] == [] and sc["composed"] == ["avoid_g0"]
    assert sc["message_counts"] == sp["message_counts"]


ROOT_SCENARIO = __import__("pathlib").Path(ROOT) / "diffbot" / "launch" / "scenarios" / "square.toml"


@pytest.mark.slow
@pytest.mark.parametrize("command, why", [
    ("controller teleop --robot robot1", "reads the keyboard"),
    ("record out.mcap", "cannot be composed"),
    ("controller square_path --side -1", "made no member"),
])
def test_a_member_that_cannot_be_composed_is_refused_with_the_reason(command, why):
    p = subprocess.run([sys.executable, "-m", "diffbot.cli", "plant", "--world", "empty",
                        "--compose", command], cwd=ROOT, capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 2 and why in p.stderr, p.stderr
