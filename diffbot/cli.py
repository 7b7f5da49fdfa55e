"""The ``diffbot`` command: a thin layer over the library.

Its commands are one table, :data:`COMMANDS`: a name, the arguments the usage shows, the
function that runs it (``module:function``, imported only when that command runs), one help
line and the manual's page. The usage (``diffbot --help``), the dispatch and the README's
commands table (:func:`commands_table`, compared with the README by the docs' tests) are
all made from it, so a command is added in one place.
"""
from __future__ import annotations

import importlib
import signal
import sys
from typing import NamedTuple

from bus.cliargs import did_you_mean


class Command(NamedTuple):
    """One row of the command table. A name of two words is a sub-command of a group
    (``fmu build``); its function is called with ``prog=`` the words a user typed."""
    name: str
    args: str           # after the name in the usage, e.g. "SCENARIO ..."
    target: str         # "module:function"; the function takes the rest of argv
    help: str           # one line; a "\n" breaks it in the usage only
    docs: str = ""      # the manual's page for it, a Markdown link


COMMANDS: tuple[Command, ...] = (
    Command("run", "SCENARIO ...", "diffbot.launch.launcher:main",
            "start a scenario's processes together and supervise them",
            "[scenarios](docs/scenarios.md)"),
    Command("plant", "...", "diffbot.launch.members:plant_main", "the DART plant alone",
            "[scenarios](docs/scenarios.md#world-files), [topics](docs/topics.md)"),
    Command("controller", "NAME ...", "diffbot.launch.members:controller_main",
            "one controller (square_path, teleop, odometry, wheel_schedule,\n"
            "wander, ball_follower, avoid, policy), or any controller\n"
            "class: python:MODULE:CLASS or PATH.py[:CLASS] (--arg K=V)",
            "[controllers](docs/controllers.md#starting-the-pieces-by-hand), "
            "[learning](docs/learning.md)"),
    Command("fmu build", "[--out DIR]", "fmus.build:main",
            "build the odometry FMUs (FMI 2.0 and 3.0) into fmus/build",
            "[fmu](docs/fmu.md#the-odometry-fmu)"),
    Command("fmu export-plant", "--out robot.fmu", "fmus.plant_export:main",
            "the DART plant as a co-simulation FMU (FMI 3 or 2)",
            "[fmu](docs/fmu.md#the-robot-as-an-fmu-diffbot-fmu-export-plant)"),
    Command("fmu export-ssp", "--out square.ssp", "fmus.plant_ssp:main",
            "the square as an SSP: plant, odometry, controller",
            "[fmu](docs/fmu.md#the-whole-square-as-an-ssp-run-from-a-masters-command-line)"),
    Command("fmu-node", "FMU --robot R", "fmus.fmu_node_cli:main",
            "run a co-simulation FMU as a bus node (--mapping FILE)", "[fmu](docs/fmu.md)"),
    Command("bench", "...", "diffbot.bench:main", "benchmarks",
            "[benchmarks](docs/benchmarks.md)"),
    Command("experiment", "NAME ...", "diffbot.study.experiment_cli:main",
            "the study's sensor experiments, --out DIR (-h lists them)",
            "[study](docs/study.md#the-experiments-alone)"),
    Command("figures", "--out DIR", "diffbot.study.figures_cli:main",
            "all twelve figures of the study + index.html (--only 4,12)",
            "[study](docs/study.md)"),
    Command("sweep", "SCENARIO ...", "diffbot.sweep:main",
            "a scenario over a grid of parameters x seeds, local or on Ray",
            "[sweeps](docs/sweeps.md)"),
    Command("record", "FILE.mcap [KEYS]", "bridges.record:main",
            "record the bus into MCAP (Foxglove, ros2 bag, rosbags)",
            "[recording](docs/recording.md)"),
    Command("replay", "FILE.mcap", "bridges.replay:main",
            "play a recording back onto the bus (--rate R | --fast)",
            "[recording](docs/recording.md)"),
    Command("view", "[--port 8765]", "bridges.view_cli:main",
            "watch live in Foxglove (3D, lidar, camera, plots) + teleop",
            "[live view](docs/live-view.md)"),
    Command("topics", "[--duration S]", "bridges.topics:topics_main",
            "live keys with message type and rate",
            "[recording](docs/recording.md#looking-at-a-live-bus)"),
    Command("echo", "KEY [--count N]", "bridges.topics:echo_main",
            "print a key's messages, decoded",
            "[recording](docs/recording.md#looking-at-a-live-bus)"),
    Command("ros2", "[--lockstep]", "bridges.ros2:main",
            "bridge the bus to ROS 2 (rclpy; `pip install -e '.[ros2]'`)",
            "[ROS 2](docs/ros2.md)"),
    Command("router", "--listen E", "diffbot.launch.router:main",
            "a Zenoh router for several machines (--zenoh-config FILE)",
            "[several machines](docs/several-machines.md)"),
    Command("certs", "--out DIR", "diffbot.launch.certs:main",
            "a test CA and TLS certificates for router and clients",
            "[several machines](docs/several-machines.md)"),
    Command("scenarios", "", "diffbot.launch.scenario:print_scenarios", "list the scenarios",
            "[scenarios](docs/scenarios.md)"),
)

#: the usage's first column; the commands wider than it line their help up together
_COLUMN = 32


TITLE = "The ``diffbot`` command: a thin layer over the library."


def usage(rows: tuple[Command, ...] | None = None, title: str = TITLE) -> str:
    """The usage text of ``rows`` (every command): a line per command, its help beside it."""
    rows = COMMANDS if rows is None else rows
    lines = [title, ""] if title else []
    lefts = [" ".join(w for w in ("diffbot", c.name, c.args) if w) for c in rows]
    wide = max([len(left) + 3 for left in lefts if len(left) >= _COLUMN], default=0)
    for c, left in zip(rows, lefts):
        first, *more = c.help.split("\n")
        lines.append(f"    {left.ljust(_COLUMN if len(left) < _COLUMN else wide)}{first}")
        lines += [" " * (4 + _COLUMN) + m for m in more]
    return "\n".join(lines)


def commands_table() -> str:
    """The README's commands table (Markdown), one row per command."""
    out = ["| command | what it does | more |", "|---|---|---|"]
    for c in COMMANDS:
        words = " ".join(w for w in ("diffbot", c.name, c.args) if w)
        said = " ".join(c.help.split()).replace("|", "\\|")     # a bar would end the cell
        out.append(f"| `{words}` | {said} | {c.docs} |")
    return "\n".join(out)


def names() -> list[str]:
    """The first words a user may type (a group once), in the table's order."""
    return list(dict.fromkeys(c.name.split()[0] for c in COMMANDS))


def main(argv: list[str] | None = None) -> int:
    code = _dispatch(argv)
    # A stop signal arriving while the interpreter shuts down (handlers are reset then)
    # would turn a clean exit into death by signal: ignore them from here on.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return code


def _dispatch(argv: list[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    cmd, rest = argv[0], argv[1:]
    group = [c for c in COMMANDS if c.name.split()[0] == cmd and " " in c.name]
    if group:
        found = [c for c in group if c.name.split()[1:] == rest[:1]]
        if not found:
            asked = rest[:1] in (["-h"], ["--help"])
            print(f"usage: diffbot {cmd} SUB ... (diffbot {cmd} SUB --help for its "
                  f"options)\n\n{usage(group, title='')}",
                  file=sys.stdout if asked else sys.stderr)
            return 0 if asked else 2
        return _call(found[0], rest[1:], prog=f"diffbot {found[0].name}")
    for c in COMMANDS:
        if c.name == cmd:
            return _call(c, rest)
    print(f"diffbot: unknown command {cmd!r}{did_you_mean(cmd, names())}\n\n{usage()}",
          file=sys.stderr)
    return 2


def _call(command: Command, rest: list[str], **kw) -> int:
    """Import the command's function and run it on ``rest``."""
    # Sub-commands' parsers take their program name from argv[0]: make `--help` and usage
    # lines say `diffbot controller square_path`, not `cli.py` or `diffbot`.
    sys.argv[0] = f"diffbot {command.name}"
    module, _, function = command.target.partition(":")
    return getattr(importlib.import_module(module), function)(rest, **kw)


if __name__ == "__main__":
    sys.exit(main())
