"""Suite ``sweep``: the runner's throughput and per-run overhead, local engine vs local Ray.

A batch of short runs (``diffbot run drive-test --duration 2``, different seeds) goes
through :func:`diffbot.runner.run_all`: once with as many at a time as the machine holds
(runs per minute), once one at a time, where the batch's wall time less the runs' own wall
times (each ``diffbot run`` process from start to exit, start-up included), divided by
the number of runs, is what the engine adds to each run (submitting, scheduling, a
worker, handing the result back). Ray's own start-up (a private instance) is reported
apart; it is paid once per sweep.
"""
from __future__ import annotations

import importlib.util
import os
import shutil
import tempfile
import time

from .harness import Context, Metric, Probe, suite

SIM_S = 2.0
#: the square runs of the hosting comparison, simulated s
SQUARE_S = 20.0


def batch(ctx: Context, engine_name: str, n: int, parallel: int | None,
          scenario: str = "drive-test", hosting: str = "--no-compose",
          sim_s: float = SIM_S) -> dict:
    from .. import runner
    from ..runner.procs import diffbot_argv
    tmp = tempfile.mkdtemp(prefix="bench-sweep-", dir=ctx.tmpdir)
    t0 = time.monotonic()
    engine = runner.make_engine(engine_name, None, parallel)
    t_up = time.monotonic() - t0
    try:
        runs = [runner.Run(f"s{i}", diffbot_argv("run", scenario, "--duration", f"{sim_s:g}",
                                                 "--seed", str(i), hosting, "--out",
                                                 os.path.join(tmp, f"s{i}")),
                           os.path.join(tmp, f"s{i}"), os.path.join(tmp, f"s{i}.log"))
                for i in range(n)]
        t0 = time.monotonic()
        runner.run_all(runs, engine, [], runner.Progress("bench", bar=False,
                                                         stream=open(os.devnull, "w")))
        wall = time.monotonic() - t0
    finally:
        engine.close()
        shutil.rmtree(tmp, ignore_errors=True)
    bad = [r for r in runs if r.status != "ok"]
    if bad:
        raise RuntimeError(f"{bad[0].name} {bad[0].status}: {bad[0].tail()}")
    own = sum(r.wall_s for r in runs)
    return {"runs_per_min": 60.0 * n / wall, "overhead_s": (wall - own) / n,
            "run_wall_s": own / n, "startup_s": t_up}


@suite("sweep", "the runner: runs per minute of a batch of short drive-test runs and the "
                "per-run overhead, local engine and a local Ray instance; square runs with "
                "their members over processes and composed")
def sweep_suite(ctx: Context):
    n = 4 if ctx.quick else 6
    engines = ["local"]
    if importlib.util.find_spec("ray"):      # (not imported here: see ray_engine)
        engines.append("ray")
    else:                                    # the [cluster] extra is missing: local only
        ctx.progress("bench sweep: ray is not installed; the local engine only")
    for name in engines:
        yield Probe(f"{name}: {n} runs, machine-wide", lambda name=name: batch(ctx, name, n, None), [
            Metric("runs_per_min", f"{name}: runs per minute ({n} x drive-test {SIM_S:g} s, "
                                   "all CPUs)", "runs/min"),
            Metric("run_wall_s", f"{name}: one run's own wall time (parallel)"),
        ], repeats=1 if ctx.quick else 2)
        yield Probe(f"{name}: {n} runs, one at a time", lambda name=name: batch(ctx, name, n, 1), [
            Metric("overhead_s", f"{name}: per-run overhead (batch wall - runs' wall) / runs",
                   notes="submit, schedule, result back; the run's own start-up not included"),
            Metric("run_wall_s", f"{name}: one run's own wall time (serial)"),
            Metric("startup_s", f"{name}: engine start-up (once per sweep)"),
        ], repeats=1 if ctx.quick else 2)
    # what `diffbot sweep` does by default: the members composed into each run's plant
    for hosting, flag in (("processes", "--no-compose"), ("composed", "--compose")):
        yield Probe(f"square {SQUARE_S:g} s, {hosting}",
                    lambda flag=flag: batch(ctx, "local", n, None, "square", flag, SQUARE_S), [
            Metric("runs_per_min", f"local: runs per minute ({n} x square {SQUARE_S:g} s, "
                                   f"members {hosting})", "runs/min"),
        ], repeats=1)
