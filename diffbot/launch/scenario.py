"""Scenario files: which world, which processes, which analysis.

A scenario is a TOML file (shipped ones live in ``diffbot/launch/scenarios/``)::

    [scenario]
    world = "living_room"      # world name or path
    mode = "lockstep"          # lockstep | realtime | fast
    coupling = "sequential"    # lockstep: sequential | pipelined (docs/PROTOCOL.md)
    physics_process = false    # DART in a process of its own (worth it for many robots)
    duration_s = 300.0        # upper bound in simulated time (optional)
    analysis = "square"        # what to plot and summarise afterwards
    robot = "robot1"           # the robot the analysis looks at
    plant_args = ["--disable", "camera"]   # extra `diffbot plant` arguments
    ros2_drives = false        # ROS 2 nodes drive the robots: with --ros2 in lockstep the
                               # bridge is the lockstep member (and its end ends the run)

    [[process]]
    name = "square_path_robot1"
    command = ["controller", "square_path", "--robot", "robot1"]   # diffbot arguments
    required = true            # its death ends the run (default true)
    ends_run = false           # its normal exit ends the run successfully
    sync = true                # a lockstep member the plant waits for (default true)
    interactive = false        # keeps the terminal (teleop)

    [[process]]                # any program, not only diffbot's (instead of command)
    name = "my_agent"
    exec = ["python3", "my_agent.py", "--name", "{name}", "{bus}"]
    # placeholders: {name} (the process name: its node name), {bus} (the bus options,
    # --endpoint E [--namespace N] [--zenoh-config F], as separate words), {endpoint},
    # {namespace}, {python} (this interpreter), {out} (the run's output directory);
    # {{ and }} for literal braces. As written, no --name/--stats/bus options are added;
    # it is never composed. A lockstep member (sync = true) must join as {name}.

Errors are ``file:key: reason`` (:class:`plant.world.WorldError`), exit 2.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

from bus.keys import check_name
from bus.protocol import COUPLINGS
from plant.tomlfile import Table, WorldError, read_toml, shipped_or_path, tomllib

SCENARIOS_DIR = os.path.join(os.path.dirname(__file__), "scenarios")
ANALYSES = ("square", "drive-test", "follow", "swarm", "none")


@dataclass
class ProcessSpec:
    name: str
    command: list[str]
    required: bool = True
    ends_run: bool = False
    sync: bool = True
    interactive: bool = False
    #: ``compose = false``: stays a process when the run composes its members
    compose: bool = True
    #: ``exec = [...]``: any program, run as written (placeholders expanded); command is []
    exec: list[str] | None = None


@dataclass
class ScenarioSpec:
    name: str
    path: str
    description: str = ""
    world: str = "living_room"
    mode: str = "lockstep"
    coupling: str = "sequential"
    physics_process: bool = False
    #: host the lockstep members in the plant's process (docs/scenarios.md, "Composed members")
    compose: bool = False
    duration_s: float | None = None
    analysis: str = "none"
    robot: str = "robot1"
    plant_args: list[str] = field(default_factory=list)
    ros2_drives: bool = False
    processes: list[ProcessSpec] = field(default_factory=list)
    #: a generated world (``generate = "swarm"``): the robot count is a run parameter
    #: (``robots``, default; ``diffbot run --robots N``), the world file is written into the
    #: run's output directory, and ``controller`` drives every robot from
    #: ``controller_processes`` processes (0: one process per robot)
    generate: str = ""
    robots: int = 0
    controller: str = ""
    controller_processes: int = 0


def scenario_path(name_or_path: str) -> str:
    """A scenario file as given, or the name of a shipped one (``square``, ``follow``)."""
    return shipped_or_path(name_or_path, SCENARIOS_DIR, "scenario")


def load_scenario(name_or_path: str) -> ScenarioSpec:
    path = scenario_path(name_or_path)
    top = Table(path, "", read_toml(path))
    s = top.table("scenario")
    spec = ScenarioSpec(name=os.path.splitext(os.path.basename(path))[0], path=path)
    spec.description = s.string("description", "")
    spec.world = s.string("world", "living_room")
    spec.mode = s.string("mode", "lockstep", choices=("lockstep", "realtime", "fast"))
    spec.coupling = s.string("coupling", "sequential", choices=COUPLINGS)
    spec.physics_process = s.boolean("physics_process", False)
    spec.compose = s.boolean("compose", False)
    spec.duration_s = s.number("duration_s", -1.0)
    if spec.duration_s == -1.0:
        spec.duration_s = None
    elif spec.duration_s <= 0:
        s.fail("duration_s", f"must be > 0, got {spec.duration_s:g}")
    spec.analysis = s.string("analysis", "none", choices=ANALYSES)
    spec.robot = s.string("robot", "robot1")
    plant_args = s.raw("plant_args", [])
    if not isinstance(plant_args, list) or not all(isinstance(a, str) for a in plant_args):
        s.fail("plant_args", "expected a list of strings (extra `diffbot plant` arguments)")
    spec.plant_args = list(plant_args)
    spec.ros2_drives = s.boolean("ros2_drives", False)
    spec.generate = s.string("generate", "", choices=("", "swarm"))
    if spec.generate:
        spec.robots = s.integer("robots", 8)
        if spec.robots < 1:
            s.fail("robots", f"must be >= 1, got {spec.robots}")
        spec.controller = s.string("controller", "avoid")
        spec.controller_processes = s.integer("controller_processes", 3)
        if spec.controller_processes < 0:
            s.fail("controller_processes", f"must be >= 0, got {spec.controller_processes}")
    s.done()
    names = set()
    for t in top.tables("process"):
        name = t.string("name")
        if name in names or name == "plant":
            t.fail("name", f"duplicate or reserved process name {name!r}")
        try:
            check_name(name, "process name")      # it becomes the node's name on the bus
        except ValueError as exc:
            t.fail("name", str(exc))
        names.add(name)
        cmd, exe = t.raw("command", None), t.raw("exec", None)
        if (cmd is None) == (exe is None):
            t.fail("command", "give one of command (diffbot arguments) and exec (any program)")
        key, val = ("command", cmd) if exe is None else ("exec", exe)
        if not isinstance(val, list) or not val or not all(isinstance(c, str) for c in val):
            t.fail(key, "expected a non-empty list of strings ("
                   + ("diffbot arguments)" if exe is None else "a program and its arguments)"))
        if exe is not None:
            try:
                expand(exe, {k: "" for k in PLACEHOLDERS})
            except (KeyError, ValueError, IndexError) as exc:
                t.fail("exec", f"bad placeholder {exc} (known: "
                               f"{', '.join('{' + k + '}' for k in PLACEHOLDERS)})")
        spec.processes.append(ProcessSpec(
            name=name, command=list(cmd or []), required=t.boolean("required", True),
            ends_run=t.boolean("ends_run", False), sync=t.boolean("sync", True),
            interactive=t.boolean("interactive", False), compose=t.boolean("compose", True),
            exec=None if exe is None else list(exe)))
        t.done()
    if spec.generate and spec.processes:
        top.fail("process", f"a generated-world scenario (generate = {spec.generate!r}) makes "
                            "its own processes (controller, controller_processes)")
    top.done()
    return spec


#: what an ``exec`` process's words may name (``{bus}`` alone as a word: several words)
PLACEHOLDERS = ("name", "bus", "endpoint", "namespace", "python", "out")


def expand(words: list[str], values: dict) -> list[str]:
    """An ``exec`` command with its placeholders filled (``values``: name -> str, and
    ``bus`` -> list of words, spliced where ``{bus}`` stands alone)."""
    out = []
    for w in words:
        if w == "{bus}":
            out += list(values["bus"])
        else:
            out.append(w.format_map({k: (" ".join(v) if isinstance(v, list) else v)
                                     for k, v in values.items()}))
    return out


def list_scenarios() -> list[tuple[str, str]]:
    out = []
    for f in sorted(os.listdir(SCENARIOS_DIR)):
        if f.endswith(".toml"):
            try:
                with open(os.path.join(SCENARIOS_DIR, f), "rb") as fh:
                    desc = tomllib.load(fh).get("scenario", {}).get("description", "")
            except Exception:
                desc = ""
            out.append((f[:-5], desc))
    return out


def print_scenarios(argv: list[str]) -> int:
    """``diffbot scenarios``: each shipped scenario's name and description, a line each."""
    for name, desc in list_scenarios():
        print(f"{name:14s} {desc}")
    return 0
