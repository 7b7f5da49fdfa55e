"""A stop signal ends a process's wait for events at once (bus.session.wake_on_stop):
its handler sets the stop event and puts a wake-up in every inbox (as the orphan check's
SIGALRM handler does after it), so the main thread looks at the event without waiting out
the rest of its timeout. Without the wake-up,
CPython 3.11's SimpleQueue, interrupted by a signal, waits out the whole timeout after the
handler ran, or forever when the handler took it past its deadline: a realtime plant kept
stepping after its SIGINT about once in forty stops, and was SIGKILLed by `diffbot run`."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from ..conftest import ROOT

#: the signal goes to the main thread itself (as the kernel may choose to deliver it)
CODE = """
import json, os, signal, threading, time
from bus.inbox import Inbox
from bus.session import install_stop_signals
stop = threading.Event()
inbox = Inbox(None)
install_stop_signals(stop)
main = threading.main_thread().ident
threading.Timer(0.2, signal.pthread_kill, (main, signal.{sig})).start()
t0 = time.monotonic()
got = inbox.get(timeout=10.0)
waited, after = time.monotonic() - t0, inbox.get_nowait()
# the orphan check's SIGALRM, half a second after the stop signal, comes in a wait too
t1 = time.monotonic()
again = inbox.get(timeout=10.0)
print(json.dumps({{"got": repr(got), "stopped": stop.is_set(), "waited_s": waited,
                  "after": repr(after), "again": repr(again),
                  "alarm_waited_s": time.monotonic() - t1}}))
"""


@pytest.mark.slow
@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_stop_signal_ends_the_main_thread_s_wait_for_events(sig):
    out = subprocess.run([sys.executable, "-c", CODE.format(sig=sig)], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout)
    assert r["stopped"] and r["got"] == "None" and r["after"] == "None", r
    # woken, not timed out: the wait ends with the signal (0.2 s), well before its 10 s
    assert r["waited_s"] < 5.0, r
    # and the next one with the orphan check's SIGALRM (0.5 s after the signal)
    assert r["again"] == "None" and r["alarm_waited_s"] < 5.0, r


def test_the_stop_signal_keeps_no_inbox_alive():
    """An env that builds a bus node per episode makes an inbox each time: the stop
    signal's list of them holds them weakly, so it does not grow with the episodes."""
    import gc

    from bus import session
    from bus.inbox import Inbox
    before = len(session._WAKE_ON_STOP)
    kept = Inbox(None)
    for _ in range(100):
        Inbox(None)
    gc.collect()
    assert len(session._WAKE_ON_STOP) == before + 1 and kept in session._WAKE_ON_STOP
