"""The node API: a controller is an object with ``step(observation) -> command``.

:func:`run_node` does everything else: it parses the standard options, opens the Zenoh
session and runs the controller with :class:`bus.runtime.NodeRunner`, which learns the
simulation's mode from the plant (``sim/info``), subscribes to the controller's inputs
and ``sim/clock``, takes part in lockstep (liveliness token ``sim/sync/<node>``, an ack
per tick), stamps and publishes the outputs, and exits cleanly on Ctrl-C, SIGTERM, the
controller finishing, or the plant going away.

One node may drive several robots (``--robots r0,r1`` or ``run_node(..., robots=[...])``):
one controller object per robot (a factory makes them, or the given object is copied),
one session, one lockstep member that acks each tick once for all its robots, each
robot's inputs awaited separately; the node finishes when every controller is done.

A controller declares (every hook and its default: :class:`bus.controller.Controller`)::

    inputs = ["joint_states", "odom"]   # topics of its robot it reads
    sync = True                         # holds the simulation in lockstep (default)
    def step(self, obs) -> Twist | WheelSpeeds | dict | None
    done = False                        # set True to stop the robot and exit 0

``step`` returns a :class:`Twist` (published as ``cmd_vel``), :class:`WheelSpeeds`
(``wheel_cmd``), a dict ``{topic: message}`` of other outputs (a Twist or WheelSpeeds
value in it, under any key, is the command), or None. This module re-exports the
controller's values (:class:`Twist`, :class:`WheelSpeeds`, :class:`Observation`) so a
controller needs one import.

Faults (see docs/failures.md): the plant is watched through its
liveliness token, so a killed plant is noticed within milliseconds and a frozen one
(SIGSTOP) within the 1 s lease; the node then exits 3, or with ``--wait`` waits for a
plant to come back, up to the run's rejoin timeout (``sim/info`` ``rejoin_timeout_s``) +
2 s, re-reads ``sim/info`` and carries on (this node's controller object keeps its state);
past that it exits 3 (:mod:`bus.plantwatch`). The end of the run (``sim/end``) ends a
node that took part in it, ``--wait`` or not (exit 0). A plant of another protocol version
makes the node exit 2, whether it is met at the start or comes back. A node that was itself frozen longer than the lease
has been dropped by the simulation; when it resumes it sees the plant gone and exits 3
(with ``--wait`` it rejoins at the current tick). Inputs are filed by stamp, so stray,
stale or forged samples never displace the one a tick needs; bad values are rejected and
counted, and the tick goes on with the last good message (``check_inputs = False`` on a
controller that validates its own). A lockstep node that waits for another node's output
after that node left exits 4 instead of holding the simulation forever.
"""
from __future__ import annotations

import argparse
import math
import sys
from contextvars import ContextVar
from dataclasses import dataclass

import zenoh

from . import controller as hooks
from .cliargs import ArgumentParser, name_arg, names_arg
from .controller import Controller, Observation, Twist, WheelSpeeds, default_name
from .keys import check_name, check_names
from .member import with_own_stats
from .protocol import ProtocolError
from .process import EXIT_BAD_CONFIG, EXIT_PLANT_GONE, Exit, Process, run_process
from .runtime import NodeRunner
from .session import BusConfigError, add_process_args, open_session, open_when_listening

#: the API a controller script uses (``from bus.node import Twist, run_node``)
__all__ = ["Controller", "Observation", "Twist", "WheelSpeeds", "node_arg_parser",
           "run_controller", "run_node", "run_node_args"]


def node_arg_parser(description: str, default_name: str | None = None) -> argparse.ArgumentParser:
    p = _NodeParser(description=description)
    p.add_argument("--robot", default="robot1", type=name_arg("robot name"),
                   help="robot to control (default robot1)")
    p.add_argument("--robots", default=None, type=names_arg, metavar="R1,R2,...",
                   help="drive several robots from this one process: one controller object "
                        "per robot, one lockstep member (the default node name uses the "
                        "first robot)")
    p.add_argument("--name", default=default_name, type=name_arg("node name"),
                   help="node name on the bus (default <controller>_<robot>)")
    p.add_argument("--wait", action="store_true",
                   help="wait for a plant to start, and when it goes away (killed, frozen, "
                        "its router lost) wait for it up to the run's rejoin timeout + 2 s "
                        "and carry on when it is back, instead of exiting with code 3 at "
                        "once; the end of the run (sim/end) still ends the node (exit 0)")
    add_process_args(p, "the node's counters")
    return p


class _NodeParser(ArgumentParser):
    """With ``--robots``, ``args.robot`` is the first of them (default node names use it)."""

    def parse_known_args(self, args=None, namespace=None):
        ns, rest = super().parse_known_args(args, namespace)
        if getattr(ns, "robots", None):
            ns.robot = ns.robots[0]
        return ns, rest


def run_node(controller, robot: str | None = None, argv: list[str] | None = None,
             name: str | None = None, robots: list[str] | None = None) -> int:
    """Run ``controller`` as a bus node; parse the standard options from ``argv``.

    ``controller`` is a controller object, or a factory of them (a class, or a callable
    taking the robot name): with several ``robots`` (or ``--robots``) the node drives one
    controller per robot (:func:`make_controllers`).
    Returns the exit code (0 when stopped or done, 2 on bad configuration,
    3 when the plant went away, 4 when an awaited input's producer left the simulation).
    """
    base = default_name(controller)
    parser = node_arg_parser(f"{base} controller")
    if robot is not None:
        parser.set_defaults(robot=robot)
    if robots:
        parser.set_defaults(robots=list(robots))
    args = parser.parse_args(argv)
    return run_node_args(controller, args, name or args.name or f"{base}_{args.robot}")


@dataclass
class MemberSpec:
    """A member as its command line made it, not yet run: what :func:`capture_member` gives
    the plant to compose (docs/scenarios.md, "Composed members")."""
    controller: object
    robots: list[str]
    name: str
    stats: str | None = None
    log_level: str = "INFO"


_capture: ContextVar[list | None] = ContextVar("diffbot_capture_member", default=None)


def capture_member(main, argv: list[str]) -> MemberSpec:
    """Run a node's ``main(argv)`` up to the point where it would join the bus, and take
    the member it made (its controller object or factory, robots, name, ``--stats``)
    instead of running it: the same parsing and checks as the process would do.
    ValueError if it made none (bad options: its message went to stderr)."""
    box: list[MemberSpec] = []
    token = _capture.set(box)
    try:
        code = main(list(argv))
    except SystemExit as exc:            # argparse: --help or a bad option
        code = exc.code
    finally:
        _capture.reset(token)
    if not box:
        raise ValueError(f"{' '.join(argv)!r} made no member (exit code {code})")
    return box[0]


def run_controller(make, args: argparse.Namespace, base: str) -> int:
    """A controller command's last step: ``make()`` builds the controller from the parsed
    options (a ValueError is the one-line error ``<base>: reason``, exit 2), then
    :func:`run_node_args` runs it, named ``--name`` or ``<base>_<robot>``."""
    try:
        controller = make()
    except ValueError as exc:
        print(f"{base}: {exc}", file=sys.stderr)
        return EXIT_BAD_CONFIG
    return run_node_args(controller, args, args.name or f"{base}_{args.robot}")


def run_node_args(controller, args: argparse.Namespace, name: str) -> int:
    robots = getattr(args, "robots", None) or [args.robot]
    if (box := _capture.get()) is not None:      # composed: the plant runs it (above)
        box.append(MemberSpec(controller, list(robots), name, getattr(args, "stats", None),
                              args.log_level))
        return 0
    return run_process(lambda proc: _run(proc, controller, robots), args, name)


def _run(proc: Process, controller, robots: list[str]) -> int:
    args, log, name = proc.args, proc.log, proc.name
    wait = bool(getattr(args, "wait", False))
    try:
        keys = proc.keys
        check_names(robots)
        check_name(name, "node name")
        proc.session = session = _open_node_session(args, wait, log)
    except (BusConfigError, ValueError) as exc:
        raise Exit(EXIT_BAD_CONFIG, exc) from None
    except KeyboardInterrupt:              # Ctrl-C while waiting for the plant
        return 0
    runner = None

    def closed_stats() -> dict | None:
        """After the session closed: the controllers closed, the stats with their own."""
        made = (hooks.distinct(s.controller for s in runner.slots) if runner is not None
                else [controller] if hasattr(controller, "step")
                and not isinstance(controller, type) else [])
        for ctrl in made:
            hooks.close(ctrl)
        return with_own_stats(runner.stats(), made) if runner is not None else None
    proc.stats = closed_stats
    try:
        if wait:
            log.info("waiting for the plant (--wait)")
        runner = NodeRunner(controller, robots[0], name, session, keys, log,
                            wait_for_plant_s=math.inf if wait else 15.0, wait=wait,
                            robots=robots)
    except TimeoutError as exc:
        raise Exit(EXIT_PLANT_GONE, exc) from None
    except (ProtocolError, ValueError) as exc:    # must not join, or a bad name
        raise Exit(EXIT_BAD_CONFIG, exc) from None
    except KeyboardInterrupt:          # Ctrl-C while waiting for the plant
        return 0
    proc.stop_on_signals(runner.stop_event)
    return runner.run()


def _open_node_session(args: argparse.Namespace, wait: bool, log) -> zenoh.Session:
    """The node's client session; with ``--wait`` (and the default config) keep trying until
    a plant listens (a Zenoh client cannot open without its router)."""
    if not wait or args.zenoh_config:
        return open_session("node", args.endpoint, args.zenoh_config)
    said = []

    def missed(exc: Exception) -> None:
        if not said:
            log.info("no plant at %s yet; waiting for one (--wait)", args.endpoint)
            said.append(exc)
    return open_when_listening(args.endpoint, missed, pause_s=0.2)
