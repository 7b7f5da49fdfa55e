"""A parallel job runner over :mod:`diffbot.procs`: run many ``diffbot`` commands, a few at
a time, longest first, each in its own output directory with its own log.

``diffbot figures`` runs the study's experiments and scenarios with it. A job is a
:class:`procs.Child` with a spec (``name``, ``est_s`` for ordering, ``what`` for progress
lines), an output directory (emptied before it starts) and a status: waiting, running,
ok, failed, timeout, interrupted or skipped. Stopping is :func:`procs.stop`: SIGINT by
PID (each job stops its own processes), a grace period, then SIGKILL to whatever is
left of its process tree.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
import time
from typing import Callable

from . import procs

STOP_GRACE_S = 20.0            # a job's own shutdown (a scenario analyses its run on SIGINT too)
HEARTBEAT_S = 15.0             # a "still running" line on stderr this often
LOG_TAIL_LINES = 15


class Job(procs.Child):
    """One job: ``spec`` (name, est_s, what), ``out`` directory, ``log_path``, ``argv``."""

    def __init__(self, spec, out: str, log_path: str, argv: list[str]) -> None:
        super().__init__(spec.name, argv, log_path)
        self.spec = spec
        self.out = out
        self.status = "waiting"
        self.summary: dict = {}

    def start(self, env: dict | None = None) -> "Job":
        if os.path.isdir(self.out):
            shutil.rmtree(self.out)              # no stale outputs from an earlier run
        os.makedirs(self.out)
        super().start(env)
        self.status = "running"
        return self

    def _ended(self, code: int) -> None:
        super()._ended(code)
        if self.status == "running":
            self.status = "ok" if code == 0 else "failed"
        self.summary = read_json(os.path.join(self.out, "summary.json"))

    def tail(self, n: int = LOG_TAIL_LINES) -> str:
        return super().tail(n)


def stop_jobs(jobs: list[Job], grace_s: float = STOP_GRACE_S, why: str = "interrupted") -> None:
    """Stop every running job (status ``why``): SIGINT, wait, SIGKILL what is left, by PID."""
    for j in jobs:
        if j.running():
            j.status = why
    procs.stop(jobs, grace_s)


class Progress:
    """Progress lines on stderr, with the time since the start."""

    def __init__(self, what: str = "figures") -> None:
        self.what = what
        self.t0 = time.monotonic()

    def __call__(self, msg: str) -> None:
        print(f"{self.what} [{time.monotonic() - self.t0:6.1f} s] {msg}", file=sys.stderr, flush=True)


def run_jobs(jobs: list[Job], parallel: int, timeout_s: float, stop_flag: list,
             say: Progress, on_done: Callable[[Job], None]) -> None:
    waiting = sorted(jobs, key=lambda j: -j.spec.est_s)       # longest first
    running: list[Job] = []
    done = 0
    last_beat = time.monotonic()
    while waiting or running:
        if stop_flag:
            say(f"{stop_flag[0]}: stopping {', '.join(j.name for j in running) or 'nothing'}")
            stop_jobs(running)
            for j in waiting:
                j.status = "skipped"
            for j in running:
                say(f"stopped {j.name} (exit code {j.exit_code})")
            return
        while waiting and len(running) < parallel:
            j = waiting.pop(0)
            try:
                j.start()
            except OSError as exc:
                j.status, j.exit_code = "failed", -1
                say(f"FAILED to start {j.name}: {exc}")
                on_done(j)
                continue
            running.append(j)
            say(f"start {j.name}: {j.spec.what} (pid {j.pid}, log {j.log_path})")
        for j in list(running):
            if j.poll() is None and j.wall_s > timeout_s:
                say(f"{j.name} exceeded --timeout {timeout_s:g} s; stopping it")
                stop_jobs([j], why="timeout")
            if j.exit_code is None:
                continue
            running.remove(j)
            done += 1
            if j.status == "ok":
                say(f"done  {j.name} in {j.wall_s:.1f} s ({done}/{len(jobs)})")
            else:
                say(f"FAILED {j.name} ({j.status}, exit code {j.exit_code}) after "
                    f"{j.wall_s:.1f} s ({done}/{len(jobs)}); last lines of {j.log_path}:\n"
                    + _indent(j.tail()))
            on_done(j)
        now = time.monotonic()
        if running and now - last_beat >= HEARTBEAT_S:
            last_beat = now
            say("running: " + ", ".join(f"{j.name} {j.wall_s:.0f} s" for j in running)
                + (f"; waiting: {', '.join(j.name for j in waiting)}" if waiting else ""))
        time.sleep(0.05)


def _indent(text: str) -> str:
    return "\n".join("    " + line for line in text.splitlines()) or "    (empty log)"


def read_json(path: str) -> dict:
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return {}
