"""Suite ``lockstep``: the plant's tick overhead with trivial lockstep nodes, both couplings."""
from __future__ import annotations

import json
import os
import shutil

from bus.protocol import COUPLINGS

from .common import private_endpoint, spawn, stop, tail
from .harness import Context, Metric, Probe, suite
from .roundtrip import bus_suite

LOCKSTEP_NODE = "bench_node"


def run_plant(ctx: Context, mode: str, duration_s: float, nodes: int,
              coupling: str = "sequential") -> dict:
    """One ``diffbot plant --world empty`` run with ``nodes`` trivial lockstep nodes (each
    sends one wheel command per tick), or none. Returns the plant's stats plus derived
    per-tick numbers in seconds."""
    d, endpoint = private_endpoint(ctx, "ls")
    stats_path = os.path.join(d, "plant.json")
    names = [f"{LOCKSTEP_NODE}{i}" for i in range(nodes)]
    children = []
    try:
        args = ["plant", "--world", "empty", "--mode", mode, "--coupling", coupling,
                "--duration", f"{duration_s:g}", "--stats", stats_path, "--endpoint", endpoint,
                "--log-level", "WARNING"]
        if names:
            args += ["--expect", ",".join(names)]
        plant = spawn(args, os.path.join(d, "plant.log"))
        children.append(plant)
        for name in names:
            children.append(spawn(["controller", "wheel_schedule", "--schedule", "1000:1,1",
                                   "--name", name, "--endpoint", endpoint,
                                   "--log-level", "WARNING"], os.path.join(d, f"{name}.log")))
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


@suite("lockstep", "plant tick overhead in lockstep (both couplings, 1/2/4 trivial nodes) next "
                   "to the bus round trip, and fast mode with no node")
def lockstep_suite(ctx: Context):
    duration = 2.0 if ctx.quick else 10.0
    warm = 0 if ctx.quick else 1
    reps = 2 if ctx.quick else None
    tick = f"empty world, {duration:g} s sim = {int(round(duration / 0.02))} ticks"
    rtt = bus_suite(ctx)              # the reference: one bus round trip, measured here too
    try:
        case = next(rtt)
        case.notes = "the reference for the lockstep overhead; " + case.notes
        yield case
    finally:
        rtt.close()
    for coupling in COUPLINGS:
        for n in (1,) if ctx.quick else (1, 2, 4):
            what = f"{coupling}, {n} node{'s' if n > 1 else ''}"
            yield Probe(what, lambda n=n, c=coupling: run_plant(ctx, "lockstep", duration, n, c), [
                Metric("overhead_s", f"lockstep {what}: tick overhead (wall - physics)",
                       notes=tick + "; each node: one wheel_cmd per tick"),
                Metric("publish_s", f"lockstep {what}: publish per tick", notes="sensors + clock"),
                Metric("wait_s", f"lockstep {what}: wait for the nodes per tick"),
                Metric("rtf", f"lockstep {what}: real-time factor", "x"),
            ], repeats=reps, warmup=warm)
    yield Probe("fast, no node", lambda: run_plant(ctx, "fast", duration, 0), [
        Metric("overhead_s", "fast: tick overhead (wall - physics)", notes=tick),
        Metric("physics_s", "fast: physics per tick", notes="20 steps"),
        Metric("rtf", "fast: real-time factor", "x"),
    ], repeats=reps, warmup=warm)
