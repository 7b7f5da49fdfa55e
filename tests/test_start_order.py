"""Which processes of a run start with the plant (docs/scenarios.md, "diffbot run"): the
recorder, the view and the scenario's ``diffbot`` members start beside it, so their start-up
overlaps its, and a plant that waits for its members before the first tick also waits for
the observer, the recorder and the view (``--wait-for``): each sees the whole run. ``exec``
programs, a placed run's processes, and every process of a run whose plant waits for no one
start once the plant listens, as before. The runs themselves: every test that runs a
scenario (tests/test_scenarios.py, tests/test_record_replay.py, ...)."""
from __future__ import annotations

from diffbot.scenario import ProcessSpec, load_scenario
from diffbot.scenario_run import ScenarioRun


def built(tmp_path, mode="lockstep", record=None, view=False, **kw) -> ScenarioRun:
    spec = load_scenario("square")
    spec.processes.append(ProcessSpec(name="mine", command=[],
                                      exec=["{python}", "agent.py", "{bus}"]))
    run = ScenarioRun(spec, str(tmp_path), mode, 0, "unixsock-stream//tmp/x.sock",
                      record=record, **kw)
    if view:
        run.view_port, run.view_host = 8765, "127.0.0.1"
    run.build()
    return run


def option(argv: list[str], name: str) -> str | None:
    return argv[argv.index(name) + 1] if name in argv else None


def test_members_recorder_and_view_start_with_a_plant_that_waits_for_them(tmp_path):
    run = built(tmp_path, record=str(tmp_path / "r.mcap"), view=True)
    plant = run.children[0].argv
    assert option(plant, "--wait-for") == "observer,recorder,view"
    assert option(plant, "--expect").split(",") == ["odometry_robot1", "square_path_robot1",
                                                     "mine"]
    assert [c.name for c in run.early()] == ["recorder", "view", "odometry_robot1",
                                             "square_path_robot1"]     # not the exec one
    run.placement = object()          # (a placed run: Ray tasks, started once the plant listens)
    assert run.early() == []


def test_a_realtime_run_starts_its_members_early_only_if_its_plant_waits_for_them(tmp_path):
    run = built(tmp_path, mode="realtime")
    # its members are sync (the default): the plant waits for them, and for the observer
    assert option(run.children[0].argv, "--wait-for") == "observer"
    assert [c.name for c in run.early()] == ["odometry_robot1", "square_path_robot1"]
    for p in run.spec.processes:
        p.sync = False
    run.children = []
    run.build()
    assert "--wait-for" not in run.children[0].argv and run.early() == []
