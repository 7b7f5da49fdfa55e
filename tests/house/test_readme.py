"""The README's two commands are the ones CI runs, and its controller example works as printed."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import threading

import pytest

from bus import codec
from bus.keys import Keys

from ..conftest import ROOT

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background


def readme_example() -> str:
    text = open(os.path.join(ROOT, "README.md")).read()
    section = text.split("## Run your own controller", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_two_commands_are_make_targets_and_ci_runs_the_test_one():
    text = open(os.path.join(ROOT, "README.md")).read()
    block = re.search(r"## The two commands\n+```sh\n(.*?)```", text, re.S).group(1)
    commands = [ln.split("#")[0].split() for ln in block.splitlines() if ln.strip()]
    assert commands == [["make", "demo"], ["make", "test"]]
    makefile = open(os.path.join(ROOT, "Makefile")).read()
    assert re.search(r"^demo:", makefile, re.M) and re.search(r"^test:", makefile, re.M)
    ci = [ln.strip() for ln in open(os.path.join(ROOT, ".ci", "run")) if ln.strip()
          and not ln.startswith("#")]
    assert "make test" in ci


def test_example_is_short():
    lines = [ln for ln in readme_example().splitlines() if ln.strip()]
    assert len(lines) <= 12


@pytest.mark.slow
def test_readme_controller_drives_one_metre_and_exits(procs, endpoint, bus, tmp_path):
    script = tmp_path / "my_controller.py"
    script.write_text(readme_example())
    procs.diffbot("plant", "--world", "empty", "--endpoint", endpoint, name="plant")
    s = bus()
    xs = []
    lock = threading.Lock()

    def on_gt(sample):
        m = codec.decode(sample.payload.to_bytes(), "nav_msgs/msg/Odometry")
        with lock:
            xs.append(m.pose.pose.position.x)
    sub = s.declare_subscriber(Keys().topic("robot1", "ground_truth"), on_gt)
    r = subprocess.run([sys.executable, str(script), "--endpoint", endpoint], cwd=str(tmp_path),
                       capture_output=True, text=True, timeout=90)
    sub.undeclare()
    assert r.returncode == 0, r.stderr
    assert "done at t=" in r.stderr
    with lock:
        assert xs[-1] >= 0.95
