"""Suite ``fmu``: odometry FMU steps (timed by fmus/bench.py)."""
from __future__ import annotations

import os

from .harness import ROOT, Case, Context, Skip, suite

@suite("fmu", "odometry FMU steps (timed by fmus/bench.py, when it exists)")
def fmu_suite(ctx: Context):
    path = os.path.join(ROOT, "fmus", "bench.py")
    if not os.path.exists(path):
        raise Skip("fmus/bench.py not available")
    try:
        import importlib
        mod = importlib.import_module("fmus.bench")
        benchmarks = mod.benchmarks
    except Exception as exc:
        raise Skip(f"fmus/bench.py not usable: {type(exc).__name__}: {exc}") from None
    try:
        items = list(benchmarks())
    except Exception as exc:
        raise Skip(f"fmus.bench.benchmarks() failed: {type(exc).__name__}: {exc}") from None
    return [Case(name, fn, timer=True, notes=desc) for name, desc, fn in items]
