"""Any controller class runs as a node (`diffbot controller python:MODULE:CLASS`, or a .py
file), as a process or composed into the plant, and a scenario may start any program
(`exec = [...]`): a trained policy needs no code of ours to deploy."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from controllers import hosted
from diffbot.launch.scenario import load_scenario
from plant.world import WorldError

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

AGENT = '''
from bus.node import Twist

class Forward:
    """Drives ahead at `speed` for `ticks` control ticks, then is done."""
    inputs = ["ground_truth"]

    def __init__(self, ticks=10, speed=0.2, robot=None):
        self.ticks, self.speed, self.robot = int(ticks), float(speed), robot
        self.done = False

    def step(self, obs):
        self.ticks -= 1
        if self.ticks <= 0:
            self.done = True
        return Twist(self.speed, 0.0)
'''

EXEC_AGENT = AGENT + '''
if __name__ == "__main__":
    import sys
    from bus.node import run_node
    sys.exit(run_node(Forward(ticks=15), argv=sys.argv[1:]))
'''


@pytest.fixture
def agent_dir(tmp_path):
    (tmp_path / "my_agent.py").write_text(AGENT)
    (tmp_path / "exec_agent.py").write_text(EXEC_AGENT)
    return tmp_path


def test_load_by_module_and_by_file(agent_dir, monkeypatch):
    monkeypatch.syspath_prepend(str(agent_dir))
    cls = hosted.load("python:my_agent:Forward")
    assert cls.__name__ == "Forward"
    assert hosted.load(str(agent_dir / "my_agent.py")).__name__ == "Forward"
    assert hosted.load(f"{agent_dir / 'my_agent.py'}:Forward").__name__ == "Forward"
    make = hosted.factory(cls, hosted.parse_kwargs(["ticks=3", "speed=0.5"]))
    c = make("robot7")
    assert (c.ticks, c.speed, c.robot) == (3, 0.5, "robot7")


@pytest.mark.parametrize("target,why", [
    ("python:no_such_module_xyz:A", "cannot import"),
    ("python:my_agent:Nope", "not a class with a step method"),
    ("python:my_agent", "python:MODULE:CLASS"),
    ("missing_file.py", "no file"),
])
def test_bad_targets_say_why(agent_dir, monkeypatch, target, why):
    monkeypatch.syspath_prepend(str(agent_dir))
    with pytest.raises(ValueError, match=why):
        hosted.load(target)


def test_arg_values_are_literals_or_text():
    assert hosted.parse_kwargs(["a=1", "b=(1, 2.5)", "c=hello", "d='x y'", "e=True"]) == \
        {"a": 1, "b": (1, 2.5), "c": "hello", "d": "x y", "e": True}
    with pytest.raises(ValueError, match="KEY=VALUE"):
        hosted.parse_kwargs(["no-equals"])


@pytest.mark.slow
def test_a_bad_class_or_argument_exits_2_with_the_reason(agent_dir):
    env = dict(os.environ, PYTHONPATH=f"{agent_dir}{os.pathsep}{ROOT}")
    out = subprocess.run([sys.executable, "-m", "diffbot.cli", "controller",
                          "python:my_agent:Forward", "--arg", "wheels=4"], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "unexpected keyword argument 'wheels'" in out.stderr


def _scenario(tmp_path, process: str) -> str:
    path = tmp_path / "s.toml"
    path.write_text(textwrap.dedent('''
        [scenario]
        world = "living_room"
        mode = "lockstep"
        coupling = "sequential"
        duration_s = 10.0
        plant_args = ["--disable", "camera,lidar"]
        ''') + process)
    return str(path)


def test_exec_and_command_are_exclusive_and_placeholders_checked(tmp_path):
    both = _scenario(tmp_path, '[[process]]\nname = "a"\ncommand = ["controller", "wander"]\n'
                               'exec = ["true"]\n')
    with pytest.raises(WorldError, match="one of command"):
        load_scenario(both)
    bad = _scenario(tmp_path, '[[process]]\nname = "a"\nexec = ["x", "{port}"]\n')
    with pytest.raises(WorldError, match="bad placeholder"):
        load_scenario(bad)
    ok = load_scenario(_scenario(tmp_path, '[[process]]\nname = "a"\n'
                                           'exec = ["{python}", "a.py", "{bus}"]\n'))
    assert ok.processes[0].exec == ["{python}", "a.py", "{bus}"]


def _run(tmp_path, scenario: str, *extra: str, env=None) -> dict:
    out = subprocess.run([sys.executable, "-m", "diffbot.cli", "run", scenario, "--out",
                          str(tmp_path / "run"), *extra], cwd=ROOT, capture_output=True,
                         text=True, timeout=150, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads((tmp_path / "run" / "summary.json").read_text())


@pytest.mark.slow
@pytest.mark.timeout(200)
@pytest.mark.parametrize("compose", [False, True])
def test_a_class_by_module_runs_as_a_node_and_composed(agent_dir, compose):
    scen = _scenario(agent_dir, '[[process]]\nname = "agent"\n'
                                'command = ["controller", "python:my_agent:Forward", '
                                '"--arg", "ticks=20"]\nends_run = true\n')
    env = dict(os.environ, PYTHONPATH=f"{agent_dir}{os.pathsep}{ROOT}")
    summary = _run(agent_dir, scen, "--compose" if compose else "--no-compose", env=env)
    assert "agent finished" in summary["end_reason"]
    assert summary["composed"] == (["agent"] if compose else [])
    assert summary["sim_time_s"] == pytest.approx(20 * 0.02, abs=0.05)


@pytest.mark.slow
@pytest.mark.timeout(200)
def test_a_scenario_process_may_run_any_program(agent_dir):
    script = agent_dir / "exec_agent.py"
    scen = _scenario(agent_dir, '[[process]]\nname = "outsider"\n'
                                f'exec = ["{{python}}", "{script}", "--name", "{{name}}", '
                                '"{bus}"]\nends_run = true\n')
    env = dict(os.environ, PYTHONPATH=ROOT)
    summary = _run(agent_dir, scen, "--plots", env=env)
    assert "outsider finished" in summary["end_reason"]
    assert summary["sim_time_s"] == pytest.approx(15 * 0.02, abs=0.05)
    check_paths(agent_dir / "run", summary)


def check_paths(out, summary) -> None:
    """A run without an analysis of its own draws its robot's ground-truth path on the room
    (paths.png) and lists it (paths.csv): from robot1's start pose, straight ahead."""
    import csv

    import numpy as np
    from PIL import Image

    from plant.world import load_world
    robot = load_world("living_room").robot("robot1")
    rows = list(csv.DictReader(open(out / "paths.csv")))
    assert {r["robot"] for r in rows} == {"robot1"}
    xy = np.array([[float(r["x_m"]), float(r["y_m"])] for r in rows])
    t = np.array([float(r["t_s"]) for r in rows])
    assert len(rows) >= 15 and np.all(np.diff(t) > 0)
    x0, y0, yaw0 = robot.pose
    assert np.hypot(*(xy[0] - (x0, y0))) < 1e-3
    ahead = (xy - xy[0]) @ (np.cos(yaw0), np.sin(yaw0))
    assert 0.02 < ahead[-1] < 0.2 * summary["sim_time_s"] + 0.01 and np.all(np.diff(ahead) > -1e-4)
    assert summary["paths"]["robots"] == 1
    assert summary["paths"]["distance_m"]["robot1"] == pytest.approx(ahead[-1], abs=0.01)
    img = np.asarray(Image.open(out / "paths.png").convert("RGB")).astype(int)
    colour = np.array([round(255 * c) for c in robot.color])
    assert img.shape[0] > 500 and (np.abs(img - colour).max(axis=2) < 30).sum() >= 20


HANGS = '''
import time
from bus.node import Twist

class Hangs:
    """Answers two ticks, then hangs in its step (a deadlock, a blocking call)."""
    inputs = ["ground_truth"]

    def __init__(self, robot=None):
        self.n = 0

    def step(self, obs):
        self.n += 1
        if self.n > 2:
            hang_here()
        return Twist(0.1, 0.0)

def hang_here():
    while True:
        time.sleep(0.05)
'''


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_process_that_does_not_stop_leaves_its_stacks_in_its_log(agent_dir):
    """Ctrl-C to a run whose node hangs in its step: the node does not end within the
    grace, so diffbot run has it write its stacks (SIGUSR1, faulthandler) before killing it,
    and its log says where it hung."""
    (agent_dir / "hangs.py").write_text(HANGS)
    scen = _scenario(agent_dir, '[[process]]\nname = "agent"\n'
                                'command = ["controller", "python:hangs:Hangs"]\n')
    env = dict(os.environ, PYTHONPATH=f"{agent_dir}{os.pathsep}{ROOT}")
    run = subprocess.Popen([sys.executable, "-m", "diffbot.cli", "run", scen, "--out",
                            str(agent_dir / "run"), "--no-compose"], cwd=ROOT, env=env,
                           stderr=subprocess.PIPE, text=True)
    try:
        log = agent_dir / "run" / "logs" / "plant.log"
        deadline = time.monotonic() + 60
        while "lockstep: waited" not in (log.read_text() if log.exists() else ""):
            assert run.poll() is None and time.monotonic() < deadline, "no wait for the agent"
            time.sleep(0.1)
        run.send_signal(signal.SIGINT)
        err = run.communicate(timeout=60)[1]
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode == 130, err
    assert "agent did not stop in time; killed (SIGKILL" in err, err
    agent_log = (agent_dir / "run" / "logs" / "agent.log").read_text()
    assert "most recent call first" in agent_log, agent_log[-2000:]      # faulthandler's
    assert re.search(r'hangs\.py", line \d+ in hang_here', agent_log), agent_log[-2000:]
    assert json.loads((agent_dir / "run" / "summary.json").read_text())["exit_codes"][
        "agent"] == -signal.SIGKILL
