"""The ``diffbot`` command: a thin layer over the library.

    diffbot run SCENARIO ...        start a scenario's processes together and supervise them
    diffbot plant ...               the DART plant alone
    diffbot controller NAME ...     one controller (square_path, teleop, odometry, wheel_schedule)
    diffbot fmu build [--out DIR]   build the odometry FMUs (FMI 2.0 and 3.0) into fmus/build
    diffbot fmu-node FMU --robot R  run a co-simulation FMU as a bus node (--mapping FILE)
    diffbot bench ...               benchmarks
    diffbot scenarios               list the scenarios
"""
from __future__ import annotations

import importlib
import signal
import sys

#: controller name -> module with a main(argv) function
CONTROLLERS = {
    "square_path": "controllers.square_path",
    "teleop": "controllers.teleop",
    "odometry": "controllers.odometry_node",
    "wheel_schedule": "controllers.scripted",
}

USAGE = __doc__


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
        print(USAGE.strip())
        return 0
    cmd, rest = argv[0], argv[1:]
    if cmd == "plant":
        from plant.node import main as plant_main
        return plant_main(rest)
    if cmd == "controller":
        if not rest or rest[0] not in CONTROLLERS:
            print(f"usage: diffbot controller {{{','.join(CONTROLLERS)}}} [options]",
                  file=sys.stderr)
            return 2
        return importlib.import_module(CONTROLLERS[rest[0]]).main(rest[1:])
    if cmd == "run":
        from .launcher import main as run_main
        return run_main(rest)
    if cmd == "scenarios":
        from .scenario import list_scenarios
        for name, desc in list_scenarios():
            print(f"{name:14s} {desc}")
        return 0
    if cmd == "fmu":
        if rest[:1] == ["build"]:
            from fmus.build import main as build_main
            return build_main(rest[1:])
        print("usage: diffbot fmu build [--out DIR]", file=sys.stderr)
        return 2
    if cmd == "fmu-node":
        from fmus.node import main as fmu_node_main
        return fmu_node_main(rest)
    if cmd == "bench":
        from .bench import main as bench_main
        return bench_main(rest)
    print(f"diffbot: unknown command {cmd!r}\n\n{USAGE.strip()}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
