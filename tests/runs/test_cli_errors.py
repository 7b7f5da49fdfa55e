"""What a new user trips on: bad numbers, unknown names, misspelt keys, strict JSON."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from bus.jsonio import strict_json, write_json
from diffbot import cli
from diffbot.launch.launcher import main as run_main
from diffbot.launch.scenario import load_scenario
from plant.process_cli import main as plant_main
from plant.world import WorldError, load_world

from ..conftest import ROOT

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background


def _strict_load(path):
    def refuse(name):
        raise ValueError(f"{name} is not JSON")
    with open(path) as f:
        return json.load(f, parse_constant=refuse)


@pytest.mark.parametrize("value", ["-5", "0", "nan", "inf", "soon"])
def test_plant_refuses_a_duration_that_is_not_a_positive_number(value, capsys):
    with pytest.raises(SystemExit) as e:
        plant_main(["--world", "empty", f"--duration={value}"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "argument --duration" in err and value in err
    assert len(err.strip().splitlines()) == 1, err          # one line, not the usage block


@pytest.mark.parametrize("argv", [["drive-test", "--duration", "-5"],
                                  ["drive-test", "--timeout", "0"],
                                  ["drive-test", "--seed", "-1"]])
def test_run_refuses_bad_numbers_before_starting_anything(argv, capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        run_main([*argv, "--out", str(tmp_path / "out")])
    assert e.value.code == 2
    assert "must be" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_controller_options_are_checked_too(capsys):
    with pytest.raises(SystemExit) as e:
        cli._dispatch(["controller", "square_path", "--side", "-1.5"])
    assert e.value.code == 2
    assert "argument --side: must be a finite number > 0, got -1.5" in capsys.readouterr().err


def test_unknown_controller_is_named_with_the_choices(capsys):
    assert cli._dispatch(["controller", "circle"]) == 2
    err = capsys.readouterr().err
    assert "unknown controller 'circle'" in err and "square_path" in err
    assert cli._dispatch(["controller", "square_pth"]) == 2
    assert "did you mean 'square_path'" in capsys.readouterr().err


def test_controller_help_names_the_controller(capsys):
    with pytest.raises(SystemExit) as e:
        cli._dispatch(["controller", "square_path", "--help"])
    assert e.value.code == 0
    assert capsys.readouterr().out.startswith("usage: diffbot controller square_path ")


def test_fmu_build_help_names_the_command_a_user_typed(capsys):
    with pytest.raises(SystemExit) as e:
        cli._dispatch(["fmu", "build", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: diffbot fmu build ") and "fmus/models/" in out


def test_a_bad_set_override_is_blamed_on_the_option_not_the_file():
    with pytest.raises(WorldError) as e:
        load_world("empty", ["world.physics_stepp_s=0.002"])
    msg = str(e.value)
    assert msg.startswith("--set world.physics_stepp_s=0.002: world.physics_stepp_s: unknown key")
    assert "did you mean 'physics_step_s'" in msg and "empty.toml" not in msg
    with pytest.raises(WorldError, match=r"^--set robots.robot1.gps.noise=\{std=-1\}: "
                                         r"robots\[0\]\.gps\.noise\.std: must be >= 0"):
        load_world("living_room", ["robots.robot1.gps.noise={std=-1}"])
    with pytest.raises(WorldError, match="no robot named 'robt1' \\(did you mean 'robot1'"):
        load_world("living_room", ["robots.robt1.gps.noise={std=1}"])
    # an error elsewhere in the file is still the file's
    with pytest.raises(WorldError, match="unknown key"):
        load_world("empty", ["world.mode=kinematic", "world.bogus=1"])


def test_scenario_and_world_typos_get_a_did_you_mean(tmp_path):
    with pytest.raises(WorldError, match="did you mean 'square'"):
        load_scenario("sqaure")
    with pytest.raises(WorldError, match="did you mean 'empty'"):
        load_world("emty")
    f = tmp_path / "s.toml"
    f.write_text('[scenario]\nworld = "empty"\nmode = "lockstp"\n')
    with pytest.raises(WorldError, match=r"s\.toml:scenario\.mode: .*did you mean 'lockstep'"):
        load_scenario(str(f))
    f.write_text('[scenario]\nworld = "empty"\nanalyss = "none"\n')
    with pytest.raises(WorldError, match=r"scenario\.analyss: unknown key \(did you mean "
                                         r"'analysis'"):
        load_scenario(str(f))


def test_json_the_project_writes_is_strict(tmp_path):
    data = {"v": math.nan, "w": [1.0, math.inf, np.float64(-math.inf)], "n": np.int64(3),
            "a": np.array([0.5, math.nan])}
    path = tmp_path / "x.json"
    write_json(str(path), data)
    assert _strict_load(path) == {"v": None, "w": [1.0, None, None], "n": 3, "a": [0.5, None]}
    assert strict_json({"ok": 1.5}) == {"ok": 1.5}
    with pytest.raises(TypeError):
        write_json(str(path), {"x": object()})


def test_drive_test_too_short_gives_null_with_a_reason(tmp_path):
    """A run that ends before the steady windows: null and why, never NaN."""
    from diffbot.analysis.runs import DriveTestAnalysis
    from bus import codec
    from bus.keys import Keys
    from diffbot.launch.scenario import load_scenario as ls

    class Obs:
        def __init__(self, msgs):
            self.msgs = msgs

        def messages(self, key):
            return self.msgs.get(key, [])

    keys, spec = Keys(), ls("drive-test")
    gt = [codec.odometry(int(t * 1e9), 0.12 * t, 0.0, 0.0, 0.12, 0.0)
          for t in np.arange(0, 2.0, 0.02)]
    cmd = [codec.joint_state(0, ("left_wheel_joint", "right_wheel_joint"), velocity=(1.0, 1.0))]
    obs = Obs({keys.topic("robot1", "ground_truth"): gt, keys.topic("robot1", "wheel_cmd"): cmd})
    m = DriveTestAnalysis.analyse(obs, keys, spec, None, str(tmp_path))
    assert m["steady_linear_velocity_mps"] is None
    assert "no ground truth between 3 and 5 s" in m["steady_linear_velocity_mps_reason"]
    write_json(str(tmp_path / "s.json"), m)
    assert _strict_load(tmp_path / "s.json")["steady_angular_velocity_radps"] is None


@pytest.mark.slow
def test_echo_says_what_the_plant_publishes_when_nothing_comes(procs, endpoint):
    procs.diffbot("plant", "--world", "empty", "--mode", "realtime", "--endpoint", endpoint,
                  name="plant")
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "echo", "robot1/scan", "--count",
                        "1", "--timeout", "2", "--endpoint", endpoint], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert "no message on robot1/scan within 2 s" in r.stderr
    assert "the plant publishes: sim/clock, robot1/joint_states, robot1/gps" in r.stderr
    assert "robot1/scan," not in r.stderr


@pytest.mark.slow
def test_copied_readme_controller_exits_nonzero_without_a_plant(tmp_path):
    from ..house.test_readme import readme_example
    script = tmp_path / "my_controller.py"
    script.write_text(readme_example())
    env = dict(os.environ, PYTHONPATH=ROOT)
    conf = tmp_path / "client.json5"          # as the default, but give up after 1 s, not 15
    conf.write_text(json.dumps({
        "mode": "client", "listen": {"endpoints": []},
        "connect": {"endpoints": [f"unixsock-stream/{tmp_path}/nobody.sock"],
                    "timeout_ms": 1000, "exit_on_failure": True},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}}}))
    r = subprocess.run([sys.executable, str(script), "--zenoh-config", str(conf)],
                       cwd=str(tmp_path), env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode != 0, r.stderr
    # the endpoint and why (not Zenoh's "Unable to connect ... Timeout!"), and the config
    assert (f"cannot connect to unixsock-stream/{tmp_path}/nobody.sock: no socket file"
            in r.stderr), r.stderr
    assert str(conf) in r.stderr


@pytest.mark.slow
def test_an_unwritable_stats_path_is_an_error_line_not_a_hang(tmp_path):
    """The plant closes its session before it writes --stats: a path it cannot write (a
    test's deleted tmp dir, a typo) is one error line, and the process still exits."""
    stats = tmp_path / "gone" / "plant.json"
    p = subprocess.run([sys.executable, "-m", "diffbot.cli", "plant", "--world", "empty",
                        "--mode", "fast", "--duration", "0.1", "--stats", str(stats),
                        "--endpoint", f"unixsock-stream/{tmp_path}/bus.sock"],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert f"cannot write --stats {stats}" in p.stderr, p.stderr
    assert "Traceback" not in p.stderr, p.stderr
    assert not stats.exists()


@pytest.mark.slow
def test_a_node_s_unwritable_stats_path_is_an_error_line_too(tmp_path):
    """As the plant's: written after the session closed, one error line, not a traceback."""
    stats = tmp_path / "gone" / "node.json"
    endpoint = f"unixsock-stream/{tmp_path}/bus.sock"
    plant = subprocess.Popen([sys.executable, "-m", "diffbot.cli", "plant", "--world", "empty",
                              "--mode", "realtime", "--duration", "3", "--endpoint", endpoint],
                             cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        r = subprocess.run([sys.executable, "-m", "diffbot.cli", "controller", "square_path",
                            "--stats", str(stats), "--endpoint", endpoint],
                           cwd=ROOT, capture_output=True, text=True, timeout=60)
    finally:
        plant.kill()
        plant.wait(10)
    assert "square_path_robot1 on robot robot1" in r.stderr, r.stderr     # it ran
    assert f"cannot write --stats {stats}" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr, r.stderr


def test_a_node_that_finds_no_plant_asks_once_whether_it_runs(tmp_path, monkeypatch):
    import socket

    from bus import session as bus_session

    def refuse(conf):
        raise RuntimeError("Unable to connect to any of [...]. Timeout!")
    monkeypatch.setattr(bus_session.zenoh, "open", refuse)
    # a node's connect timeout of two attempts instead of 15 s: the same attempts, the same
    # diagnosis at the end (its length is not what is asked here), 26 s sooner
    make_config = bus_session.make_config

    def short_timeout(*a, **kw):
        conf = make_config(*a, **kw)
        conf.insert_json5("connect/timeout_ms", str(2 * bus_session.ATTEMPT_MS))
        return conf
    monkeypatch.setattr(bus_session, "make_config", short_timeout)
    with pytest.raises(bus_session.BusConfigError) as e:
        bus_session.open_session("node", f"unixsock-stream/{tmp_path}/nobody.sock")
    assert "no socket file" in str(e.value) and str(e.value).count("running") == 1, e.value
    with socket.socket() as s:              # TCP answers, Zenoh does not: the hint helps
        s.bind(("127.0.0.1", 0))
        s.listen()
        with pytest.raises(bus_session.BusConfigError) as e:
            bus_session.open_session("node", f"tcp/127.0.0.1:{s.getsockname()[1]}")
    assert "no Zenoh session opened" in str(e.value)
    assert "[is `diffbot plant` running with the same --endpoint?]" in str(e.value)
