"""Many runs through one engine: what a run is, the loop that runs them, the progress line.

A :class:`Run` is a command and an output folder (plus what the caller wants to keep
beside it: parameters, an estimate for ordering, the CPUs it reserves). :func:`run_all`
submits them to an engine (:mod:`.local` or :mod:`.ray_engine`), collects results as they
come, re-submits a failed run up to ``retries`` times, and on a stop request (Ctrl-C) has
the engine cancel what is queued and stop what runs. The engine decides where a run
goes; the run itself is :func:`.task.execute` wherever it lands.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import Callable

from . import procs

HEARTBEAT_S = 15.0             # a "still running" line this often (when no progress bar)


@dataclass
class Run:
    """One run: its command, output folder and log; filled in as it runs."""
    name: str
    argv: list[str]
    out: str
    log_path: str
    est_s: float = 0.0                 # expected wall time: longest first
    cpus: float = 1.0                  # CPUs its processes use (reserved on a Ray node)
    timeout_s: float = 900.0
    params: dict = field(default_factory=dict)
    spec: object = None                # the caller's own description of it
    env: dict = field(default_factory=dict)  # variables set for the command (on its node)
    # ---- filled in
    status: str = "waiting"            # waiting, running, ok, failed, timeout, interrupted, skipped
    exit_code: int | None = None
    wall_s: float | None = None
    summary: dict = field(default_factory=dict)
    log_tail: str = ""
    node: str = ""
    host: str = ""
    attempts: int = 0
    error: str = ""                    # why the engine could not run it (a node died, ...)

    def tail(self, n: int = 15) -> str:
        return self.log_tail or procs.tail(self.log_path, n)

    def take(self, result: dict) -> None:
        """Record what :func:`.task.execute` returned."""
        self.status = result["status"]
        self.exit_code = result["exit_code"]
        self.wall_s = result["wall_time_s"]
        self.summary = result["summary"]
        self.log_tail = result["log_tail"]
        self.node, self.host = result["node"], result["host"]
        self.error = ""


class Progress:
    """Progress lines on stderr, with the time since the start; on a terminal (or
    ``bar=True``) a bar with counts and an estimate of the time left is redrawn in place."""

    def __init__(self, what: str = "runs", bar: bool | None = None, stream=None) -> None:
        self.what = what
        self.stream = stream or sys.stderr
        self.bar = self.stream.isatty() if bar is None else bar
        self.t0 = time.monotonic()
        self._drawn = False

    def __call__(self, msg: str) -> None:
        self._clear()
        print(f"{self.what} [{time.monotonic() - self.t0:6.1f} s] {msg}", file=self.stream,
              flush=True)

    def update(self, done: int, total: int, running: int, failed: int) -> None:
        if not self.bar or not total:
            return
        el = time.monotonic() - self.t0
        eta = el / done * (total - done) if done else None
        width = 30
        fill = int(width * done / total)
        line = (f"\r{self.what} [{'#' * fill}{'.' * (width - fill)}] {done}/{total} "
                f"running {running} failed {failed} {_clock(el)} elapsed, "
                f"ETA {_clock(eta) if eta is not None else '?'}")
        self.stream.write(line + "\033[K")
        self.stream.flush()
        self._drawn = True

    def _clear(self) -> None:
        if self._drawn:
            self.stream.write("\r\033[K")
            self._drawn = False


def _clock(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def run_all(runs: list[Run], engine, stop_flag: list, say: Progress,
            on_done: Callable[[Run], None] = lambda r: None, retries: int = 0) -> None:
    """Run every run on ``engine``, longest first; ``on_done(run)`` once each has its final
    status. A run that failed (not interrupted) is submitted again, up to ``retries``
    times. When ``stop_flag`` becomes non-empty (a signal handler appends to it), queued
    runs are cancelled (status ``skipped``), running ones stopped (``interrupted``)."""
    queue = sorted(runs, key=lambda r: -r.est_s)
    window = engine.slots or len(runs)                   # runs handed to the engine at once
    pending: dict = {}                                   # handle -> run
    done = failed = 0
    last_beat = time.monotonic()
    while queue or pending:
        if stop_flag:
            say(f"{stop_flag[0]}: cancelling {len(queue) + len(pending)} queued or running "
                "run(s)")
            for run in queue:
                run.status = "skipped"
                on_done(run)
            for h, r in engine.cancel(list(pending)).items():
                run = pending[h]
                if r is None:
                    run.status = "skipped"
                else:
                    run.take(r)
                on_done(run)
            say.update(done, len(runs), 0, failed)
            return
        while queue and len(pending) < window:
            run = queue.pop(0)
            run.attempts += 1
            run.status = "running"
            pending[engine.submit(run)] = run
            if not say.bar:
                what = getattr(run.spec, "what", "")
                say(f"{'start' if engine.name == 'local' else 'submit'} {run.name}"
                    f"{': ' + what if what else ''} (log {run.log_path})")
        for h, result in engine.wait(list(pending), timeout_s=0.2):
            run = pending.pop(h)
            if isinstance(result, BaseException):        # the engine could not run it
                run.status, run.exit_code = "failed", None
                run.error = f"{type(result).__name__}: {result}"
                run.log_tail = run.log_tail or run.error
            else:
                run.take(result)
            if run.status in ("failed", "timeout") and run.attempts <= retries \
                    and not stop_flag:
                say(f"{run.name} {run.status} (exit code {run.exit_code}"
                    f"{', ' + run.error if run.error else ''}); retry "
                    f"{run.attempts}/{retries}")
                queue.insert(0, run)
                continue
            done += 1
            if run.status == "ok":
                if not say.bar:
                    say(f"done  {run.name} in {run.wall_s:.1f} s on {run.node} "
                        f"({done}/{len(runs)})")
            else:
                failed += 1
                say(f"FAILED {run.name} ({run.status}, exit code {run.exit_code}) after "
                    f"{run.wall_s or 0:.1f} s on {run.node or '?'} ({done}/{len(runs)})"
                    + (f": {run.error}" if run.error else "")
                    + f"; last lines of its log:\n{indent(run.tail())}")
            on_done(run)
        say.update(done, len(runs), len(pending), failed)
        now = time.monotonic()
        if not say.bar and pending and now - last_beat >= HEARTBEAT_S:
            last_beat = now
            say(f"{done}/{len(runs)} done, {len(pending)} submitted, {len(queue)} waiting")


def run_until_done(runs: list[Run], engine, say: Progress,
                   on_done: Callable[[Run], None] = lambda r: None, retries: int = 0) -> list[str]:
    """:func:`run_all` with Ctrl-C and SIGTERM turned into a stop request, the engine closed
    afterwards whatever happens (nothing outlives us), the handlers restored. Returns the
    names of the signals that stopped it (empty: it ran to the end)."""
    with procs.stop_requests() as stop_flag:
        try:
            run_all(runs, engine, stop_flag, say, on_done, retries)
        finally:
            engine.close()
    return stop_flag


def indent(text: str) -> str:
    return "\n".join("    " + line for line in text.splitlines()) or "    (empty log)"
