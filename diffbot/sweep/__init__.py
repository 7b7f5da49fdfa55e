"""``diffbot sweep SCENARIO``: the same scenario over a grid of parameters and seeds, on
this machine or a Ray cluster, into one table and a plot per metric.

    diffbot sweep follow --grid robots.follower.camera.noise.std=0,10,20,40 --seeds 0-3 \\
        --duration 20 --out out/sweep-noise [--engine ray --address auto]

Each point of the grid is a normal ``diffbot run SCENARIO --seed S [--set K=V | --OPTION V]
--duration D --out OUT/runs/<run>`` with its own private endpoint (see
:mod:`diffbot.runner`). Then ``OUT`` holds::

    sweep.csv, sweep.parquet   one row per run: parameters, seed, status, exit code,
                               attempts, wall time, real-time factor, node, host, every
                               scalar metric of its summary.json, and a failed run's log tail
    plots/<metric>_vs_<param>.png   median over seeds, spread as bands (not with --no-plots)
    runs/<run>/                the run's own output (summary.json, plots, logs, run.log)

A run that failed is retried (``--retries``); Ctrl-C cancels the queued runs and stops the
running ones; the same command again skips the runs that finished (resume). Exit codes: 0
every run ok, 1 some failed (their rows say why), 2 bad arguments, 130 interrupted.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

from bus.cliargs import ArgumentParser, nonneg_int, positive_float

from .. import runner
from ..runner.procs import diffbot_argv
from .grid import Axis, Point, parse_axis, parse_seeds, points
from ..analysis.sweep_plots import plot_all
from .table import (HEAD, LAST, TAIL, columns, finished_row, make_row, save_row,
                    write_table)

EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 1, 2, 130


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="diffbot sweep", description=__doc__.split("\n\n")[0].strip(),
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="docs/sweeps.md has examples and the cluster set-up")
    p.add_argument("scenario", help="scenario name (see `diffbot scenarios`) or TOML file")
    p.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="a swept parameter: a dotted world key (as `diffbot run --set`) or a "
                        "`diffbot run` option (coupling, mode, robots, ...); several multiply")
    p.add_argument("--seeds", default="0", metavar="A-B",
                   help="seeds of every grid point: A-B, A or A,B,C (default 0)")
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="simulated seconds per run (default: the scenario's)")
    p.add_argument("--out", default=None, help="output directory (default out/sweep-SCENARIO)")
    runner.add_engine_args(p, "default: local engine, the CPUs / CPUs per run; ray engine: "
                              "as many as the cluster's CPUs hold")
    p.add_argument("--cpus-per-run", type=positive_float, default=None, metavar="N",
                   help="CPUs a run reserves (default: 1 for a sequential lockstep scenario, "
                        "else its process count, at most 2)")
    p.add_argument("--retries", type=nonneg_int, default=1, metavar="N",
                   help="run a failed run again up to N times (default 1)")
    p.add_argument("--timeout", type=positive_float, default=900.0, metavar="S",
                   help="wall-clock limit per run (default 900 s)")
    p.add_argument("--compose", action=argparse.BooleanOptionalAction, default=True,
                   help="host each run's lockstep members in its plant's process (default: "
                        "the same bytes, no process hop per tick); --no-compose: a process "
                        "each, as `diffbot run` without --compose")
    p.add_argument("--plots", action=argparse.BooleanOptionalAction,
                   default=os.environ.get("DIFFBOT_PLOTS", "1") != "0",
                   help="draw the sweep's plots (default); --no-plots writes the table alone "
                        "and runs each point with `diffbot run --no-plots`: the data, no "
                        "figures (DIFFBOT_PLOTS=0 sets the default)")
    p.add_argument("--fresh", action="store_true",
                   help="run everything again, even runs a previous sweep into --out finished")
    p.add_argument("--progress", choices=("auto", "bar", "lines"), default="auto",
                   help="a progress bar with ETA (default on a terminal) or a line per run")
    return p


def cpus_for(spec, point_args: list[str], composed: bool = False) -> float:
    """CPUs a run of this scenario keeps busy: sequential lockstep runs one process at a
    time, and so does a lockstep run whose members are composed into the plant; pipelined,
    realtime, fast and physics-process runs keep two or more busy."""
    coupling = spec.coupling
    mode = spec.mode
    if "--coupling" in point_args:
        coupling = point_args[point_args.index("--coupling") + 1]
    if "--mode" in point_args:
        mode = point_args[point_args.index("--mode") + 1]
    if mode == "lockstep" and (coupling == "sequential" or composed) \
            and not spec.physics_process:
        return 1.0
    return float(min(2, 1 + max(1, len(spec.processes))))


def check_points(spec, axes: list[Axis], pts: list[Point]) -> None:
    """Every point's world builds (a wrong key fails here, before any run starts)."""
    from plant.world import load_world
    if spec.generate:
        return
    pa = spec.plant_args
    base = [v for k, v in zip(pa, pa[1:]) if k == "--set"]
    seen = set()
    for pt in pts:
        sets = tuple(a for a in pt.run_args(axes) if "=" in a)
        if sets not in seen:
            seen.add(sets)
            load_world(spec.world, base + list(sets))


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from plant.world import WorldError
    from ..launch.scenario import load_scenario
    try:
        spec = load_scenario(args.scenario)
        axes = [parse_axis(g) for g in args.grid]
        if len({a.key for a in axes}) != len(axes):
            raise ValueError("--grid: the same key twice")
        seeds = parse_seeds(args.seeds)
        pts = points(axes, seeds)
        check_points(spec, axes, pts)
        if args.address and args.engine != "ray":
            raise ValueError("--address is for --engine ray")
    except (WorldError, ValueError) as exc:
        print(f"diffbot sweep: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    out = os.path.abspath(args.out or os.path.join("out", f"sweep-{spec.name}"))
    os.makedirs(os.path.join(out, "runs"), exist_ok=True)
    params = [a.key for a in axes]
    scenario_arg = spec.path if os.path.isfile(args.scenario) else spec.name
    runs, rows, todo = {}, {}, []
    for pt in pts:
        rid = pt.run_id(axes)
        run_out = os.path.join(out, "runs", rid)
        extra = pt.run_args(axes)
        cmd = diffbot_argv("run", scenario_arg, *extra, "--out", run_out,
                           "--timeout", f"{args.timeout:g}",
                           "--compose" if args.compose else "--no-compose",
                           *(["--duration", f"{args.duration:g}"] if args.duration else []),
                           *([] if args.plots else ["--no-plots"]))
        run = runner.Run(rid, cmd, run_out, os.path.join(run_out, "run.log"),
                         cpus=args.cpus_per_run or cpus_for(spec, extra, args.compose),
                         timeout_s=args.timeout + 60, params=dict(zip(params, pt.values)),
                         spec=pt)
        runs[rid] = run
        kept = None if args.fresh else finished_row(run_out, cmd[1:])
        if kept is not None:
            rows[rid] = kept
        else:
            todo.append(run)
    order = list(runs)
    say = runner.Progress("sweep", bar=None if args.progress == "auto" else args.progress == "bar")

    def flush() -> None:
        write_table([rows[r] for r in order if r in rows], params, out)

    def on_done(run: runner.Run) -> None:
        rows[run.name] = make_row(run, run.spec, axes, out)
        save_row(rows[run.name], run.out, run.argv[1:])
        flush()

    try:
        engine = runner.make_engine(args.engine, args.address, args.max_parallel,
                                    max(r.cpus for r in runs.values()))
    except (ValueError, RuntimeError, ConnectionError) as exc:
        print(f"diffbot sweep: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    say(f"{spec.name}: {len(pts)} run(s) ({' x '.join(str(len(a.texts)) for a in axes) or '1'}"
        f" point(s) x {len(seeds)} seed(s)); {len(runs) - len(todo)} already done in {out}, "
        f"{len(todo)} to run on the {engine.describe()}")
    t0 = time.monotonic()
    stop_flag = runner.run_until_done(todo, engine, say, on_done, args.retries)
    wall = time.monotonic() - t0
    all_rows = [rows[r] for r in order if r in rows]
    written = write_table(all_rows, params, out) if all_rows else []
    metrics = [c for c in columns(all_rows, params)
               if c not in (*HEAD, *TAIL, *LAST, *params)] + ["real_time_factor"]
    plots_dir = os.path.join(out, "plots")
    os.makedirs(plots_dir, exist_ok=True)
    pngs = plot_all(all_rows, params, metrics, plots_dir, spec.name) \
        if params and args.plots else []
    bad = [r for r in all_rows if r["status"] != "ok"]
    say(f"{len(all_rows) - len(bad)}/{len(pts)} run(s) ok in {wall:.1f} s; "
        f"{', '.join(os.path.relpath(w, out) for w in written)} and {len(pngs)} plot(s) in {out}")
    for r in bad:
        say(f"{r['run']}: {r['status']} (exit code {r['exit_code']})")
    if stop_flag:
        return EXIT_INTERRUPTED
    return EXIT_FAILED if bad or len(all_rows) < len(pts) else 0
