"""The local engine: a pool of threads on this machine, each running one
:func:`.task.execute` (which starts and watches one command), nothing to start first."""
from __future__ import annotations

import concurrent.futures as cf
import os
import threading

from .task import execute


def default_parallel(cpus_per_run: float = 1.0) -> int:
    """As many runs at once as the machine's CPUs hold (at least one)."""
    return max(1, int((os.cpu_count() or 1) // max(cpus_per_run, 1e-9)))


class LocalEngine:
    name = "local"

    def __init__(self, max_parallel: int) -> None:
        self.slots = max_parallel
        self._pool = cf.ThreadPoolExecutor(max_workers=max_parallel,
                                           thread_name_prefix="diffbot-run")
        self._cancel = threading.Event()

    def describe(self) -> str:
        return f"local engine, {self.slots} run(s) at a time on {os.cpu_count()} CPU(s)"

    def submit(self, run) -> cf.Future:
        return self._pool.submit(execute, run.argv, run.out, run.log_path, run.timeout_s,
                                 self._cancel)

    def wait(self, handles: list, timeout_s: float) -> list[tuple]:
        done, _ = cf.wait(handles, timeout=timeout_s, return_when=cf.FIRST_COMPLETED)
        return [(h, h.exception() or h.result()) for h in done]

    def cancel(self, handles: list) -> dict:
        """Cancel queued runs (result None), stop running ones and wait for their results."""
        self._cancel.set()
        out = {h: None for h in handles}
        for h in handles:
            if not h.cancel():                    # already running: it stops its command
                try:
                    out[h] = h.result()
                except Exception:
                    out[h] = None
        return out

    def close(self) -> None:
        self._cancel.set()
        self._pool.shutdown(wait=True, cancel_futures=True)
