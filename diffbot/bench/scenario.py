"""Suite ``scenario``: the square and follow scenarios end to end (``diffbot run``)."""
from __future__ import annotations

import os
import shutil
import tempfile

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
#: targets (composed, pipelined) and floors (over processes), x real time: composed
#: members skip the process hop per tick, so they are held to more
TARGETS = {("square", "composed"): 50.0, ("follow", "composed"): 12.0,
           ("square", "processes"): 17.0, ("follow", "processes"): 6.0}


@suite("scenario", "the square and follow scenarios end to end in lockstep (diffbot run), "
                   "under both couplings, members over processes and composed")
def scenario_suite(ctx: Context):
    for name in ("square", "follow"):
        for coupling in COUPLINGS:
            for hosting, flag in HOSTINGS.items():
                what = f"{name}, {coupling}, {hosting}"
                target = TARGETS.get((name, hosting)) if coupling == "pipelined" else None
                yield Probe(what, lambda name=name, c=coupling, f=flag: run_scenario(
                    ctx, name, 900.0, "--coupling", c, f), [
                    Metric("real_time_factor", f"{what}: real-time factor", "x",
                           notes="summary.json real_time_factor (plant, lockstep)"
                           + (f"; target >= {target:g}x" if target else "")),
                    Metric("wall_time_s", f"{what}: wall time",
                           notes="whole run incl. start-up, analysis"),
                    Metric("sim_time_s", f"{what}: simulated time"),
                ], repeats=1 if ctx.quick or name == "follow" else 3, warmup=0,
                    notes="no warm-up run")
