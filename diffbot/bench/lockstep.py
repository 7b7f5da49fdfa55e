"""Suite ``lockstep``: the plant's tick overhead with a trivial lockstep node."""
from __future__ import annotations

import json
import os
import shutil

from .common import private_endpoint, spawn, stop, tail
from .harness import Context, Metric, Probe, suite

LOCKSTEP_NODE = "bench_node"


def run_plant(ctx: Context, mode: str, duration_s: float, with_node: bool) -> dict:
    """One ``diffbot plant --world empty`` run (with one trivial lockstep node, or none).

    Returns the plant's stats plus derived per-tick numbers in seconds.
    """
    d, endpoint = private_endpoint(ctx, "ls")
    stats_path = os.path.join(d, "plant.json")
    children = []
    try:
        args = ["plant", "--world", "empty", "--mode", mode, "--duration", f"{duration_s:g}",
                "--stats", stats_path, "--endpoint", endpoint, "--log-level", "WARNING"]
        if with_node:
            args += ["--expect", LOCKSTEP_NODE]
        plant = spawn(args, os.path.join(d, "plant.log"))
        children.append(plant)
        if with_node:
            children.append(spawn(["controller", "wheel_schedule", "--schedule", "1000:1,1",
                                 "--name", LOCKSTEP_NODE, "--endpoint", endpoint,
                                 "--log-level", "WARNING"], os.path.join(d, "node.log")))
        rc = plant.wait(60 + 20 * duration_s)
        if rc is None:
            raise RuntimeError(f"plant did not finish: {tail(os.path.join(d, 'plant.log'))}")
        if rc != 0 or not os.path.exists(stats_path):
            raise RuntimeError(f"plant exited {rc}: {tail(os.path.join(d, 'plant.log'))}")
        with open(stats_path) as f:
            st = json.load(f)
    finally:
        stop(children)
        shutil.rmtree(d, ignore_errors=True)
    ticks = max(int(st.get("ticks") or 0), 1)
    per = st.get("per_tick_ms", {})
    wall_tick = st["wall_time_s"] / ticks
    physics = per.get("physics", 0.0) * 1e-3
    return {"rtf": st.get("real_time_factor"), "tick_s": wall_tick, "physics_s": physics,
            "overhead_s": wall_tick - physics, "publish_s": per.get("publish", 0.0) * 1e-3,
            "wait_s": per.get("wait", 0.0) * 1e-3, "ticks": ticks}


@suite("lockstep", "plant tick overhead: lockstep with one trivial node vs fast with none")
def lockstep_suite(ctx: Context):
    duration = 2.0 if ctx.quick else 10.0
    warm = 0 if ctx.quick else 1
    reps = 2 if ctx.quick else None
    tick = f"empty world, {duration:g} s sim = {int(round(duration / 0.02))} ticks"
    yield Probe("lockstep + 1 node", lambda: run_plant(ctx, "lockstep", duration, True), [
        Metric("overhead_s", "lockstep: tick overhead (wall - physics)", notes=tick),
        Metric("publish_s", "lockstep: publish per tick", notes="sensors + clock"),
        Metric("wait_s", "lockstep: wait for node per tick",
               notes="wheel_schedule node answers each tick"),
        Metric("physics_s", "lockstep: physics per tick", notes="20 steps"),
        Metric("rtf", "lockstep: real-time factor", "x"),
    ], repeats=reps, warmup=warm)
    yield Probe("fast, no node", lambda: run_plant(ctx, "fast", duration, False), [
        Metric("overhead_s", "fast: tick overhead (wall - physics)", notes=tick),
        Metric("physics_s", "fast: physics per tick", notes="20 steps"),
        Metric("rtf", "fast: real-time factor", "x"),
    ], repeats=reps, warmup=warm)
