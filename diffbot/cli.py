"""The ``diffbot`` command: a thin layer over the library.

    diffbot run SCENARIO ...        start a scenario's processes together and supervise them
    diffbot plant ...               the DART plant alone
    diffbot controller NAME ...     one controller (square_path, teleop, odometry, wheel_schedule,
                                    wander, ball_follower, avoid, policy), or any controller
                                    class: python:MODULE:CLASS or PATH.py[:CLASS] (--arg K=V)
    diffbot fmu build [--out DIR]   build the odometry FMUs (FMI 2.0 and 3.0) into fmus/build
    diffbot fmu export-plant --out robot.fmu   the DART plant as a co-simulation FMU (FMI 3 or 2)
    diffbot fmu export-ssp --out square.ssp    the square as an SSP: plant, odometry, controller
    diffbot fmu-node FMU --robot R  run a co-simulation FMU as a bus node (--mapping FILE)
    diffbot bench ...               benchmarks
    diffbot experiment NAME ...     the study's sensor experiments, --out DIR (-h lists them)
    diffbot figures --out DIR       all twelve figures of the study + index.html (--only 4,12)
    diffbot sweep SCENARIO ...      a scenario over a grid of parameters x seeds, local or on Ray
    diffbot record FILE.mcap [KEYS] record the bus into MCAP (Foxglove, ros2 bag, rosbags)
    diffbot replay FILE.mcap        play a recording back onto the bus (--rate R | --fast)
    diffbot view [--port 8765]      watch live in Foxglove (3D, lidar, camera, plots) + teleop
    diffbot topics [--duration S]   live keys with message type and rate
    diffbot echo KEY [--count N]    print a key's messages, decoded
    diffbot ros2 [--lockstep]       bridge the bus to ROS 2 (rclpy; `pip install -e '.[ros2]'`)
    diffbot router --listen E       a Zenoh router for several machines (--zenoh-config FILE)
    diffbot certs --out DIR         a test CA and TLS certificates for router and clients
    diffbot scenarios               list the scenarios
"""
from __future__ import annotations

import importlib
import signal
import sys

from bus.cliargs import did_you_mean

from .launch.members import CONTROLLERS, compose_member, hosted

USAGE = __doc__
#: the sub-commands (for "did you mean")
COMMANDS = ("run", "plant", "controller", "fmu", "fmu-node", "bench", "experiment", "figures",
            "sweep", "record", "replay", "topics", "echo", "router", "ros2", "scenarios",
            "certs", "view")


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
    # Sub-commands' parsers take their program name from argv[0]: make `--help` and usage
    # lines say `diffbot controller square_path`, not `cli.py` or `diffbot`.
    sys.argv[0] = f"diffbot {cmd}"
    if cmd == "plant":
        from plant.process_cli import main as plant_main
        return plant_main(rest, compose=compose_member)
    if cmd == "controller":
        if not rest or rest[0] in ("-h", "--help"):
            print(f"usage: diffbot controller {{{','.join(CONTROLLERS)}}} [options]\n"
                  "       diffbot controller python:MODULE:CLASS|PATH.py[:CLASS] [--arg K=V] "
                  "[options]\n"
                  "  (diffbot controller NAME --help for a controller's options)",
                  file=sys.stderr if not rest else sys.stdout)
            return 2 if not rest else 0
        if hosted(rest[0]):
            from controllers.hosted import main as hosted_main
            sys.argv[0] = f"diffbot controller {rest[0]}"
            return hosted_main(rest[0], rest[1:])
        if rest[0] not in CONTROLLERS:
            print(f"diffbot controller: unknown controller {rest[0]!r}"
                  f"{did_you_mean(rest[0], CONTROLLERS)} (choose from "
                  f"{', '.join(CONTROLLERS)})", file=sys.stderr)
            return 2
        sys.argv[0] = f"diffbot controller {rest[0]}"
        return importlib.import_module(CONTROLLERS[rest[0]]).main(rest[1:])
    if cmd == "run":
        from .launch.launcher import main as run_main
        return run_main(rest)
    if cmd == "scenarios":
        from .launch.scenario import list_scenarios
        for name, desc in list_scenarios():
            print(f"{name:14s} {desc}")
        return 0
    if cmd == "fmu":
        if rest[:1] == ["build"]:
            from fmus.build import main as build_main
            return build_main(rest[1:], prog="diffbot fmu build")
        if rest[:1] == ["export-plant"]:
            from fmus.plant_export import main as export_main
            return export_main(rest[1:], prog="diffbot fmu export-plant")
        if rest[:1] == ["export-ssp"]:
            from fmus.plant_ssp import main as ssp_main
            return ssp_main(rest[1:], prog="diffbot fmu export-ssp")
        print("usage: diffbot fmu build [--out DIR]\n"
              "       diffbot fmu export-plant [--world W] [--robots R ...] [--fmi 3|2] "
              "--out robot.fmu\n"
              "       diffbot fmu export-ssp [--fmi 2|3] --out square.ssp", file=sys.stderr)
        return 2
    if cmd == "fmu-node":
        from fmus.fmu_node_cli import main as fmu_node_main
        return fmu_node_main(rest)
    if cmd == "experiment":
        from .study.experiment_cli import main as experiment_main
        return experiment_main(rest)
    if cmd == "figures":
        from .study.figures_cli import main as figures_main
        return figures_main(rest)
    if cmd == "sweep":
        from .sweep import main as sweep_main
        return sweep_main(rest)
    if cmd == "bench":
        from .bench import main as bench_main
        return bench_main(rest)
    if cmd == "router":
        from .launch.router import main as router_main
        return router_main(rest)
    if cmd == "certs":
        from .launch.certs import main as certs_main
        return certs_main(rest)
    if cmd == "ros2":
        from bridges.ros2 import main as ros2_main
        return ros2_main(rest)
    if cmd == "record":
        from bridges.record import main as record_main
        return record_main(rest)
    if cmd == "replay":
        from bridges.replay import main as replay_main
        return replay_main(rest)
    if cmd == "view":
        from bridges.view_cli import main as view_main
        return view_main(rest)
    if cmd == "topics":
        from bridges.topics import topics_main
        return topics_main(rest)
    if cmd == "echo":
        from bridges.topics import echo_main
        return echo_main(rest)
    print(f"diffbot: unknown command {cmd!r}{did_you_mean(cmd, COMMANDS)}\n\n{USAGE.strip()}",
          file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
