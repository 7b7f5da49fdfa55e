"""Waits on processes, timed in the time they could run.

On a busy machine (other sessions' load; a background test's processes at a low CPU
priority, tests/conftest.py) a process can be ready to run and still wait seconds for a
CPU. A fixed wall-clock timeout then fails a test whose process was never slow, only not
scheduled. The clock here is the wall time minus the longest time any one thread of the
awaited processes, or of this one, has waited for a CPU since the wait began (Linux's
``/proc/<pid>/task/<tid>/schedstat``, its second field: time spent on a run queue).

A hang still ends the wait: a process blocked for good (a deadlock, a lost message) waits
on no run queue, so its clock runs with the wall clock; a spinning one runs as often as it
gets a CPU, and the test's own timeout (pytest-timeout) bounds the whole. Where the kernel
keeps no scheduler statistics the clock is the wall clock.
"""
from __future__ import annotations

import contextlib
import os
import queue
import time


def _run_queue_s(pid: int) -> dict[int, float]:
    """Each live thread of ``pid``: seconds it has spent waiting for a CPU."""
    out: dict[int, float] = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        try:
            with open(f"/proc/{pid}/task/{tid}/schedstat") as f:
                out[int(tid)] = int(f.read().split()[1]) * 1e-9
        except (OSError, IndexError, ValueError):
            pass                    # (the thread ended, or no scheduler statistics)
    return out


class Patience:
    """A timeout of ``timeout_s`` on the clock of ``pids`` (module docstring)."""

    def __init__(self, timeout_s: float, *pids: int) -> None:
        self.timeout_s = timeout_s
        self.pids = (os.getpid(), *(p for p in pids if p is not None))
        self.start = time.monotonic()
        self.base = {(pid, tid): s for pid in self.pids for tid, s in _run_queue_s(pid).items()}
        self.held_s = 0.0           # the longest a thread has waited for a CPU so far

    def elapsed(self) -> float:
        """Wall seconds since the start, less the longest run-queue wait of one thread."""
        for pid in self.pids:
            for tid, s in _run_queue_s(pid).items():
                self.held_s = max(self.held_s, s - self.base.get((pid, tid), 0.0))
        return max(0.0, time.monotonic() - self.start - self.held_s)

    def expired(self) -> bool:
        if time.monotonic() - self.start <= self.timeout_s:
            return False            # (within the limit on the wall clock too: no need to read)
        return self.elapsed() > self.timeout_s

    def fail(self, what: str):
        wall = time.monotonic() - self.start
        raise AssertionError(f"timed out after {self.timeout_s:g} s waiting for {what} "
                             f"({wall:.1f} s of wall time, {self.held_s:.1f} s of it "
                             "waiting for a CPU)")


def wait_until(pred, timeout_s: float, *pids: int, what: str = "condition",
               step: float = 0.02):
    """``pred()``'s first true value, polled every ``step`` s; AssertionError once
    ``timeout_s`` have passed on the clock of ``pids`` (this process's included)."""
    p = Patience(timeout_s, *pids)
    while True:
        v = pred()
        if v:
            return v
        if p.expired():
            p.fail(what)
        time.sleep(step)


def get(q, timeout_s: float, *pids: int, what: str = "a message"):
    """``q.get()`` within ``timeout_s`` on the clock of ``pids``; queue.Empty after, with
    what was waited for and how long."""
    p = Patience(timeout_s, *pids)
    while True:
        try:
            return q.get(timeout=0.05)
        except queue.Empty:
            if p.expired():
                raise queue.Empty(f"no {what} within {timeout_s:g} s ({p.held_s:.1f} s more "
                                  "waiting for a CPU)") from None


def listening(proc, endpoint: str, timeout_s: float = 30.0) -> None:
    """Return once the process ``proc`` (a plant started with ``--endpoint endpoint``, a
    unix socket) listens there: its socket file is there. AssertionError, with the end of
    its log where it has one, if it exits first or does not listen within ``timeout_s`` on
    its clock (a plant's start is a few CPU seconds of imports)."""
    path = endpoint.split("/", 1)[1]
    wait_until(lambda: proc.poll() is not None or os.path.exists(path), timeout_s, proc.pid,
               what=f"the plant to listen at {endpoint}")
    if proc.poll() is not None:
        log = getattr(proc, "log_path", None)
        tail = open(log, errors="replace").read()[-3000:] if log else ""
        raise AssertionError(f"the plant exited {proc.poll()} before listening:\n{tail}")


@contextlib.contextmanager
def sessions(endpoint: str, started: list):
    """``connect()``: a client session to ``endpoint``, closed at the end, opened once each
    plant of ``started`` (the test's processes) that serves ``endpoint`` listens there."""
    from bus.session import open_session
    opened = []

    def connect():
        for p in started:
            if p.poll() is None and "plant" in p.args and endpoint in p.args:
                listening(p, endpoint)
        opened.append(open_session("test", endpoint))
        return opened[-1]
    try:
        yield connect
    finally:
        for s in opened:
            s.close()
