"""`diffbot bench`: the harness picks its loop counts, computes its statistics, reports
JSON and a table, and refuses unknown suites. Speed itself is never asserted here."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time

import pytest

from diffbot import bench
from diffbot.cli import main as cli_main

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CASE_KEYS = {"suite", "name", "unit", "median", "min", "max", "repeats", "samples", "notes"}


class FakeClock:
    """A clock that only moves when the benchmarked function says so."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


# ---------------------------------------------------------------- timing primitive
def test_autorange_picks_number_so_one_repeat_takes_a_tenth_of_a_second():
    calls = []

    def timer(number):  # 1 ms per operation, exactly
        calls.append(number)
        return number * 1e-3
    number, t = bench.autorange(timer, min_time=0.1, target=0.15)
    assert t == pytest.approx(number * 1e-3)
    assert 0.1 <= t <= 0.3
    assert calls == sorted(calls) and calls[-1] == number      # grows, stops at the pick
    assert all(c * 1e-3 < 0.1 for c in calls[:-1])              # every earlier try was too short


def test_autorange_keeps_number_1_for_a_slow_operation():
    assert bench.autorange(lambda n: n * 0.5, min_time=0.1) == (1, 0.5)


def test_as_timer_times_a_plain_callable_on_the_given_clock():
    clock = FakeClock()

    def op():
        clock.now += 0.002
    timer = bench.as_timer(op, clock=clock)
    assert timer(10) == pytest.approx(0.02)
    number, samples = bench.measure(timer, repeats=4, warmup=1, min_time=0.1, target=0.15)
    assert number * 0.002 >= 0.1
    assert samples == pytest.approx([0.002] * 4)


def test_measure_reports_per_operation_samples_and_their_statistics():
    per_op = iter([5e-3, 1e-3, 3e-3, 2e-3, 4e-3])
    number, samples = bench.measure(lambda n: n * next(per_op), repeats=5, number=10, warmup=0)
    assert number == 10
    assert samples == pytest.approx([5e-3, 1e-3, 3e-3, 2e-3, 4e-3])
    st = bench.stats(samples)
    assert st["median"] == pytest.approx(3e-3)
    assert st["min"] == pytest.approx(1e-3) and st["max"] == pytest.approx(5e-3)
    assert st["p90"] == pytest.approx(4.6e-3)                   # linear between ranks
    assert st["q1"] == pytest.approx(2e-3) and st["q3"] == pytest.approx(4e-3)


def test_median_of_an_even_number_of_samples_is_the_mean_of_the_middle_two():
    assert bench.stats([4.0, 1.0, 3.0, 2.0])["median"] == 2.5
    assert bench.percentile(list(range(1, 11)), 90) == pytest.approx(9.1)


def test_sleep_based_operation_is_never_measured_shorter_than_it_sleeps():
    number, samples = bench.measure(bench.as_timer(lambda: time.sleep(0.005)), repeats=3,
                                    min_time=0.02, target=0.03)
    assert number >= 1 and len(samples) == 3
    assert min(samples) >= 0.005


def test_time_values_are_printed_in_readable_units():
    assert bench.fmt_value(18.2e-6, "s") == "18.2 µs"
    assert bench.fmt_value(3.2e-3, "s") == "3.20 ms"
    assert bench.fmt_value(850e-9, "s") == "850 ns"
    assert bench.fmt_value(2.83, "x") == "2.83 xRT"


# ---------------------------------------------------------------- command line
def test_list_names_every_suite(capsys):
    assert bench.main(["--list"]) == 0
    out = capsys.readouterr().out
    for name in ("physics", "codec", "bus", "lockstep", "scenario", "fmu"):
        assert any(line.split()[0] == name for line in out.splitlines()), name


def test_unknown_suite_exits_2_with_the_known_names(capsys):
    assert cli_main(["bench", "--suite", "codec", "--suite", "nosuch"]) == 2
    err = capsys.readouterr().err
    assert "unknown suite 'nosuch'" in err and "codec" in err


@pytest.mark.slow
def test_codec_quick_writes_json_and_prints_a_table(tmp_path):
    out = tmp_path / "bench.json"
    p = subprocess.run([sys.executable, "-m", "diffbot.cli", "bench", "--suite", "codec",
                        "--quick", "--json", str(out)], cwd=ROOT, capture_output=True, text=True,
                       timeout=90)
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    m = doc["machine"]
    assert m["cpu_count"] >= 1 and m["python"]
    assert m["versions"]["dartpy"] and m["versions"]["eclipse-zenoh"]
    assert doc["suites"][0]["name"] == "codec" and doc["suites"][0]["status"] == "ok"
    names = {c["name"] for c in doc["cases"]}
    for t in ("JointState", "TwistStamped", "Odometry", "PointStamped", "Clock",
              "Image 160x120 rgb8", "LaserScan 180 rays"):
        assert {f"encode {t}", f"decode {t}"} <= names
    for c in doc["cases"]:
        assert CASE_KEYS <= set(c), c
        assert c["suite"] == "codec" and c["unit"] == "s"
        assert c["repeats"] == len(c["samples"]) == bench.QUICK_REPEATS
        assert 0 < c["min"] <= c["median"] <= c["max"]
        assert " B" in c["notes"]
    # the table: a header with the machine facts, then one aligned row per case
    assert "CPUs" in p.stdout and "dartpy" in p.stdout and "eclipse-zenoh" in p.stdout
    rows = [ln for ln in p.stdout.splitlines() if ln.startswith("codec ")]
    assert len(rows) == len(doc["cases"])
    header = next(ln for ln in p.stdout.splitlines() if ln.startswith("suite "))
    n_end = header.index(" n ") + 2                             # the n column is right-aligned
    assert {re.search(r"(?<= )\d+x\d+(?=  )", r).end() for r in rows} == {n_end}
    assert "[codec]" in p.stderr                                # progress goes to stderr
    assert "[codec]" not in p.stdout


@pytest.mark.slow
def test_a_failing_case_is_reported_and_the_suite_releases_its_resources(tmp_path, monkeypatch,
                                                                         capsys):
    released = []

    def boom(ctx):
        try:
            yield bench.Case("works", lambda: None, notes="no-op")
            yield bench.Case("fails", lambda: 1 / 0)
        finally:
            released.append(True)
    monkeypatch.setitem(bench.SUITES, "boom", boom)
    out = tmp_path / "b.json"
    assert bench.main(["--suite", "boom", "--quick", "--repeats", "2", "--json", str(out)]) == 1
    assert released == [True]
    doc = json.loads(out.read_text())
    works, fails = doc["cases"]
    assert works["repeats"] == 2 and works["median"] > 0 and "error" not in works
    assert "ZeroDivisionError" in fails["error"]
    assert doc["suites"][0]["status"] == "error"
    assert "FAILED" in capsys.readouterr().out


def test_fmu_suite_is_skipped_without_fmus_bench(tmp_path, monkeypatch):
    monkeypatch.setattr("diffbot.bench.fmu.ROOT", str(tmp_path))
    results, status = bench.run_suite(bench.Context(quick=True), "fmu")
    assert results == []
    assert status["status"] == "skipped" and status["reason"] == "fmus/bench.py not available"


def _children_with(marker: bytes) -> list[int]:
    me, found = os.getpid(), []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmd = f.read()
        except (OSError, ValueError, IndexError):
            continue
        if ppid == me and marker in cmd:
            found.append(int(pid))
    return found


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_bus_suite_measures_a_round_trip_and_kills_its_echo_process(tmp_path, capsys):
    out = tmp_path / "bus.json"
    assert bench.main(["--suite", "bus", "--quick", "--repeats", "1", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert [c["name"] for c in doc["cases"]] == ["round trip 64 B",
                                                 "round trip 57.6 KB (160x120 rgb8)"]
    assert all(c["median"] > 0 for c in doc["cases"])
    assert _children_with(b"--echo") == []


@pytest.mark.slow
def test_sensor_suites_time_the_lidar_sweep_and_camera_frames(tmp_path):
    out = tmp_path / "sensors.json"
    assert bench.main(["--suite", "lidar,camera", "--quick", "--repeats", "1",
                       "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    names = {c["name"] for c in doc["cases"]}
    assert {"sweep 180 rays", "render 160x120", "render 320x240"} <= names
    assert all(c["median"] > 0 for c in doc["cases"])
    sweep = next(c for c in doc["cases"] if c["name"] == "sweep 180 rays")
    assert "32 shapes" in sweep["notes"] and "180 rays" in sweep["notes"]


def test_tick_profile_puts_each_main_thread_sample_in_its_innermost_phase():
    from diffbot.bench import tick
    root = ("_run_module_as_main (<frozen runpy>:198);main (plant/process.py:795);"
            "Plant.run (plant/process.py:590)")
    pub = "Plant._publish (plant/process.py:252);Plant.publish_sensors (plant/process.py:224)"
    raw = "\n".join([
        f"{root};{pub};RobotSensors.messages (plant/sensors.py:9);"
        "render (plant/camera.py:1);render_full (plant/camera.py:2) 6",
        f"{root};{pub};Outbox.put (plant/outbox.py:76);"
        "encode (bus/codec.py:53);_fast_image (bus/codec.py:99) 3",
        f"{root};{pub};Outbox.put (plant/outbox.py:76) 2",
        f"{root};Stepper.start (plant/stepper.py:1);Simulation.step_tick (plant/sim.py:2) 4",
        f"{root};Plant.run (plant/process.py:600) 1",
        "Thread-1 (zenoh);Inbox._on_sample (bus/inbox.py:40) 50",      # not the main thread
        "garbage line",
    ])
    p = tick.summarise(tick.parse_raw(raw))
    assert p["samples"] == 16
    assert p["phases"]["camera render"] == pytest.approx(6 / 16)
    assert p["phases"]["encode"] == pytest.approx(3 / 16)
    assert p["phases"]["zenoh put"] == pytest.approx(2 / 16)
    assert p["phases"]["physics"] == pytest.approx(4 / 16)
    assert p["phases"]["other"] == pytest.approx(1 / 16)
    assert sum(p["phases"].values()) == pytest.approx(1.0)
    assert p["self"][0] == ("render_full (plant/camera.py)", pytest.approx(6 / 16))
    assert ("Outbox.put (plant/outbox.py)", pytest.approx(5 / 16)) in p["inclusive"]


def test_scenario_suite_sets_each_run_beside_dart_alone_in_its_world(monkeypatch):
    """Every scenario run reports its share of DART alone, in wall and in CPU time, timed in
    the scenario's world (with the scenario's world overrides) right after it; the targets
    stand in the pipelined rows (the scenarios' coupling)."""
    from diffbot.bench import scenario as sc
    from diffbot.launch.scenario import load_scenario
    worlds, runs = [], []

    def alone(world, ticks=sc.ALONE_TICKS, chunks=sc.ALONE_CHUNKS, sets=()):
        worlds.append((world, tuple(sets)))
        return {"real_time_factor": 80.0 if world == "living_room" else 40.0,
                "cpu_real_time_factor": 90.0, "tick_s": 2.5e-4, "cpu_tick_s": 2e-4}

    def run(ctx, name, timeout_s, *extra):
        runs.append((name, extra))
        return {"real_time_factor": 20.0, "wall_time_s": 3.0, "sim_time_s": 50.0,
                "cpu_per_tick_ms": {"plant": 0.8}}
    monkeypatch.setattr(sc, "dart_alone", alone)
    monkeypatch.setattr(sc, "run_scenario", run)
    results, status = bench.run_suite(bench.Context(quick=True), "scenario")
    assert status["status"] == "ok", status
    follow_sets = tuple(sc.world_sets(load_scenario("follow").plant_args))
    assert follow_sets and all(s.startswith("robots.follower.") for s in follow_sets)
    assert len(runs) == 8 and worlds.count(("living_room", ())) == 5   # 1 row + 4 runs each
    assert worlds.count(("living_room_follow", follow_sets)) == 5
    by = {r.name: r for r in results}
    assert by["square: DART alone (living_room): control-tick rate"].samples == [80.0]
    assert by["square, pipelined, composed: share of DART alone"].samples == [0.25]
    assert by["square, pipelined, composed: share of DART alone"].target == ">= 0.5"
    assert by["follow, sequential, composed: share of DART alone"].samples == [0.5]
    assert by["follow, sequential, composed: share of DART alone"].target == ""
    assert by["follow, pipelined, composed: real-time factor"].target == ">= 18x"
    assert by["square, pipelined, processes: real-time factor"].target == ">= 16x"
    assert by["follow, pipelined, processes: real-time factor"].target == ">= 8.5x"
    assert by["square, sequential, composed: DART alone beside it"].samples == [80.0]
    assert by["square, pipelined, composed: share of DART alone (CPU)"].samples == [
        pytest.approx(0.25)]                                  # 0.2 ms of DART, 0.8 of plant


def test_dart_alone_steps_the_worlds_control_tick():
    from diffbot.bench.scenario import dart_alone
    from plant.world import load_world
    got = dart_alone("living_room", ticks=3, chunks=1)
    tick_s = load_world("living_room").control_tick_s
    assert got["tick_s"] > 0 and got["cpu_tick_s"] > 0
    assert got["real_time_factor"] == pytest.approx(tick_s / got["tick_s"])
    assert got["cpu_real_time_factor"] == pytest.approx(tick_s / got["cpu_tick_s"])


def test_a_scenario_s_world_overrides_are_its_dart_alone_s():
    """DART alone loads the scenario's world as its plant does: with the ``--set``
    overrides among its ``plant_args`` (either spelling, in order), nothing else."""
    from diffbot.bench.scenario import world_sets
    assert world_sets(["--disable", "camera", "--set", "a.b=1", "--set=c=2", "--seed", "3",
                       "--set", "a.b=4"]) == ["a.b=1", "c=2", "a.b=4"]
    assert world_sets(["--disable", "camera"]) == [] == world_sets(["--set"])


def test_the_steered_swarm_bound_steps_robots_their_avoid_drives(tmp_path):
    """The dynamic swarm's bound in `diffbot bench --suite swarm`: DART stepping robots that
    the swarm's avoid controller steers on their scans (they move, and every robot stands on
    the floor: 3 contacts each at least), only the steps timed."""
    from diffbot.bench.swarm import steered_physics_rtf
    got = steered_physics_rtf(3, str(tmp_path), 2.0)
    assert 0 < got["physics_share"] <= 1, got
    assert got["contacts"] >= 9, got
    assert got["travel_m"] > 0.2, got
    # the steps' CPU a tick, told beside the composed run's physics process's
    assert got["cpu_ms_per_tick"] > 0, got


def test_the_composed_dynamic_swarm_is_told_as_a_share_of_the_bounds_before_it(monkeypatch):
    """The composed run's real-time factor over the bounds the suite measured just before
    it (open-loop and steered), and its physics process's CPU over DART's steered."""
    from diffbot.bench import swarm
    monkeypatch.setattr(swarm, "composed_run", lambda ctx, n, mode, duration: {
        "real_time_factor": 4.0, "physics_cpu_ms_per_tick": 4.5})
    bound = {"open": {"real_time_factor": 8.0}, "steered": {"real_time_factor": 5.0,
                                                           "cpu_ms_per_tick": 3.6}}
    got = swarm.composed_beside(None, 24, "dynamic", "2", bound)
    assert got["share_of_open"] == 0.5 and got["share_of_steered"] == 0.8
    assert got["physics_cpu_over_steered"] == 4.5 / 3.6
    assert "share_of_open" not in swarm.composed_beside(None, 24, "dynamic", "2", {})
    kept: dict = {}
    assert swarm._kept(kept, "open", lambda: {"real_time_factor": 2.0})() == kept["open"]
