"""What several suites share: child processes on a private bus endpoint, sensor scenes."""
from __future__ import annotations

import json
import os
import sys
import tempfile

from diffbot.runner import procs

from .harness import ROOT, Context


def spawn(args: list[str], log_path: str, module: str = "diffbot.cli") -> procs.Child:
    """Start ``python -m module args`` in its own session, output to ``log_path``."""
    return procs.Child(os.path.basename(log_path), [sys.executable, "-m", module, *args],
                       log_path, cwd=ROOT, die_with_parent=True).start()


def stop(children: list[procs.Child], grace_s: float = 3.0) -> None:
    """SIGINT every child still running, wait ``grace_s``, then SIGKILL its tree (by PID)."""
    procs.stop(children, grace_s)


def tail(path: str, n: int = 8) -> str:
    """The last ``n`` lines of a log, on one line."""
    return " | ".join(procs.tail(path, n).splitlines())


def run_summary(out: str, name: str, rc) -> dict:
    """The summary.json a ``diffbot run NAME --out OUT`` that exited ``rc`` wrote; a
    RuntimeError with the end of its log if there is none."""
    try:
        with open(os.path.join(out, "summary.json")) as f:
            return json.load(f)
    except (OSError, ValueError):
        raise RuntimeError(f"diffbot run {name} exited {rc} without a summary: "
                           f"{tail(os.path.join(out, 'run.log'))}") from None


def private_endpoint(ctx: Context, tag: str) -> tuple[str, str]:
    """(a fresh directory, a unix-socket endpoint in it): no port shared with anything."""
    d = tempfile.mkdtemp(prefix=f"{tag}-", dir=ctx.tmpdir)
    return d, f"unixsock-stream/{d}/bus.sock"


def sensor_scene(world: str, robot: str):
    """(spec, sim, robot state, Scene) of a shipped world with its robots at their start."""
    from plant.raycast import Scene
    from plant.sim import Simulation
    from plant.world import load_world
    spec = load_world(world)
    sim = Simulation(spec)
    return spec, sim, sim.state(robot), Scene(sim.shapes())


