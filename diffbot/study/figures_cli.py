"""``diffbot figures --out DIR``: the study's figures from the command line (which figures,
which jobs they need, progress, the index page): :mod:`diffbot.study.figures` makes each."""
from __future__ import annotations


import argparse
import os
import sys
import time

from bus.cliargs import ArgumentParser, nonneg_int, positive_float, positive_int

from .. import runner
from ..runner import Progress
from .report import build_report, write_outputs

EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
from .figures import FIGURES, JOBS, Context, FigureSpec, job_argv


def parse_only(text: str | None) -> list[int]:
    """``"4,12"``, ``"1-3,7"`` -> sorted figure numbers; ValueError names the bad part."""
    if text is None:
        return sorted(FIGURES)
    nums: set[int] = set()
    for part in text.replace(" ", "").split(","):
        if not part:
            continue
        try:
            lo, _, hi = part.partition("-")
            a, b = int(lo), int(hi or lo)
        except ValueError:
            raise ValueError(f"--only: {part!r} is not a figure number or range") from None
        if a > b:
            raise ValueError(f"--only: empty range {part!r}")
        for n in range(a, b + 1):
            if n not in FIGURES:
                raise ValueError(f"--only: there is no figure {n} (figures are "
                                 f"{min(FIGURES)}-{max(FIGURES)})")
            nums.add(n)
    if not nums:
        raise ValueError("--only: no figure numbers given")
    return sorted(nums)


# ------------------------------------------------------------------ running everything
def build_parser() -> argparse.ArgumentParser:
    lines = [f"  {n:2d} {f.file:30s} {', '.join(f.jobs)}" for n, f in FIGURES.items()]
    p = ArgumentParser(
        prog="diffbot figures", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run the experiments and scenarios behind the study's twelve figures and "
                    "write the figures, index.html, REPORT.md and figures.json into --out.",
        epilog="figures (number, file, the jobs it needs):\n" + "\n".join(lines))
    p.add_argument("--out", default=os.path.join("out", "figures"),
                   help="output directory (default out/figures); runs go to OUT/runs/")
    p.add_argument("--only", default=None, metavar="LIST",
                   help="only these figures, e.g. 4,12 or 1-3 (and only the jobs they need)")
    p.add_argument("--jobs", type=positive_int, default=2, metavar="N",
                   help="jobs run at the same time (default 2)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="seed for every run (default 0)")
    p.add_argument("--timeout", type=positive_float, default=480.0, metavar="S",
                   help="wall-clock limit per job (default 480 s)")
    runner.add_engine_args(p, None)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        numbers = parse_only(args.only)
    except ValueError as exc:
        print(f"diffbot figures: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    out = os.path.abspath(args.out)
    runs = os.path.join(out, "runs")
    os.makedirs(runs, exist_ok=True)
    for n in numbers:                            # no stale figure from an earlier run
        for name in (FIGURES[n].file, *(["follow.gif"] if n == 12 else [])):
            if os.path.exists(os.path.join(out, name)):
                os.remove(os.path.join(out, name))
    needed = sorted({j for n in numbers for j in FIGURES[n].jobs}, key=list(JOBS).index)
    jobs = {name: runner.Run(name, job_argv(JOBS[name], os.path.join(runs, name), args.seed),
                             os.path.join(runs, name), os.path.join(runs, f"{name}.log"),
                             est_s=JOBS[name].est_s, cpus=JOBS[name].cpus,
                             timeout_s=args.timeout, spec=JOBS[name])
            for name in needed}
    ctx = Context(out, jobs)
    say = Progress("figures", bar=False)
    try:
        engine = runner.make_engine(args.engine, args.address, args.jobs)
    except (ValueError, RuntimeError, ConnectionError) as exc:
        print(f"diffbot figures: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    say(f"{len(numbers)} figure(s) ({_ranges(numbers)}) from {len(jobs)} job(s) "
        f"({', '.join(needed)}) on the {engine.describe()}, seed {args.seed}; output in {out}")
    results: dict[int, dict] = {}

    def on_done(job: runner.Run) -> None:
        for n in numbers:
            f = FIGURES[n]
            if n in results or job.name not in f.jobs:
                continue
            if all(jobs[j].status == "ok" for j in f.jobs):
                results[n] = make_figure(ctx, f, say)
            elif all(jobs[j].status not in ("waiting", "running") for j in f.jobs):
                bad = [j for j in f.jobs if jobs[j].status != "ok"]
                results[n] = {"status": "not made",
                              "error": f"job {', '.join(bad)} {jobs[bad[0]].status} "
                                       f"(exit code {jobs[bad[0]].exit_code})"}

    t0 = time.monotonic()
    stop_flag = runner.run_until_done(list(jobs.values()), engine, say, on_done)
    wall = time.monotonic() - t0
    for n in numbers:
        results.setdefault(n, {"status": "not made", "error": "interrupted before its jobs finished"
                               if stop_flag else "its jobs did not run"})
    report = build_report(FIGURES, ctx, numbers, results, args, wall, bool(stop_flag))
    write_outputs(out, report)
    made = [n for n in numbers if results[n]["status"] == "ok"]
    failed_jobs = [j for j in jobs.values() if j.status not in ("ok",)]
    say(f"{len(made)}/{len(numbers)} figure(s) written in {wall:.1f} s: "
        f"{os.path.join(out, 'index.html')}, REPORT.md, figures.json")
    for n in numbers:
        if results[n]["status"] != "ok":
            say(f"figure {n} not written: {results[n]['error']}")
    if stop_flag:
        return EXIT_INTERRUPTED
    return 0 if len(made) == len(numbers) and not failed_jobs else EXIT_FAILED


def make_figure(ctx: Context, f: FigureSpec, say: Progress) -> dict:
    dest = os.path.join(ctx.out, f.file)
    try:
        made = f.build(ctx, dest)
    except Exception as exc:                     # one bad figure must not lose the others
        say(f"figure {f.number} FAILED: {type(exc).__name__}: {exc}")
        return {"status": "failed", "error": f"{type(exc).__name__}: {exc}"}
    say(f"wrote {f.file}")
    return {"status": "ok", "caption": made.caption, "parameters": made.parameters,
            "numbers": made.numbers, "extra_files": made.extra_files}


def _ranges(nums: list[int]) -> str:
    out, i = [], 0
    while i < len(nums):
        j = i
        while j + 1 < len(nums) and nums[j + 1] == nums[j] + 1:
            j += 1
        out.append(str(nums[i]) if i == j else f"{nums[i]}-{nums[j]}")
        i = j + 1
    return ",".join(out)



