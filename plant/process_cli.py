"""``diffbot plant``: the plant process's command line (:class:`plant.process.Plant`)."""
from __future__ import annotations


import argparse


from bus.cliargs import ArgumentParser, nonneg_float, nonneg_int, positive_float
from bus.composed import Composed
from bus.process import EXIT_BAD_CONFIG, EXIT_FAILED, Exit, Process, process_main
from bus.protocol import COUPLINGS
from bus.session import add_process_args

from . import modes
from .memory import keep_freed_memory
from .physics_process import PhysicsError
from .world import WorldError, load_world

from .process import Plant


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="diffbot plant", description="Run the DART plant on the bus.")
    p.add_argument("--world", default="living_room",
                   help="world file, or the name of a shipped world (living_room, empty)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a world-file value, e.g. world.mode=kinematic or "
                        "'robots.robot1.encoders.noise={webots_noise = 0.2}' (repeatable)")
    p.add_argument("--mode", choices=modes.MODES, default="lockstep")
    p.add_argument("--coupling", choices=COUPLINGS, default="sequential",
                   help="lockstep: sequential (commands of tick k from tick k's sensors act at "
                        "once; exact) or pipelined (the plant steps while the nodes compute: "
                        "commands act one tick later, node-to-node inputs are a tick old)")
    p.add_argument("--rate", type=positive_float, default=1.0,
                   help="realtime mode: simulated seconds per wall second (default 1)")
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="stop after S simulated seconds (default: run until stopped)")
    p.add_argument("--seed", type=nonneg_int, default=None, help="noise seed (default: the world's)")
    p.add_argument("--expect", default="", metavar="NODES",
                   help="lockstep: comma-separated members to wait for before the first tick")
    p.add_argument("--wait-for", default="", metavar="NODES",
                   help="comma-separated processes that are not lockstep members (a recorder) "
                        "to wait for, by their sim/alive token, before the first tick")
    p.add_argument("--join-timeout", type=positive_float, default=30.0, metavar="S",
                   help="how long to wait for the --expect members before the first tick "
                        "(then exit 1 naming the missing; default 30)")
    p.add_argument("--rejoin-timeout", type=nonneg_float, default=0.0, metavar="S",
                   help="lockstep: how long to hold simulated time for a member gone without "
                        "its FINAL (killed, frozen past the lease, router or link lost) to "
                        "come back; 0 (default): end the run at once, naming it, exit 1. "
                        "Announced in sim/info (rejoin_timeout_s): a node or recorder that "
                        "lost this plant waits as long (+ 2 s) for it, then exits 3")
    p.add_argument("--end-with", default="", metavar="NODES",
                   help="lockstep: stop, without stepping further, at the tick where one of "
                        "these members finishes (so a run's length is reproducible)")
    p.add_argument("--disable", default="", metavar="SENSORS",
                   help="comma-separated sensors of the world file to leave off: lidar, camera")
    p.add_argument("--physics-process", action="store_true",
                   help="step DART in a process of its own; with pipelined lockstep or fast "
                        "mode the plant then publishes tick k while the physics steps to k+1 "
                        "(two cores; same bytes)")
    p.add_argument("--compose", action="append", default=[], metavar="COMMAND",
                   help="host a member in this process instead of its own (composed), given "
                        "as its command line, e.g. \"controller square_path --robot robot1\" "
                        "or \"fmu-node odometry --robot robot1\"; repeatable (docs/scenarios.md)")
    add_process_args(p, "counters and timing")
    return p


def main(argv: list[str] | None = None, compose=None) -> int:
    """``diffbot plant``; ``compose(command) -> bus.node.MemberSpec`` builds a member for
    ``--compose`` (the command line's, diffbot.cli.compose_member)."""
    return process_main(lambda proc: _run(proc, compose), build_parser(), argv, "plant")


def _run(proc: Process, compose) -> int:
    args, log = proc.args, proc.log
    keep_freed_memory()
    try:
        spec = load_world(args.world, args.set)
        if args.seed is not None:
            spec.seed = args.seed
        keys = proc.keys
        disabled = tuple(x for x in args.disable.split(",") if x)
        if set(disabled) - {"lidar", "camera"}:
            raise WorldError(f"--disable takes lidar and/or camera, got {args.disable!r}")
        if args.compose and compose is None:
            raise ValueError("--compose needs the diffbot command (diffbot plant --compose)")
        members = [compose(c) for c in args.compose]
    except (WorldError, ValueError) as exc:
        raise Exit(EXIT_BAD_CONFIG, exc) from None
    session = proc.open("plant")
    plant = None
    try:
        composed = Composed(members, keys, session) if members else None
        plant = Plant(spec, session, keys, args.mode, log, rate=args.rate,
                      expect=tuple(n for n in args.expect.split(",") if n),
                      watchers=tuple(n for n in args.wait_for.split(",") if n),
                      duration_s=args.duration, join_timeout_s=args.join_timeout,
                      disabled=disabled,
                      end_with=tuple(n for n in args.end_with.split(",") if n),
                      coupling=args.coupling, physics_process=args.physics_process,
                      rejoin_timeout_s=args.rejoin_timeout,
                      skip_unread=args.zenoh_config is None, composed=composed)
        proc.stop_on_signals(plant.stop_event)
        code = plant.run() or plant.exit_code
        st = plant.stats()
        log.info("stopped at t=%.2f s after %d ticks (%.1fx real time)", st["sim_time_s"],
                 st["ticks"], st["real_time_factor"] or 0.0)
        return code
    except ValueError as exc:               # a composed member that cannot join
        raise Exit(EXIT_BAD_CONFIG, exc) from None
    except PhysicsError as exc:
        if plant is not None:
            plant.end_reason = "physics process failed"
        raise Exit(EXIT_FAILED, exc) from None
    finally:
        if plant is not None:
            proc.stats = plant.stats()     # (as it ran, before it closes)
            plant.close(plant.end_reason)
