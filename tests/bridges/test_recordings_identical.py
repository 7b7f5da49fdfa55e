"""Same seed, same bytes: two recordings of a run agree topic by topic, payloads and stamps
(tests/support/compare_recordings.py, the check that showed the lockstep restructuring kept every
byte), with and without a physics process, and the check does see a run that differs."""
from __future__ import annotations

import subprocess
import sys

import pytest

from ..support.compare_recordings import compare
from ..conftest import ROOT

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background


def record(tmp_path, name: str, *args: str):
    path = tmp_path / f"{name}.mcap"
    subprocess.run([sys.executable, "-m", "diffbot.cli", "run", "square", "--duration", "2",
                    "--out", str(tmp_path / name), "--record", str(path), *args],
                   cwd=ROOT, check=True, capture_output=True, timeout=300)
    return str(path)


@pytest.mark.slow
def test_two_runs_of_one_seed_record_the_same_bytes_and_another_coupling_does_not(tmp_path):
    a = record(tmp_path, "a", "--seed", "5", "--coupling", "pipelined", "--physics-process")
    b = record(tmp_path, "b", "--seed", "5", "--coupling", "pipelined")
    lines = compare(a, b)
    # the robot's 7 topics, sim/clock and sim/poses (every robot's pose a tick)
    assert len(lines) == 9 and all(ln.startswith("same") for ln in lines), lines
    assert any(ln.split()[1] == "/sim/poses:" for ln in lines), lines
    # sequential: the commands act a tick earlier, so the robot's path differs, not the clock
    c = record(tmp_path, "c", "--seed", "5", "--coupling", "sequential")
    differ = [ln.split()[1] for ln in compare(a, c) if ln.startswith("DIFF")]
    assert "/robot1/ground_truth:" in differ and "/sim/clock:" not in differ, differ
    assert "/sim/poses:" in differ, differ
