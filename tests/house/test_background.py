"""The ``background`` mark (tests/conftest.py): a background test's processes run at the
low CPU priority, each in a session of its own, so that under `make test`'s two workers
they take only what the serial tests' wall-clock runs leave idle. Checked on a real process
and on what it starts."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from ..conftest import BACKGROUND_NICE, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.background]


def _nice(pid: int) -> int:
    with open(f"/proc/{pid}/stat") as f:
        return int(f.read().rsplit(")", 1)[1].split()[16])     # field 19: nice


def _autogroups_on() -> bool:
    try:
        with open("/proc/sys/kernel/sched_autogroup_enabled") as f:
            return f.read().strip() == "1"
    except OSError:
        return False


def test_a_background_test_s_processes_and_theirs_yield_the_cpu(tmp_path):
    pidfile = tmp_path / "grandchild.pid"
    code = ("import os, subprocess, sys, time; "
            "g = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)']); "
            f"open({str(pidfile)!r} + '.tmp', 'w').write(str(g.pid)); "
            f"os.replace({str(pidfile)!r} + '.tmp', {str(pidfile)!r}); time.sleep(60)")
    own = os.nice(0)
    p = subprocess.Popen([sys.executable, "-c", code])          # as a test starts a plant
    try:
        grandchild = int(wait_for(lambda: pidfile.is_file() and pidfile.read_text(), 30,
                                  what="the grandchild"))
        assert os.getsid(p.pid) == p.pid != os.getsid(0)          # a session of its own
        assert os.getsid(grandchild) == p.pid                     # ... shared with its own
        assert _nice(p.pid) == BACKGROUND_NICE
        if _autogroups_on():    # the kernel shares the CPU between sessions first
            for pid in (p.pid, grandchild):
                with open(f"/proc/{pid}/autogroup") as f:
                    assert f.read().split()[-1] == str(BACKGROUND_NICE), pid
        assert os.nice(0) == own                                  # the test itself: as it was
    finally:
        os.killpg(p.pid, 9)
        p.wait()
