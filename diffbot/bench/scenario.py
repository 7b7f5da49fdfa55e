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


def dart_alone(world: str, ticks: int = ALONE_TICKS, chunks: int = ALONE_CHUNKS) -> dict:
    """The control-tick rate DART alone allows in ``world``: ``Simulation.step_tick`` of the
    world with every robot driving (wheels -/+1 rad/s, as the physics suite), no sensors, no
    bus; the median of ``chunks`` chunks of ``ticks`` ticks, as a real-time factor (wall and
    CPU) and the wall time of one control tick."""
    from plant.sim import Simulation
    from plant.world import load_world
    spec = load_world(world)
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
            "tick_s": wall}


def beside_dart(ctx: Context, name: str, world: str, *extra: str) -> dict:
    """One scenario run, then DART alone in its world at once (the same machine load):
    the run's summary with ``dart_alone_rtf`` and ``share_of_dart_alone`` added."""
    summary = run_scenario(ctx, name, 900.0, *extra)
    alone = dart_alone(world)["real_time_factor"]
    rtf = summary.get("real_time_factor")
    return {**summary, "dart_alone_rtf": alone,
            "share_of_dart_alone": rtf / alone if rtf and alone else None}


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
        world = load_scenario(name).world
        what = f"{name}: DART alone ({world})"
        yield Probe(what, lambda world=world: dart_alone(world), [
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
                yield Probe(what, lambda name=name, w=world, c=coupling, f=flag: beside_dart(
                    ctx, name, w, "--coupling", c, f), [
                    Metric("real_time_factor", f"{what}: real-time factor", "x",
                           target=rtf_target,
                           notes="summary.json real_time_factor (plant, lockstep)"),
                    Metric("share_of_dart_alone", f"{what}: share of DART alone", "",
                           target=share_target,
                           notes="real-time factor / DART alone's, DART timed right after "
                                 "each run"),
                    Metric("dart_alone_rtf", f"{what}: DART alone beside it", "x",
                           notes=f"{world}, timed right after the run"),
                    Metric("wall_time_s", f"{what}: wall time",
                           notes="whole run incl. start-up, analysis"),
                    Metric("sim_time_s", f"{what}: simulated time"),
                ], repeats=1 if ctx.quick or name == "follow" else 3, warmup=0,
                    notes="no warm-up run")
