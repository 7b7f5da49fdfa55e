"""Suite ``scenario``: the square and follow scenarios end to end (``diffbot run``), each
beside DART alone stepping the scenario's world (what the physics allows)."""
from __future__ import annotations

import os
import shutil
import tempfile
import time

from .common import run_summary, spawn, stop
from bus.protocol import COUPLINGS

from .harness import Context, Metric, Probe, suite

def run_scenario(ctx: Context, name: str, timeout_s: float = 900.0, *extra: str) -> dict:
    """One ``diffbot run NAME --out TMP [extra...]`` run; returns its summary.json."""
    out = tempfile.mkdtemp(prefix=f"{name}-", dir=ctx.tmpdir)
    proc = None
    try:
        proc = spawn(["run", name, "--out", out, "--timeout", f"{timeout_s:g}", *extra],
                      os.path.join(out, "run.log"))
        rc = proc.wait(timeout_s + 60)
        if rc is None:
            raise RuntimeError(f"diffbot run {name} did not finish")
        summary = run_summary(out, name, rc)
        if rc != 0:
            raise RuntimeError(f"diffbot run {name} exited {rc}: {summary.get('end_reason')}")
        return summary
    finally:
        if proc is not None:
            stop([proc], grace_s=15.0)  # the launcher stops its own children on SIGINT
        shutil.rmtree(out, ignore_errors=True)


#: where the members run: one process each, or composed into the plant's process
HOSTINGS = {"processes": "--no-compose", "composed": "--compose"}
#: targets (pipelined, the scenarios' coupling), x real time or (``share``) a share of
#: DART alone stepping the same world: composed members skip the process hop per tick, so
#: they are held to more; members over processes to no less than they ran before
TARGETS = {("square", "composed"): (0.5, "share"), ("follow", "composed"): (18.0, "x"),
           ("square", "processes"): (16.0, "x"), ("follow", "processes"): (8.5, "x")}
#: DART alone: control ticks per timed chunk, chunks (the median is taken)
ALONE_TICKS, ALONE_CHUNKS = 200, 5


def world_sets(plant_args: list[str]) -> list[str]:
    """The ``--set KEY=VALUE`` world overrides among a scenario's ``plant_args``: the plant
    of its runs loads its world with them."""
    sets, args = [], iter(plant_args)
    for a in args:
        if a == "--set":
            sets.append(next(args, ""))
        elif a.startswith("--set="):
            sets.append(a.split("=", 1)[1])
    return [v for v in sets if v]


def dart_alone(world: str, ticks: int = ALONE_TICKS, chunks: int = ALONE_CHUNKS,
               sets: list[str] | tuple[str, ...] = ()) -> dict:
    """The control-tick rate DART alone allows in ``world`` (with the overrides ``sets``, as
    the scenario's plant loads it: the same robots, contacts, physics steps a tick):
    ``Simulation.step_tick`` of the world with every robot driving (wheels -/+1 rad/s, as the
    physics suite), no sensors, no bus; the median of ``chunks`` chunks of ``ticks`` ticks,
    as a real-time factor (wall and CPU) and the wall and CPU time of one control tick."""
    from plant.sim import Simulation
    from plant.world import load_world
    spec = load_world(world, list(sets))
    sim = Simulation(spec)
    for name in sim.robots:
        sim.command_wheels(name, 1.0, -1.0)
    for _ in range(10):           # the drive limiters ramp up to the command
        sim.step_tick()
    walls, cpus = [], []
    for _ in range(chunks):
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(ticks):
            sim.step_tick()
        walls.append((time.perf_counter() - t0) / ticks)
        cpus.append((time.process_time() - c0) / ticks)
    wall, cpu = sorted(walls)[chunks // 2], sorted(cpus)[chunks // 2]
    return {"real_time_factor": spec.control_tick_s / wall,
            "cpu_real_time_factor": spec.control_tick_s / cpu if cpu > 0 else float("nan"),
            "tick_s": wall, "cpu_tick_s": cpu}


def beside_dart(ctx: Context, name: str, world: str, *extra: str,
                sets: list[str] | tuple[str, ...] = ()) -> dict:
    """One scenario run, then DART alone in its world at once (the same machine load):
    the run's summary with ``dart_alone_rtf`` and ``share_of_dart_alone`` added, and the
    same share in CPU time (``cpu_share_of_dart_alone``: DART alone's CPU a tick over the
    run's plant process's, summary.json ``cpu_per_tick_ms.plant``), which moves less with
    the machine's load than the wall-clock rates."""
    summary = run_scenario(ctx, name, 900.0, *extra)
    alone = dart_alone(world, sets=sets)
    rtf = summary.get("real_time_factor")
    plant_cpu_ms = (summary.get("cpu_per_tick_ms") or {}).get("plant")
    return {**summary, "dart_alone_rtf": alone["real_time_factor"],
            "share_of_dart_alone": (rtf / alone["real_time_factor"]
                                    if rtf and alone["real_time_factor"] else None),
            "cpu_share_of_dart_alone": (alone["cpu_tick_s"] * 1e3 / plant_cpu_ms
                                        if plant_cpu_ms else None)}


def _target(name: str, hosting: str, coupling: str) -> tuple[str, str]:
    """(target of the real-time factor, target of the share of DART alone) of a row."""
    got = TARGETS.get((name, hosting)) if coupling == "pipelined" else None
    if got is None:
        return "", ""
    value, kind = got
    return ("", f">= {value:g}") if kind == "share" else (f">= {value:g}x", "")


@suite("scenario", "the square and follow scenarios end to end in lockstep (diffbot run), "
                   "under both couplings, members over processes and composed, each beside "
                   "DART alone stepping the scenario's world")
def scenario_suite(ctx: Context):
    from diffbot.launch.scenario import load_scenario
    for name in ("square", "follow"):
        scenario = load_scenario(name)
        world, sets = scenario.world, world_sets(scenario.plant_args)
        what = f"{name}: DART alone ({world})"
        yield Probe(what, lambda world=world, sets=sets: dart_alone(world, sets=sets), [
            Metric("real_time_factor", f"{what}: control-tick rate", "x",
                   notes="Simulation.step_tick, every robot driving, no sensors, no bus: "
                         "what the physics allows"),
            Metric("cpu_real_time_factor", f"{what}: control-tick rate (CPU)", "x",
                   notes="process CPU time: less sensitive to a loaded machine"),
            Metric("tick_s", f"{what}: one control tick", "s")], repeats=1, warmup=0)
        for coupling in COUPLINGS:
            for hosting, flag in HOSTINGS.items():
                what = f"{name}, {coupling}, {hosting}"
                rtf_target, share_target = _target(name, hosting, coupling)
                yield Probe(what, lambda name=name, w=world, c=coupling, f=flag, s=sets:
                            beside_dart(ctx, name, w, "--coupling", c, f, sets=s), [
                    Metric("real_time_factor", f"{what}: real-time factor", "x",
                           target=rtf_target,
                           notes="summary.json real_time_factor (plant, lockstep)"),
                    Metric("share_of_dart_alone", f"{what}: share of DART alone", "",
                           target=share_target,
                           notes="real-time factor / DART alone's, DART timed right after "
                                 "each run"),
                    Metric("cpu_share_of_dart_alone", f"{what}: share of DART alone (CPU)",
                           "", notes="DART alone's CPU a tick / the run's plant process's "
                                     "(summary.json cpu_per_tick_ms.plant; member processes "
                                     "not counted)"),
                    Metric("dart_alone_rtf", f"{what}: DART alone beside it", "x",
                           notes=f"{world}, timed right after the run"),
                    Metric("wall_time_s", f"{what}: wall time",
                           notes="whole run incl. start-up, analysis"),
                    Metric("sim_time_s", f"{what}: simulated time"),
                ], repeats=1 if ctx.quick or name == "follow" else 3, warmup=0,
                    notes="no warm-up run")
