"""The harness of ``diffbot bench``: timing, statistics, the table, JSON, the CLI.

    diffbot bench [--suite NAME ...] [--quick] [--repeats N] [--json FILE] [--list]

Speed is measured here and printed, never asserted in tests. Each suite is a
function registered in :data:`SUITES` that returns (or yields) cases:

- :class:`Case` -- a micro-benchmark: ``fn(number) -> total seconds`` (``timer=True``)
  or a plain callable timed with :func:`time.perf_counter`. ``number`` is picked so
  that one repeat takes ~0.1-0.2 s (:func:`autorange`); a warm-up call comes first.
- :class:`Probe` -- one expensive run per repeat (a subprocess, a scenario) that
  returns several numbers at once, e.g. ``{"rtf": 2.8, "overhead_s": 3e-3}``.

Adding a suite takes a few lines::

    @suite("raycast", "one 180-ray lidar sweep")
    def raycast_suite(ctx):
        return [Case("sweep 180 rays", lambda: caster.sweep(origin, angles))]

A suite that cannot run raises :class:`Skip` with the reason. Units: ``"s"`` values
are seconds per operation in the JSON and printed as ns/µs/ms/s; ``"x"`` is a
real-time factor (simulated seconds per wall second). Results go to stdout as an
aligned table, progress to stderr, and everything to ``--json FILE``.
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import math
import os
import platform
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable

from bus.cliargs import ArgumentParser, positive_int

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

#: One repeat of a micro-benchmark aims at this much wall time (s): normal, --quick.
MIN_TIME_S, QUICK_MIN_TIME_S = 0.1, 0.02
TARGET_TIME_S, QUICK_TARGET_TIME_S = 0.15, 0.03
DEFAULT_REPEATS, QUICK_REPEATS = 5, 3
MAX_NUMBER = 10_000_000


# ============================================================================ cases
class Skip(Exception):
    """Raised by a suite (or a case) that cannot run here; the message says why."""


@dataclass
class Case:
    """A micro-benchmark of one operation.

    ``fn`` is ``fn(number) -> total seconds for number operations`` when ``timer`` is
    true, otherwise a plain callable (one call = one operation) timed with perf_counter.
    ``number`` fixes the operations per repeat (default: auto-picked). ``target``: the
    figure the case must meet (e.g. ``"<= 0.7 ms"``), printed beside the median.
    """
    name: str
    fn: Callable
    timer: bool = False
    unit: str = "s"
    notes: str = ""
    number: int | None = None
    target: str = ""
    repeats: int | None = None
    warmup: int = 1


@dataclass
class Metric:
    """One number a :class:`Probe` reports: ``key`` in its result dict, shown as ``name``."""
    key: str
    name: str
    unit: str = "s"
    notes: str = ""
    target: str = ""          # as Case.target


@dataclass
class Probe:
    """An expensive measurement: each repeat is one call of ``fn() -> {key: value}``."""
    name: str
    fn: Callable[[], dict]
    metrics: list[Metric]
    repeats: int | None = None
    warmup: int = 0
    notes: str = ""


@dataclass
class Context:
    """What a suite may want to know: quick mode, an explicit repeat count, a temp dir."""
    quick: bool = False
    repeats: int | None = None
    tmpdir: str = field(default_factory=tempfile.gettempdir)

    def progress(self, msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)


#: name -> function(Context) returning an iterable of Case / Probe (a generator may
#: hold resources open across its cases and release them in ``finally``).
SUITES: dict[str, Callable[[Context], Iterable]] = {}


def suite(name: str, description: str = ""):
    """Decorator registering a suite function under ``name``."""
    def register(fn):
        fn.description = description
        SUITES[name] = fn
        return fn
    return register


# ============================================================================ timing
def as_timer(fn: Callable[[], object], clock: Callable[[], float] = time.perf_counter):
    """Turn a plain callable into ``timer(number) -> total seconds`` (like timeit)."""
    def timer(number: int) -> float:
        it = range(number)
        t0 = clock()
        for _ in it:
            fn()
        return clock() - t0
    return timer


def autorange(timer: Callable[[int], float], min_time: float = MIN_TIME_S,
              target: float = TARGET_TIME_S, max_number: int = MAX_NUMBER) -> tuple[int, float]:
    """Smallest ``number`` found for which ``timer(number)`` takes >= ``min_time``.

    Grows ``number`` by the factor the last timing suggests (aiming at ``target``,
    at least x2, at most x10 per try), so one repeat ends up at ~min_time..2*target.
    Returns (number, seconds of the last try).
    """
    number = 1
    while True:
        t = timer(number)
        if t >= min_time or number >= max_number:
            return number, t
        factor = 10.0 if t <= 0 else min(10.0, max(2.0, target / t))
        number = min(max_number, int(math.ceil(number * factor)))


def percentile(values: list[float], q: float) -> float:
    """``q``-th percentile (0-100), linear interpolation between closest ranks."""
    v = sorted(values)
    if not v:
        return math.nan
    k = (len(v) - 1) * q / 100.0
    lo, hi = math.floor(k), math.ceil(k)
    return v[lo] + (v[hi] - v[lo]) * (k - lo)


def stats(samples: list[float]) -> dict:
    """median, min, max, mean, p90 and quartiles of ``samples``."""
    if not samples:
        return {k: None for k in ("median", "min", "max", "mean", "p90", "q1", "q3")}
    return {"median": percentile(samples, 50), "min": min(samples), "max": max(samples),
            "mean": sum(samples) / len(samples), "p90": percentile(samples, 90),
            "q1": percentile(samples, 25), "q3": percentile(samples, 75)}


def measure(timer: Callable[[int], float], repeats: int = DEFAULT_REPEATS,
            number: int | None = None, warmup: int = 1, min_time: float = MIN_TIME_S,
            target: float = TARGET_TIME_S) -> tuple[int, list[float]]:
    """Warm up, pick ``number`` (unless given), then time ``repeats`` repeats.

    Returns (number, per-operation seconds of each repeat).
    """
    for _ in range(warmup):
        timer(1)
    if number is None:
        number, _ = autorange(timer, min_time, target)  # its last try is a full-size warm-up
    return number, [timer(number) / number for _ in range(repeats)]


# ============================================================================ running
@dataclass
class Result:
    suite: str
    name: str
    unit: str
    samples: list[float]
    number: int = 1
    notes: str = ""
    error: str | None = None
    target: str = ""

    def as_dict(self) -> dict:
        return {"suite": self.suite, "name": self.name, "unit": self.unit, **stats(self.samples),
                "repeats": len(self.samples), "number": self.number, "samples": self.samples,
                "notes": self.notes, **({"target": self.target} if self.target else {}),
                **({"error": self.error} if self.error else {})}


def _repeats(ctx: Context, own: int | None) -> int:
    if ctx.repeats is not None:
        return ctx.repeats
    if own is not None:
        return own
    return QUICK_REPEATS if ctx.quick else DEFAULT_REPEATS


def run_case(ctx: Context, suite_name: str, case: Case) -> Result:
    timer = case.fn if case.timer else as_timer(case.fn)
    min_time, target = (QUICK_MIN_TIME_S, QUICK_TARGET_TIME_S) if ctx.quick else \
        (MIN_TIME_S, TARGET_TIME_S)
    number, samples = measure(timer, _repeats(ctx, case.repeats), case.number, case.warmup,
                              min_time, target)
    return Result(suite_name, case.name, case.unit, samples, number, case.notes,
                  target=case.target)


def run_probe(ctx: Context, suite_name: str, probe: Probe) -> list[Result]:
    n = _repeats(ctx, probe.repeats)
    for i in range(probe.warmup):
        ctx.progress(f"  [{suite_name}] {probe.name}: warm-up run {i + 1}/{probe.warmup}")
        probe.fn()
    runs = []
    for i in range(n):
        ctx.progress(f"  [{suite_name}] {probe.name}: run {i + 1}/{n}")
        runs.append(probe.fn())
    out = []
    for i, m in enumerate(probe.metrics):
        vals = [float(r[m.key]) for r in runs if r.get(m.key) is not None]
        notes = "; ".join(x for x in (m.notes, probe.notes if i == 0 else "") if x)
        out.append(Result(suite_name, m.name, m.unit, vals, 1, notes,
                          None if vals else f"no {m.key!r} in any run", m.target))
    return out


def run_suite(ctx: Context, name: str) -> tuple[list[Result], dict]:
    """Run one suite; returns its results and a status dict (ok / skipped / error)."""
    results: list[Result] = []
    status = {"name": name, "status": "ok"}
    ctx.progress(f"[{name}] {getattr(SUITES[name], 'description', '')}")
    t0 = time.monotonic()
    try:
        cases = SUITES[name](ctx)
        with contextlib.closing(cases) if hasattr(cases, "close") else contextlib.nullcontext():
            for case in cases:
                label = case.name
                try:
                    if isinstance(case, Probe):
                        got = run_probe(ctx, name, case)
                    else:
                        got = [run_case(ctx, name, case)]
                except Skip as exc:
                    ctx.progress(f"  [{name}] {label}: skipped: {exc}")
                    continue
                except (KeyboardInterrupt, GeneratorExit):
                    raise
                except Exception as exc:
                    msg = f"{type(exc).__name__}: {exc}"
                    ctx.progress(f"  [{name}] {label}: FAILED: {msg}")
                    got = [Result(name, label, getattr(case, "unit", "s"), [], error=msg)]
                for r in got:
                    results.append(r)
                    if r.samples:
                        ctx.progress(f"  [{name}] {r.name}: {fmt_value(stats(r.samples)['median'], r.unit)}"
                                     f" (median of {len(r.samples)} x {r.number})")
    except Skip as exc:
        status = {"name": name, "status": "skipped", "reason": str(exc)}
        ctx.progress(f"[{name}] skipped: {exc}")
    except KeyboardInterrupt:
        raise
    except Exception as exc:
        status = {"name": name, "status": "error", "reason": f"{type(exc).__name__}: {exc}"}
        ctx.progress(f"[{name}] FAILED: {status['reason']}")
    status["wall_time_s"] = time.monotonic() - t0
    if status["status"] == "ok" and any(r.error for r in results):
        status["status"] = "error"
    return results, status


# ============================================================================ report
def machine_info() -> dict:
    from importlib.metadata import PackageNotFoundError, version
    vers = {}
    for pkg in ("dartpy", "eclipse-zenoh", "rosbags", "numpy", "fmpy"):
        try:
            vers[pkg] = version(pkg)
        except PackageNotFoundError:
            vers[pkg] = None
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        affinity = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        affinity = None
    try:
        load = list(os.getloadavg())
    except OSError:
        load = None
    return {"cpu_count": os.cpu_count(), "cpus_usable": affinity, "cpu_model": cpu,
            "platform": platform.platform(), "python": platform.python_version(),
            "python_implementation": platform.python_implementation(),
            "versions": vers, "load_avg_start": load,
            "started": datetime.datetime.now().astimezone().isoformat(timespec="seconds")}


def fmt_value(v: float | None, unit: str, scale: tuple[float, str] | None = None) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if unit == "s":
        f, u = scale or time_scale(v)
        return f"{_num(v / f)} {u}"
    if unit == "x":
        return f"{_num(v)} xRT"
    return f"{_num(v)} {unit}"


def time_scale(v: float) -> tuple[float, str]:
    a = abs(v)
    if a < 1e-6:
        return 1e-9, "ns"
    if a < 1e-3:
        return 1e-6, "µs"
    if a < 1.0:
        return 1e-3, "ms"
    return 1.0, "s"


def _num(x: float) -> str:
    a = abs(x)
    if a >= 100:
        return f"{x:.0f}"
    if a >= 10:
        return f"{x:.1f}"
    return f"{x:.2f}"


def table(results: list[Result], statuses: list[dict], info: dict) -> str:
    v = info["versions"]
    lines = [
        f"diffbot bench  {info['started']}",
        f"machine: {info['cpu_count']} CPUs ({info['cpu_model']}), {info['platform']}",
        f"python {info['python']}, dartpy {v.get('dartpy')}, eclipse-zenoh {v.get('eclipse-zenoh')}, "
        f"rosbags {v.get('rosbags')}, numpy {v.get('numpy')}; load avg at start "
        + (" ".join(f"{x:.2f}" for x in info["load_avg_start"]) if info.get("load_avg_start")
           else "n/a"),
        "",
    ]
    head = ["suite", "case", "median", "target", "min", "p90", "max", "n", "notes"]
    rows = []
    for r in results:
        if r.error:
            rows.append([r.suite, r.name, "FAILED", r.target, "", "", "", "", r.error])
            continue
        s = stats(r.samples)
        sc = time_scale(s["median"]) if r.unit == "s" else None
        rows.append([r.suite, r.name, fmt_value(s["median"], r.unit, sc), r.target,
                     *(fmt_value(s[k], r.unit, sc) for k in ("min", "p90", "max")),
                     f"{len(r.samples)}x{r.number}" if r.number > 1 else str(len(r.samples)),
                     r.notes])
    for st in statuses:
        if st["status"] == "skipped":
            rows.append([st["name"], "(suite)", "skipped", "", "", "", "", "", st["reason"]])
        elif st["status"] == "error" and "reason" in st:
            rows.append([st["name"], "(suite)", "FAILED", "", "", "", "", "", st["reason"]])
    widths = [max([len(head[i])] + [len(row[i]) for row in rows]) for i in range(len(head) - 1)]
    right = {2, 3, 4, 5, 6, 7}

    def line(cells):
        out = [c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(cells, widths))]
        return "  ".join(out + [cells[-1]]).rstrip()
    lines.append(line(head))
    lines.append(line(["-" * w for w in widths] + ["-----"]))
    prev = None
    for row in rows:
        if prev is not None and row[0] != prev:
            lines.append("")
        lines.append(line(row))
        prev = row[0]
    lines += ["", "n = repeats x operations per repeat (subprocess suites: runs); times are per "
                  "operation; xRT = simulated seconds per wall second."]
    return "\n".join(lines)


# ============================================================================ CLI
def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="diffbot bench", description="Run benchmark suites and "
                                "print median / min / p90 / max per operation.")
    p.add_argument("--suite", action="append", default=[], metavar="NAME",
                   help="suite to run (repeatable or comma-separated; default: all)")
    p.add_argument("--quick", action="store_true", help="fewer repeats, smaller runs")
    p.add_argument("--repeats", type=positive_int, default=None, metavar="N",
                   help=f"repeats per case (default {DEFAULT_REPEATS}, --quick {QUICK_REPEATS}; "
                        "some suites use fewer)")
    p.add_argument("--json", metavar="FILE", help="also write machine info and every case as JSON")
    p.add_argument("--list", action="store_true", help="list the suites and exit")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.list:
        for name, fn in SUITES.items():
            print(f"{name:10s} {getattr(fn, 'description', '')}")
        return 0
    names = [n.strip() for s in args.suite for n in s.split(",") if n.strip()] or list(SUITES)
    unknown = [n for n in names if n not in SUITES]
    if unknown:
        print(f"diffbot bench: unknown suite {', '.join(map(repr, unknown))} "
              f"(known: {', '.join(SUITES)})", file=sys.stderr)
        return 2
    names = list(dict.fromkeys(names))
    info = machine_info()
    tmp = tempfile.mkdtemp(prefix="dbb-")
    ctx = Context(quick=args.quick, repeats=args.repeats, tmpdir=tmp)
    results: list[Result] = []
    statuses: list[dict] = []
    interrupted = False
    try:
        for name in names:
            got, st = run_suite(ctx, name)
            results += got
            statuses.append(st)
    except KeyboardInterrupt:
        interrupted = True
        print("diffbot bench: interrupted; reporting what finished", file=sys.stderr)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    with contextlib.suppress(OSError):
        info["load_avg_end"] = list(os.getloadavg())
    print(table(results, statuses, info))
    if args.json:
        doc = {"tool": "diffbot bench", "format": 1, "machine": info,
               "options": {"suites": names, "quick": args.quick, "repeats": args.repeats},
               "suites": statuses, "cases": [r.as_dict() for r in results],
               "interrupted": interrupted}
        with open(args.json, "w") as f:
            json.dump(doc, f, indent=2, allow_nan=False, default=str)
            f.write("\n")
        print(f"diffbot bench: wrote {args.json}", file=sys.stderr)
    if interrupted:
        return 130
    return 1 if any(st["status"] == "error" for st in statuses) else 0
