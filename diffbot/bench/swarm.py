"""Suite ``swarm``: many robots. Physics alone (dynamic and kinematic), the swarm's lidar
per robot and for all robots in one pass, ``diffbot run swarm`` with its avoid controllers
composed into the plant (24/96/256 kinematic robots with lidars, 24 dynamic ones, each
beside DART alone stepping as many robots: the cost of a robot's tick; the dynamic one also
beside DART stepping robots their avoid steers, as loaded as the run's), and in lockstep
with 8/16/24 robots from 3 controller processes and from one process per robot, under both
couplings (physics in a process of its own, the scenario's default; and once without)."""
from __future__ import annotations

import os
import tempfile
import time

import numpy as np

from bus.protocol import COUPLINGS

from .harness import Case, Context, Metric, Probe, suite
from .scenario import run_scenario


def _swarm_spec(n: int, mode: str, tmpdir: str):
    """The swarm world of ``n`` robots (seed 0, as `diffbot run swarm` lays it out)."""
    from plant.swarm_world import write_swarm_world
    from plant.world import load_world
    fd, path = tempfile.mkstemp(suffix=".toml", dir=tmpdir)
    os.close(fd)
    try:
        return load_world(write_swarm_world(path, n, seed=0, mode=mode))
    finally:
        os.unlink(path)


def _swarm_sim(n: int, mode: str, tmpdir: str):
    from plant.sim import Simulation
    spec = _swarm_spec(n, mode, tmpdir)
    sim = Simulation(spec)
    for i, name in enumerate(sim.robots):           # all driving, some turning
        sim.command_twist(name, 0.3, 0.3 if i % 2 else -0.2)
    sim.step_tick()
    return spec, sim


def physics_rtf(n: int, mode: str, tmpdir: str, sim_s: float = 2.0) -> dict:
    """Physics only (Simulation.step_tick, no sensors, no bus): real-time factor, the cost
    per robot per physics step and (DART) the contacts of the last step of each tick, on
    average: the robots drive open-loop in circles, touching the floor alone, where a
    controlled swarm presses on walls and each other too, and DART's step costs more with
    every contact."""
    spec, sim = _swarm_sim(n, mode, tmpdir)
    ticks = max(1, int(round(sim_s / spec.control_tick_s)))
    contacts = 0
    dart = sim.kin is None
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(ticks):
        sim.step_tick()
        if dart:
            contacts += sim.world.getLastCollisionResult().getNumContacts()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    steps = ticks * spec.substeps
    return {"real_time_factor": ticks * spec.control_tick_s / wall,
            "cpu_ms_per_tick": cpu / ticks * 1e3,
            "us_per_robot_step": wall / steps / n * 1e6,
            "cpu_us_per_robot_step": cpu / steps / n * 1e6,
            **({"contacts": contacts / ticks} if dart else {})}


def steered_physics_rtf(n: int, tmpdir: str, sim_s: float) -> dict:
    """DART alone as the composed swarm loads it: the robots steered by the swarm's own
    avoid controller (:class:`controllers.avoid.Avoid`, every robot in one object, on the
    lidar's scans as the tick makes them, in this process, no bus), and only their steps
    (:meth:`plant.tick.Tick.step`) timed. They press on walls and each other as the composed
    run's do, so this is the bound the composed run can reach, where :func:`physics_rtf`'s
    open-loop circles touch the floor alone. Its real-time factor, the physics' share of
    the loop, the contacts a tick on average and how far a robot got, on average (m)."""
    from bus.controller import Observation
    from controllers.avoid import Avoid
    from plant.tick import Tick
    spec = _swarm_spec(n, "dynamic", tmpdir)
    tick, ctrl = Tick(spec), Avoid()
    try:
        robots = list(tick.sim.robots)
        only_scans = {r: (lambda topic: topic == "scan") for r in robots}
        latest: dict[str, object] = dict.fromkeys(robots)
        ticks = max(1, int(round(sim_s / spec.control_tick_s)))
        start = {r: tick.sim.state(r).tf[:2, 3].copy() for r in robots}
        stepping = stepping_cpu = contacts = 0.0
        t_loop = time.perf_counter()
        for _ in range(ticks):
            t_ns = tick.t_ns
            for robot, topic, msg in tick.messages(only_scans):
                if topic == "scan" and msg is not None:
                    latest[robot] = msg
            cmds = ctrl.step_many({r: Observation(t_ns, r, {"scan": latest[r]})
                                   for r in robots})
            for r in robots:
                tick.drive(r, cmds.get(r))
            t0, c0 = time.perf_counter(), time.thread_time()
            tick.step()
            stepping += time.perf_counter() - t0
            stepping_cpu += time.thread_time() - c0
            contacts += tick.sim.world.getLastCollisionResult().getNumContacts()
        loop = time.perf_counter() - t_loop
        travel = sum(float(np.hypot(*(tick.sim.state(r).tf[:2, 3] - start[r])))
                     for r in robots) / len(robots)
    finally:
        tick.close()
    return {"real_time_factor": ticks * spec.control_tick_s / stepping,
            "cpu_ms_per_tick": stepping_cpu / ticks * 1e3,
            "physics_share": stepping / loop, "contacts": contacts / ticks,
            "travel_m": travel}


def _sensor_cases(ctx: Context):
    """The swarm world's lidar, one robot's and all at once, and the tick's scene."""
    from plant import lidar
    from plant.raycast import Scene
    spec, sim = _swarm_sim(24, "dynamic", ctx.tmpdir)
    cfg = spec.robots[0].sensors.lidar
    scene = Scene(sim.shapes())
    st = sim.state("r0")
    yield Case(f"swarm lidar sweep ({cfg.num_rays} rays, 24 robots' world)",
               lambda: lidar.measure(cfg, st.tf, scene, None, "r0"),
               notes=f"{len(scene)} shapes; one robot's scan alone, at {cfg.rate_hz:g} Hz")
    names = list(sim.robots)
    tfs = [sim.state(n).tf for n in names]
    yield Case("swarm lidar, all 24 robots' scans in one pass",
               lambda: lidar.scan_many(cfg, tfs, scene, names),
               notes="lidar.scan_many, what the plant does at a tick the lidars are due")
    yield Case("swarm scene snapshot (24 robots)", sim.scene,
               notes="Simulation.scene, once per tick a lidar is due, shared by every robot")
    _, sim96 = _swarm_sim(96, "kinematic", ctx.tmpdir)
    yield Case("swarm scene snapshot (96 kinematic robots)", sim96.scene,
               notes="the parts' poses from the robots' (x, y, yaw) in numpy, into the world's "
                     "scene built once")
    yield Case("swarm scene snapshot (96 kinematic robots), the solids as objects",
               lambda: Scene(sim96.shapes()),
               notes="Scene(sim.shapes()): a Shape a part first (figures list them so)")


@suite("swarm", "many robots: physics alone (dynamic, kinematic), the swarm lidar, and "
                "`diffbot run swarm` in lockstep with 3 controller processes vs one per robot")
def swarm_suite(ctx: Context):
    repeats = 1 if ctx.quick else 3
    for mode in ("dynamic", "kinematic"):
        for n in (1, 8, 24):
            what = f"physics alone, {n} {mode} robot{'s' if n > 1 else ''}"
            yield Probe(what, lambda n=n, mode=mode: physics_rtf(n, mode, ctx.tmpdir), [
                Metric("real_time_factor", f"{what}: real-time factor", "x",
                       notes="Simulation.step_tick in one process, 2 ms steps, 20 ms ticks"),
                Metric("us_per_robot_step", f"{what}: per robot per step (wall)", "us"),
                Metric("cpu_us_per_robot_step", f"{what}: per robot per step (CPU)", "us",
                       notes="process CPU time: less sensitive to a loaded machine"),
            ], repeats=repeats, warmup=0)
    yield from _sensor_cases(ctx)
    duration = "5" if ctx.quick else "20"
    yield from composed_swarm(ctx)

    def per_robot(summary: dict, n: int) -> dict:
        ms = summary.get("plant_per_tick_ms") or {}
        return {**summary, **{f"{k}_s_per_robot": v * 1e-3 / n for k, v in ms.items()}}
    what = "swarm lockstep, 24 robots, 3 controller processes, pipelined: the plant's tick"
    yield Probe(what, lambda: per_robot(run_scenario(
        ctx, "swarm", 600.0, "--robots", "24", "--coupling", "pipelined",
        "--duration", duration), 24), [
        Metric("publish_s_per_robot", f"{what}, publishing per robot", "s",
               notes="sensors, lidar, encoding and puts (plant_per_tick_ms / 24)"),
        Metric("physics_s_per_robot", f"{what}, physics not hidden, per robot", "s",
               notes="the physics process's step beyond the publishing it overlaps"),
        Metric("wait_s_per_robot", f"{what}, waiting for the nodes, per robot", "s")],
        repeats=1, warmup=0)
    for n in (8, 16, 24):
        for procs, label in ((3, "3 controller processes"), (0, "one process per robot")):
            if procs == 0 and n > 16 and ctx.quick:
                continue
            for coupling in COUPLINGS:
                what = f"swarm lockstep, {n} robots, {label}, {coupling}"
                headline = n == 24 and procs == 3      # the case with a target
                yield Probe(what, lambda n=n, p=procs, c=coupling: run_scenario(
                    ctx, "swarm", 600.0, "--robots", str(n), "--controller-processes", str(p),
                    "--coupling", c, "--duration", duration), [
                    Metric("real_time_factor", f"{what}: real-time factor", "x",
                           target=">= 6x" if headline else "",
                           notes=f"summary.json real_time_factor, {duration} s simulated"
                                 + ("; peers (physics only, docs/benchmarks.md): PyBullet "
                                    "1.4x, MuJoCo 12.3x" if headline else "")),
                ], repeats=1, warmup=0)
    what = "swarm lockstep, 24 robots, 3 controller processes, pipelined, physics in the plant"
    yield Probe(what, lambda: run_scenario(
        ctx, "swarm", 600.0, "--robots", "24", "--no-physics-process",
        "--coupling", "pipelined", "--duration", duration), [
        Metric("real_time_factor", f"{what}: real-time factor", "x",
               notes="--no-physics-process: DART stepped in the plant's own process, "
                     "taking turns with publishing")], repeats=1, warmup=0)
    what = "swarm lockstep, 24 kinematic robots, 3 controller processes, pipelined"
    yield Probe(what, lambda: run_scenario(
        ctx, "swarm", 600.0, "--robots", "24", "--physics", "kinematic",
        "--coupling", "pipelined", "--duration", duration), [
        Metric("real_time_factor", f"{what}: real-time factor", "x",
               notes=f"summary.json real_time_factor, {duration} s simulated")],
        repeats=1, warmup=0)


#: the targets for composed swarms (x real time, or a share of DART alone)
COMPOSED_TARGETS = {("kinematic", 96): ">= 15x", ("kinematic", 24): ">= 40x",
                    ("dynamic", 24): ">= 0.8 of DART alone"}


def composed_run(ctx: Context, n: int, mode: str, duration: str) -> dict:
    """``diffbot run swarm`` with ``n`` robots, their avoid controllers composed into the
    plant, pipelined: its real-time factor and the wall, CPU and plant-phase cost of one
    robot's tick."""
    summary = run_scenario(ctx, "swarm", 900.0, "--robots", str(n), "--physics", mode,
                           "--compose", "--coupling", "pipelined", "--duration", duration)
    rtf = summary.get("real_time_factor") or 0.0
    tick_s = 0.02                                   # the swarm world's control tick
    out = {**summary, "us_per_robot_tick": tick_s / rtf / n * 1e6 if rtf else float("nan")}
    for k, v in (summary.get("plant_per_tick_ms") or {}).items():
        out[f"{k}_us_per_robot"] = v * 1e3 / n
    for k, v in (summary.get("cpu_per_tick_ms") or {}).items():
        out[f"{k}_cpu_ms_per_tick"] = v
    return out


def _kept(into: dict, key: str, fn):
    """``fn``, its result also kept in ``into[key]`` (for a later probe of the suite)."""
    def run() -> dict:
        got = into[key] = fn()
        return got
    return run


def composed_beside(ctx: Context, n: int, mode: str, duration: str, bound: dict) -> dict:
    """:func:`composed_run` with its shares of the bounds measured just before it
    (``bound``: "open" -> :func:`physics_rtf`'s, "steered" -> :func:`steered_physics_rtf`'s):
    its real-time factor over each, and its physics process's CPU a tick over DART's
    steered."""
    out = composed_run(ctx, n, mode, duration)
    rtf = out.get("real_time_factor") or 0.0
    for key in ("open", "steered"):
        alone = (bound.get(key) or {}).get("real_time_factor")
        if alone:
            out[f"share_of_{key}"] = rtf / alone
    steered_cpu = (bound.get("steered") or {}).get("cpu_ms_per_tick")
    if steered_cpu and out.get("physics_cpu_ms_per_tick"):
        out["physics_cpu_over_steered"] = out["physics_cpu_ms_per_tick"] / steered_cpu
    return out


def composed_swarm(ctx: Context):
    """Composed swarms, each beside DART (or the kinematic step) alone with as many robots."""
    duration = "2" if ctx.quick else "6"
    for mode, sizes in (("kinematic", (24, 96, 256)), ("dynamic", (24,))):
        for n in sizes:
            if ctx.quick and n > 96:
                continue
            bound: dict = {}
            alone = f"physics alone, {n} {mode} robots"
            yield Probe(alone, _kept(bound, "open", lambda n=n, mode=mode: physics_rtf(
                n, mode, ctx.tmpdir)), [
                Metric("real_time_factor", f"{alone}: real-time factor", "x",
                       notes="beside the composed run below: what the physics allows")]
                + ([Metric("cpu_ms_per_tick", f"{alone}: CPU a tick", "ms",
                           notes="process CPU: beside the composed run's physics process")]
                   if mode == "dynamic" else [])
                + ([Metric("contacts", f"{alone}: contacts a tick", "",
                           notes="the floor's alone (3 a robot); the composed swarm's "
                                 "robots touch walls and each other too, and DART's step "
                                 "costs more with each contact")] if mode == "dynamic" else []),
                repeats=1, warmup=0)
            if mode == "dynamic":
                steered = f"physics alone, {n} dynamic robots steered by their avoid controllers"
                yield Probe(steered, _kept(bound, "steered", lambda n=n: steered_physics_rtf(
                    n, ctx.tmpdir, float(duration))), [
                    Metric("real_time_factor", f"{steered}: real-time factor", "x",
                           notes="only DART's steps timed, the robots driven by the swarm's "
                                 "avoid on their scans in this process: the composed run's "
                                 "contacts, so its bound"),
                    Metric("cpu_ms_per_tick", f"{steered}: CPU a tick", "ms",
                           notes="the steps' thread CPU: beside the composed run's "
                                 "physics process, whatever else the cores run"),
                    Metric("contacts", f"{steered}: contacts a tick", "")],
                    repeats=1, warmup=0)
            what = f"swarm composed, {n} {mode} robots with lidars and avoid controllers"
            target = COMPOSED_TARGETS.get((mode, n), "")
            dynamic = mode == "dynamic"               # (its target is a share of DART's)
            yield Probe(what, lambda n=n, mode=mode, bound=bound: composed_beside(
                ctx, n, mode, duration, bound), [
                Metric("real_time_factor", f"{what}: real-time factor", "x",
                       target="" if dynamic else target,
                       notes=f"summary.json, {duration} s simulated, pipelined"),
                Metric("us_per_robot_tick", f"{what}: wall per robot per tick", "us",
                       notes="control tick / real-time factor / robots"),
                Metric("publish_us_per_robot", f"{what}: plant publishing per robot", "us",
                       notes="sensors, messages, the composed members, puts (a tick / robots)"),
                Metric("physics_us_per_robot", f"{what}: physics per robot", "us")]
                + ([Metric("share_of_steered", f"{what}: share of DART alone steered", "",
                           target=target, notes="its real-time factor over the steered "
                                                "bound's above: the fair one"),
                    Metric("share_of_open", f"{what}: share of DART alone open-loop", "",
                           notes="over the open-loop circles' (floor contacts alone)"),
                    Metric("physics_cpu_over_steered",
                           f"{what}: physics process CPU over DART alone steered's", "",
                           notes="1: the worker costs what DART alone does; the rest of "
                                 "the gap is the plant's CPU sharing the cores"),
                    Metric("physics_cpu_ms_per_tick", f"{what}: physics process CPU a tick",
                           "ms", notes="summary.json cpu_per_tick_ms: its DART step and "
                                       "hand-over, beside DART alone's CPU above"),
                    Metric("plant_cpu_ms_per_tick", f"{what}: plant CPU a tick", "ms",
                           notes="the plant's process, all threads: what competes with "
                                 "the physics process for the cores")]
                   if mode == "dynamic" else []),
                repeats=1, warmup=0)
