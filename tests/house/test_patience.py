"""tests/support/patience.py: a wait on a process does not count the time the process spent
waiting for a CPU, and still ends when the process never does what is waited for."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from ..support import patience

pytestmark = pytest.mark.slow


def _busy_on(cpu: int) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", f"import os; os.sched_setaffinity(0, {{{cpu}}})"
                             "\nwhile True: pass"])


@pytest.mark.skipif(not os.path.exists(f"/proc/{os.getpid()}/schedstat"),
                    reason="no scheduler statistics (Linux schedstat)")
def test_the_time_a_process_waits_for_a_cpu_is_not_counted():
    """Two busy processes on one CPU: each waits for it about half the time, and the wait on
    one of them counts only the other half."""
    cpu = min(os.sched_getaffinity(0))
    a, b = _busy_on(cpu), _busy_on(cpu)
    try:
        time.sleep(0.3)                         # both pinned, both running
        p = patience.Patience(10.0, a.pid)
        t0 = time.monotonic()
        time.sleep(1.5)
        elapsed, wall = p.elapsed(), time.monotonic() - t0
    finally:
        for q in (a, b):
            q.kill()
            q.wait()
    assert p.held_s > 0.3 and elapsed <= wall - 0.3, (p.held_s, elapsed, wall)


@pytest.mark.timeout(60)
def test_a_wait_on_a_process_that_never_answers_still_ends():
    """A process blocked for good (here asleep) waits on no run queue: the wait ends after its
    timeout, as on the wall clock."""
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        with pytest.raises(AssertionError, match="timed out after 0.5 s waiting for nothing"):
            patience.wait_until(lambda: False, 0.5, sleeper.pid, what="nothing")
    finally:
        sleeper.kill()
        sleeper.wait()


def test_a_plant_that_exits_before_listening_is_named(tmp_path):
    gone = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    with pytest.raises(AssertionError, match="exited 3 before listening"):
        patience.listening(gone, f"unixsock-stream/{tmp_path}/bus.sock")


def test_a_bus_session_waits_for_the_test_s_plant_to_listen(endpoint):
    """The ``bus`` fixture's sessions: a plant the test started on the endpoint is waited for
    before connecting (here one that ends before it listens is named at once)."""
    code = "import time; time.sleep(1); raise SystemExit(3)"
    plant = subprocess.Popen([sys.executable, "-c", code, "plant", "--endpoint", endpoint])
    with patience.sessions(endpoint, [plant]) as connect:
        with pytest.raises(AssertionError, match="exited 3 before listening"):
            connect()
