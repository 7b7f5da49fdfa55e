"""The commands that make a bus member: which module runs each controller, and a member's
command line turned into the member itself, to compose into the plant's process
(docs/scenarios.md, "Composed members")."""
from __future__ import annotations

import importlib
import shlex
import sys

from bus.cliargs import did_you_mean

#: controller name -> module with a main(argv) function (`diffbot controller NAME`)
CONTROLLERS = {
    "square_path": "controllers.square_path",
    "teleop": "controllers.teleop",
    "odometry": "controllers.odometry_node",
    "wheel_schedule": "controllers.scripted",
    "wander": "controllers.wander",
    "ball_follower": "controllers.ball_follower",
    "avoid": "controllers.avoid",
    "policy": "controllers.learned",
}

#: controllers that cannot be composed into the plant: they keep threads of their own
NOT_COMPOSABLE = {"teleop": "it reads the keyboard on a thread of its own"}


def member_main(argv: list[str]):
    """(main, its argv) of a member's command line (``controller NAME ...`` or
    ``fmu-node ...``); ValueError if the command cannot be a composed member."""
    if argv[:1] == ["controller"] and len(argv) > 1 and hosted(argv[1]):
        from controllers.hosted import main as hosted_main
        target = argv[1]
        return (lambda rest: hosted_main(target, rest)), argv[2:]
    if argv[:1] == ["controller"] and len(argv) > 1 and argv[1] in CONTROLLERS:
        if argv[1] in NOT_COMPOSABLE:
            raise ValueError(f"controller {argv[1]} cannot be composed: "
                             f"{NOT_COMPOSABLE[argv[1]]}; run it as a process")
        return importlib.import_module(CONTROLLERS[argv[1]]).main, argv[2:]
    if argv[:1] == ["fmu-node"]:
        from fmus.fmu_node_cli import main as fmu_node_main
        return fmu_node_main, argv[1:]
    raise ValueError(f"{' '.join(argv)!r} cannot be composed into the plant: only "
                     "`controller NAME ...` and `fmu-node FMU ...` members can")


def hosted(name: str) -> bool:
    """A controller class to host (controllers/hosted.py): python:MODULE:CLASS or a .py path."""
    from controllers.hosted import is_target
    return is_target(name)


def compose_member(command: str | list[str]):
    """The member a command line makes (``"controller square_path --robot robot1"``), built
    by that command's own parser (bus.node.capture_member), to compose into the plant."""
    from bus.node import capture_member
    argv = shlex.split(command) if isinstance(command, str) else list(command)
    main, rest = member_main(argv)
    return capture_member(main, rest)


def controller_main(argv: list[str]) -> int:
    """``diffbot controller NAME ...``: a shipped controller by name, or a controller class
    (:func:`hosted`), on its own command line."""
    if not argv or argv[0] in ("-h", "--help"):
        print(f"usage: diffbot controller {{{','.join(CONTROLLERS)}}} [options]\n"
              "       diffbot controller python:MODULE:CLASS|PATH.py[:CLASS] [--arg K=V] "
              "[options]\n"
              "  (diffbot controller NAME --help for a controller's options)",
              file=sys.stderr if not argv else sys.stdout)
        return 2 if not argv else 0
    if hosted(argv[0]):
        from controllers.hosted import main as hosted_main
        sys.argv[0] = f"diffbot controller {argv[0]}"
        return hosted_main(argv[0], argv[1:])
    if argv[0] not in CONTROLLERS:
        print(f"diffbot controller: unknown controller {argv[0]!r}"
              f"{did_you_mean(argv[0], CONTROLLERS)} (choose from "
              f"{', '.join(CONTROLLERS)})", file=sys.stderr)
        return 2
    sys.argv[0] = f"diffbot controller {argv[0]}"
    return importlib.import_module(CONTROLLERS[argv[0]]).main(argv[1:])


def plant_main(argv: list[str]) -> int:
    """``diffbot plant ...``: the plant process, its ``--compose`` members built here."""
    from plant.process_cli import main
    return main(argv, compose=compose_member)
