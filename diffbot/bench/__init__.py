"""``diffbot bench``: a small benchmark harness and its suites.

    diffbot bench [--suite NAME ...] [--quick] [--repeats N] [--json FILE] [--list]

Speed is measured here and printed, never asserted in tests. The harness
(:mod:`.harness`: timing, statistics, the table, JSON, the CLI) runs suites; each suite
lives in its own module of this package and registers itself with ``@suite``:

- :class:`Case` -- a micro-benchmark: ``fn(number) -> total seconds`` (``timer=True``)
  or a plain callable timed with :func:`time.perf_counter`.
- :class:`Probe` -- one expensive run per repeat (a subprocess, a scenario) that
  returns several numbers at once, e.g. ``{"rtf": 2.8, "overhead_s": 3e-3}``.

**Adding a suite is one new file** here, e.g. ``diffbot/bench/raycast.py`` (the suite's
name is what ``@suite`` says; ``messages.py`` holds ``codec`` and ``roundtrip.py`` ``bus``,
so that no module shadows a top-level package's name)::

    from .harness import Case, suite

    @suite("raycast", "one 180-ray lidar sweep")
    def raycast_suite(ctx):
        return [Case("sweep 180 rays", lambda: caster.sweep(origin, angles))]

Every module of the package is imported when ``diffbot bench`` starts (the shipped
suites first, in :data:`ORDER`, then any other, by name). Import optional libraries
(rclpy, foxglove) inside the suite function and raise :class:`Skip` with the reason when
they are missing; a module that fails to import anyway is reported as a suite in error,
and the other suites still run. Helpers for suites that start processes (a private
endpoint, spawning and stopping by PID) are in :mod:`.common`.
"""
from __future__ import annotations

import importlib
import pkgutil

from .harness import (DEFAULT_REPEATS, QUICK_REPEATS, ROOT, SUITES, Case, Context,
                      Metric, Probe, Result, Skip, as_timer, autorange, build_parser,
                      fmt_value, machine_info, main, measure, percentile, run_case, run_probe,
                      run_suite, stats, suite, table)

__all__ = ["DEFAULT_REPEATS", "QUICK_REPEATS", "ROOT", "SUITES", "Case", "Context", "Metric",
           "Probe", "Result", "Skip", "as_timer", "autorange", "build_parser", "fmt_value",
           "machine_info", "main", "measure", "percentile", "run_case", "run_probe", "run_suite",
           "stats", "suite", "table", "load_suites"]

#: the shipped suites' modules, in the order ``--list`` shows and a full run runs them
ORDER = ("physics", "lidar", "camera", "messages", "roundtrip", "lockstep", "scenario", "fmu",
         "sweep")
_NOT_SUITES = {"harness", "common", "echo", "plantprofile", "__main__"}


def load_suites() -> None:
    """Import every suite module of this package (each registers itself in SUITES)."""
    found = sorted(m.name for m in pkgutil.iter_modules(__path__) if m.name not in _NOT_SUITES)
    for name in [n for n in ORDER if n in found] + [n for n in found if n not in ORDER]:
        try:
            importlib.import_module(f"{__name__}.{name}")
        except Exception as exc:             # one broken suite must not take the rest down
            SUITES.setdefault(name, _broken(name, exc))


def _broken(name: str, exc: Exception):
    def fails(ctx):
        raise RuntimeError(f"diffbot/bench/{name}.py does not import: "
                           f"{type(exc).__name__}: {exc}")
    fails.description = f"(does not import: {type(exc).__name__})"
    return fails


load_suites()
