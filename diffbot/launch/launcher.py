"""``diffbot run``: a scenario's run (:class:`diffbot.launch.scenario_run.ScenarioRun`) from the
command line: start its processes (placed on other machines with ``--place``), supervise
them, analyse the run, write ``summary.json``.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time

from bus.cliargs import ArgumentParser, nonneg_int, port, positive_float, positive_int
from bus.jsonio import write_json
from bus.keys import Keys
from bus.protocol import COUPLINGS
from bus.session import BusConfigError
from plant.world import WorldError, load_world

from ..runner import procs
from . import placement
from .scenario import ProcessSpec, ScenarioSpec, load_scenario
from .scenario_run import (EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED, VIEW, ScenarioRun,
                           published_counts, run_stats, summarize)

#: a run's bus socket folder, <tmp>/diffbot-run-<launcher PID>-<random>, removed when the run
#: ends; a SIGKILLed launcher cannot, and the next run removes the folders of launchers gone
SOCKET_DIR_PREFIX = "diffbot-run-"


def socket_dir() -> str:
    """A new folder for this run's unix socket, after removing those of dead launchers."""
    root = tempfile.gettempdir()
    for name in os.listdir(root):
        if not name.startswith(SOCKET_DIR_PREFIX):
            continue
        pid = name[len(SOCKET_DIR_PREFIX):].split("-", 1)[0]
        path = os.path.join(root, name)
        try:
            if pid.isdigit() and not procs.alive(int(pid)) and os.stat(path).st_uid == os.getuid():
                shutil.rmtree(path, ignore_errors=True)
        except OSError:
            pass
    return tempfile.mkdtemp(prefix=f"{SOCKET_DIR_PREFIX}{os.getpid()}-")


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="diffbot run", description="Run a scenario.")
    p.add_argument("scenario", help="scenario name (see `diffbot scenarios`) or TOML file")
    p.add_argument("--mode", choices=("lockstep", "realtime", "fast"), default=None,
                   help="override the scenario's mode")
    p.add_argument("--coupling", choices=COUPLINGS, default=None,
                   help="lockstep coupling: sequential (exact) or pipelined (plant and nodes in "
                        "parallel, one tick of actuation delay); default: the scenario's")
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="stop after S simulated seconds")
    p.add_argument("--physics-process", action=argparse.BooleanOptionalAction, default=None,
                   help="the plant steps DART in a process of its own, publishing while it "
                        "steps (pipelined lockstep, fast mode; same bytes); default: the "
                        "scenario's physics_process")
    p.add_argument("--seed", type=nonneg_int, default=0)
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a world key for this run (as `diffbot plant --set`, e.g. "
                        "robots.follower.camera.noise.std=20); repeatable")
    p.add_argument("--out", default=None, help="output directory (default out/<scenario>)")
    p.add_argument("--endpoint", default=None,
                   help="Zenoh endpoint (default: a unix socket private to this run)")
    p.add_argument("--namespace", default="")
    p.add_argument("--zenoh-config", default=None, metavar="FILE")
    p.add_argument("--timeout", type=positive_float, default=900.0, metavar="S",
                   help="wall-clock limit for the whole run (default 900)")
    p.add_argument("--record", default=None, metavar="FILE.mcap",
                   help="record every message into this MCAP file (Foxglove opens it; a path "
                        "without .mcap is a rosbag2 bag directory)")
    p.add_argument("--plots", action=argparse.BooleanOptionalAction,
                   default=os.environ.get("DIFFBOT_PLOTS", "1") != "0",
                   help="draw the run's figures (PNG plots, the follow animation; default); "
                        "--no-plots writes the data alone (CSV, summary.json), a second or "
                        "so less a run, for batches of runs (DIFFBOT_PLOTS=0 sets the default)")
    p.add_argument("--robots", type=positive_int, default=None, metavar="N",
                   help="robot count of a generated-world scenario (swarm; default: the "
                        "scenario's)")
    p.add_argument("--controller-processes", type=nonneg_int, default=None, metavar="K",
                   help="generated-world scenario: split the robots over K controller "
                        "processes (0: one process per robot; default: the scenario's)")
    p.add_argument("--physics", choices=("dynamic", "kinematic"), default=None,
                   help="generated-world scenario: DART contact physics (default) or the "
                        "cheap kinematic mode (ideal unicycle arcs; footprints stop robots at "
                        "walls, obstacles and each other)")
    p.add_argument("--compose", action=argparse.BooleanOptionalAction, default=None,
                   help="host the lockstep members (controllers, FMU nodes) inside the plant's "
                        "process instead of one process each: the same bytes, no process hop "
                        "per tick (docs/scenarios.md, \"Composed members\"); default: the "
                        "scenario's compose")
    p.add_argument("--ros2", action="store_true",
                   help="also start the ROS 2 bridge (`diffbot ros2`; needs rclpy: "
                        "pip install -e '.[ros2]'), on the environment's ROS_DOMAIN_ID")
    p.add_argument("--view", action="store_true",
                   help="watch the run live in Foxglove: also start `diffbot view` "
                        "(ws://127.0.0.1:8765; needs the [view] extra)")
    p.add_argument("--view-port", type=port, default=8765, metavar="PORT",
                   help="port of --view (default 8765)")
    p.add_argument("--view-host", default="127.0.0.1", metavar="HOST",
                   help="address --view binds (default 127.0.0.1)")
    placement.add_args(p)                        # --place, --address, --tls: diffbot/launch/placement.py
    return p


def generate(spec, args, out: str) -> None:
    """A generated-world scenario: write its world into ``out`` and one controller process
    per group of robots (round robin, so neighbours on the grid sit in different groups)."""
    from plant.swarm_world import write_swarm_world
    n = args.robots or spec.robots
    spec.robots = n
    spec.world = write_swarm_world(os.path.join(out, "world.toml"), n, args.seed,
                                   args.physics or "dynamic")
    k = spec.controller_processes if args.controller_processes is None \
        else args.controller_processes
    names = [f"r{i}" for i in range(n)]
    groups = [[r] for r in names] if k == 0 else \
        [g for g in (names[j::min(k, n)] for j in range(min(k, n))) if g]
    spec.controller_processes = len(groups)
    spec.processes = [ProcessSpec(name=f"{spec.controller}_{g[0]}" if len(g) == 1 else
                                  f"{spec.controller}_g{j}",
                                  command=["controller", spec.controller, "--robots", ",".join(g)])
                      for j, g in enumerate(groups)]
    spec.robot = names[0]


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        spec, out, world, keys = _inputs(args)
    except (WorldError, ValueError) as exc:
        print(f"diffbot run: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    from ..analysis.runs import ANALYSES
    os.makedirs(out, exist_ok=True)
    tmp = None
    endpoint = args.endpoint
    placed = placement.wanted(args)
    if endpoint is None and args.zenoh_config is None and not placed:
        tmp = socket_dir()
        endpoint = f"unixsock-stream/{tmp}/bus.sock"
    run = ScenarioRun(spec, out, args.mode or spec.mode, args.seed, endpoint or "", args.namespace,
              args.zenoh_config, args.duration if args.duration is not None else spec.duration_s,
              args.timeout, coupling=args.coupling or spec.coupling, record=args.record,
              ros2=args.ros2, compose=spec.compose if args.compose is None else args.compose,
              physics_process=(spec.physics_process if args.physics_process is None
                               else args.physics_process))
    if args.view:
        run.view_port, run.view_host = args.view_port, args.view_host
    if placed:                         # processes on Ray nodes (diffbot/launch/placement.py)
        try:
            run.placement = placement.place(args, run.process_names(), run.endpoint,
                                            run.zenoh_config)
        except (placement.PlacementError, BusConfigError) as exc:
            print(f"diffbot run: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
        run.endpoint, run.zenoh_config = run.placement.endpoint, run.placement.zenoh_config
    run.build()
    live = _Live(run, ANALYSES[spec.analysis], keys, spec, world, out, placed, args.plots)
    wall0 = time.monotonic()
    code = EXIT_FAILED
    try:
        code = live.supervise()
    finally:
        wall = time.monotonic() - wall0
        live.close()
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    return live.report(code, wall)


def _inputs(args) -> tuple:
    """(scenario, output folder, world, keys) of ``diffbot run``'s arguments; WorldError or
    ValueError if they do not make a run. A generated world is written to the folder."""
    spec = load_scenario(args.scenario)
    if (args.robots is not None or args.controller_processes is not None
            or args.physics is not None) and not spec.generate:
        raise ValueError(f"--robots/--controller-processes/--physics: scenario "
                         f"{spec.name!r} has a "
                         "fixed world (only generated-world scenarios, e.g. swarm, take them)")
    out = os.path.abspath(args.out or os.path.join("out", spec.name))
    if spec.generate:
        os.makedirs(out, exist_ok=True)
        generate(spec, args, out)
    for item in args.set:                  # after the scenario's own: they win
        spec.plant_args += ["--set", item]
    # the world as the plant will build it (its --set overrides: the start pose the
    # analysis compares odometry through)
    pa = spec.plant_args
    world = load_world(spec.world, [v for k, v in zip(pa, pa[1:]) if k == "--set"])
    return spec, out, world, Keys(args.namespace)


def analysis_keys(analysis, keys, spec, world, draw: bool) -> dict[str, str]:
    """The keys (and their types) the launcher's observer keeps for ``analysis``: without
    the figures (``draw`` False), not those the analysis reads only to draw them (its
    ``drawing_keys``, if it names any: the follow's camera images)."""
    keep = analysis.keys(keys, spec, world)
    drawing = getattr(analysis, "drawing_keys", None)
    if not draw and drawing is not None:
        for key in drawing(keys):
            keep.pop(key, None)
    return keep


class _Live:
    """A built run while it goes: its processes started and supervised, the launcher's own
    bus session observing what the analysis needs, and after it the summary."""

    def __init__(self, run: ScenarioRun, analysis, keys: Keys, spec: ScenarioSpec, world,
                 out: str, placed: bool, plots: bool = True) -> None:
        self.run, self.analysis, self.keys = run, analysis, keys
        self.spec, self.world, self.out, self.placed = spec, world, out, placed
        self.draw = plots                   # the figures drawn, not only the data written
        # every run draws its robots' paths (paths.png, paths.csv) unless its analysis does
        self.own_paths = getattr(analysis, "draws_paths", False)
        self.observer = self.session = self.watch = self.plots = self.stats = None

    def supervise(self) -> int:
        """Start the processes, supervise them until the run ends; the run's exit code."""
        from ..analysis import paths as analysis_paths
        from .observer import Observer
        run, spec, keys = self.run, self.spec, self.keys
        env = dict(os.environ)
        env["PYTHONUNBUFFERED"] = "1"
        code = EXIT_FAILED
        with procs.stop_requests() as stop_flag:   # Ctrl-C, SIGTERM: stop the run in order
            try:
                run.children[0].start(env)
                try:
                    self.session = run.open_observer()
                except BusConfigError as exc:
                    run.reason = f"cannot connect to the plant: {exc}"
                    run.failed = run.children[0]
                if self.session is not None:
                    keep = analysis_keys(self.analysis, keys, spec, self.world, self.draw)
                    if not self.own_paths:
                        keep = {**analysis_paths.keys(keys, self.world, keep), **keep}
                    self.observer = Observer(self.session, keys, keep)
                    self.watch = self.session.liveliness().declare_subscriber(
                        keys.alive(), run.on_alive, history=True)
                    if run.start_recorder(env, self.session, stop_flag):
                        code = self._start_the_rest(env, stop_flag)
                    elif stop_flag:
                        run.reason = f"interrupted ({stop_flag[0]})"
                        code = EXIT_INTERRUPTED
            finally:
                run.stop_all()
        return code

    def _start_the_rest(self, env: dict, stop_flag: list) -> int:
        from ..analysis.runs import import_plots_meanwhile
        run = self.run
        for c in run.children[1:]:
            if c is not run.recorder and c.name != VIEW:
                c.start(env)
        print(f"diffbot run {self.spec.name}: {run.mode} mode, seed {run.seed}, "
              f"{len(run.children)} processes, output in {self.out}", file=sys.stderr)
        if self.placed:
            print(f"diffbot run: {placement.describe(run)}", file=sys.stderr)
        if self.draw and (self.analysis.draws or not self.own_paths):
            self.plots = import_plots_meanwhile()
        return run.supervise(stop_flag)

    def close(self) -> None:
        """The launcher's own bus session closed, once every process has ended."""
        if self.watch is not None:
            self.watch.undeclare()
        if self.observer is not None:
            self.stats = run_stats(self.run)   # every process has ended: its stats are final
            self.observer.settle(published_counts(self.stats))
            self.observer.close()
        if self.session is not None:
            self.session.close()

    def report(self, code: int, wall: float) -> int:
        """The failure said, the analysis run, summary.json written; the exit code."""
        from ..analysis import paths as analysis_paths
        run, observer = self.run, self.observer
        if run.failed is not None:
            code = EXIT_FAILED if code == 0 else code
            print(f"diffbot run: {run.reason or run.failed.name + ' failed'}\n"
                  f"--- last lines of {run.failed.name}'s log ({run.failed.log_path}):\n"
                  f"{run.failed.tail()}", file=sys.stderr)
        summary = summarize(run, wall, code, self.stats)
        if self.placed:
            summary["placement"] = placement.where_ran(run)
        if observer is not None:
            if self.plots is not None:
                self.plots.join()
            args = (observer, self.keys, self.spec, self.world, self.out, self.draw)
            try:
                summary["metrics"] = self.analysis.analyse(*args)
            except Exception as exc:  # analysis must not lose the summary
                summary["analysis_error"] = f"{type(exc).__name__}: {exc}"
                code = code or EXIT_FAILED
            if not self.own_paths:
                try:
                    summary["paths"] = analysis_paths.write_paths(*args)
                except Exception as exc:  # nor the paths
                    summary["paths_error"] = f"{type(exc).__name__}: {exc}"
                    code = code or EXIT_FAILED
        path = os.path.join(self.out, "summary.json")
        write_json(path, summary)
        print(f"diffbot run {self.spec.name}: {summary['end_reason']}; summary in {path}",
              file=sys.stderr)
        return code
