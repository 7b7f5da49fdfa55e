"""Suite ``startup``: how long a process of each kind takes to start (its imports, its
argument parsing), the cost every node, plant and recorder of a run pays once.

Each repeat starts ``python -m diffbot.cli <command> --help`` and reads its wall time and
the child's CPU time (user + system, from the operating system's accounting); a process
of a run pays this plus opening its Zenoh session."""
from __future__ import annotations

import os
import subprocess
import sys
import time

from .harness import Metric, Probe, suite

COMMANDS = {
    "plant": ["plant"],
    "controller": ["controller", "square_path"],
    "fmu-node": ["fmu-node"],
    "record": ["record"],
}


def _start(args: list[str]) -> dict:
    before = os.times()
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "diffbot.cli", *args, "--help"], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=120)
    wall = time.perf_counter() - t0
    after = os.times()
    cpu = (after.children_user - before.children_user) + \
        (after.children_system - before.children_system)
    return {"wall_s": wall, "cpu_s": cpu}


@suite("startup", "a process's start-up: python -m diffbot.cli COMMAND --help, wall and CPU")
def startup_suite(ctx):
    n = 3 if ctx.quick else 7
    for name, args in COMMANDS.items():
        yield Probe(f"start {name}", lambda a=args: _start(a), [
            Metric("wall_s", f"start {name} (wall)"),
            Metric("cpu_s", f"start {name} (CPU)")], repeats=ctx.repeats or n, warmup=1,
            notes="imports and argument parsing, before any session")
