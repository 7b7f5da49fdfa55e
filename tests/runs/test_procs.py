"""diffbot.runner.procs: children are stopped by PID with a grace and an escalation, and leave
nothing behind."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from diffbot.runner import procs

from ..conftest import wait_for


def _py(code: str) -> list[str]:
    return [sys.executable, "-c", textwrap.dedent(code)]


@pytest.mark.slow
def test_a_child_that_exits_reports_its_code_and_log_tail(tmp_path):
    c = procs.Child("talker", _py("""
        import sys
        for i in range(30):
            print(f"line {i}", flush=True)
        sys.stderr.write("oops on stderr\\n")
        sys.exit(3)
    """), str(tmp_path / "talker.log")).start()
    assert c.wait(20) == 3 and c.exit_code == 3 and not c.running()
    assert c.tail(3).splitlines() == ["line 28", "line 29", "oops on stderr"]
    assert c.describe_exit() == "failed with exit code 3"
    assert c.wall_s > 0


@pytest.mark.serial                  # a wall-clock promise: runs alone under xdist
@pytest.mark.slow
def test_a_child_that_ignores_sigint_is_killed_after_the_grace(tmp_path):
    c = procs.Child("stubborn", _py("""
        import signal, time
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        print("ready", flush=True)
        time.sleep(60)
    """), str(tmp_path / "stubborn.log")).start()
    wait_for(lambda: "ready" in procs.tail(c.log_path), 20, what="the child to start")
    t0 = time.monotonic()
    procs.stop([c], grace_s=0.5)
    took = time.monotonic() - t0
    assert c.exit_code == -signal.SIGKILL
    assert 0.4 < took < 5.0
    assert "SIGKILL" in c.describe_exit()
    assert not procs.alive(c.pid)


@pytest.mark.slow
def test_a_child_that_obeys_sigint_ends_cleanly_within_the_grace(tmp_path):
    c = procs.Child("polite", _py("""
        import sys, time
        try:
            print("ready", flush=True)
            time.sleep(60)
        except KeyboardInterrupt:
            print("bye", flush=True)
            sys.exit(0)
    """), str(tmp_path / "polite.log")).start()
    wait_for(lambda: "ready" in procs.tail(c.log_path), 20, what="the child to start")
    procs.stop([c], grace_s=10.0)
    assert c.exit_code == 0
    assert c.tail(1) == "bye"


@pytest.mark.slow
def test_a_child_started_where_stop_signals_are_blocked_still_obeys_sigint(tmp_path):
    """A blocked signal mask survives fork and exec (a Ray task's thread blocks SIGINT):
    the child starts with SIGINT and SIGTERM unblocked, so a stop ends it cleanly instead
    of waiting out the grace for a SIGKILL."""
    started = []

    def start_blocked() -> None:
        signal.pthread_sigmask(signal.SIG_BLOCK, (signal.SIGINT, signal.SIGTERM))
        started.append(procs.Child("polite", _py("""
            import signal, sys, time
            print("mask", sorted(int(s) for s in signal.pthread_sigmask(signal.SIG_BLOCK, [])),
                  flush=True)
            try:
                time.sleep(60)
            except KeyboardInterrupt:
                print("bye", flush=True)
                sys.exit(0)
        """), str(tmp_path / "polite.log")).start())
    t = threading.Thread(target=start_blocked)
    t.start()
    t.join()
    c = started[0]
    wait_for(lambda: "mask" in procs.tail(c.log_path), 20, what="the child to start")
    procs.stop([c], grace_s=10.0)
    assert c.exit_code == 0, c.tail()
    assert c.tail(2).splitlines() == ["mask []", "bye"]


@pytest.mark.slow
def test_no_grandchild_is_orphaned(tmp_path):
    """The child ignores SIGINT and so does the grandchild it started; stop() kills both by
    PID, including a grandchild whose parent died first."""
    pidfile = tmp_path / "grandchild.pid"
    c = procs.Child("parent", _py(f"""
        import signal, subprocess, sys, time
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        g = subprocess.Popen([sys.executable, "-c",
                              "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN);"
                              " time.sleep(60)"])
        open({str(pidfile)!r}, "w").write(str(g.pid))
        time.sleep(60)
    """), str(tmp_path / "parent.log")).start()
    wait_for(lambda: pidfile.exists() and pidfile.read_text(), 20, what="the grandchild")
    grandchild = int(pidfile.read_text())
    assert grandchild in procs.descendants(c.pid)
    procs.stop([c], grace_s=0.3)
    assert c.exit_code == -signal.SIGKILL
    wait_for(lambda: not procs.alive(grandchild), 5, what="the grandchild to die")


@pytest.mark.slow
def test_stopped_child_is_seen_and_still_stopped_by_pid(tmp_path):
    c = procs.Child("frozen", _py("import time; time.sleep(60)"),
                    str(tmp_path / "frozen.log")).start()
    os.kill(c.pid, signal.SIGSTOP)
    wait_for(c.stopped, 5, what="state T")
    procs.stop([c], grace_s=0.2)           # SIGINT stays pending on a stopped process
    assert c.exit_code == -signal.SIGKILL and not c.stopped()


@pytest.mark.slow
def test_stop_leaves_finished_children_alone(tmp_path):
    done = procs.Child("done", _py("pass"), str(tmp_path / "done.log")).start()
    assert done.wait(20) == 0
    procs.stop([done], grace_s=0.1)
    assert done.exit_code == 0


@pytest.mark.slow
def test_a_daemonised_grandchild_left_in_the_group_is_killed_too(tmp_path):
    """A grandchild whose parent exited at once is no longer below the child in /proc, but
    it is still in the child's process group: stop() kills the group as well."""
    pidfile = tmp_path / "orphan.pid"
    c = procs.Child("forker", ["sh", "-c", f"(sleep 60 & echo $! > {pidfile}); sleep 60"],
                    str(tmp_path / "forker.log")).start()
    wait_for(lambda: pidfile.exists() and pidfile.read_text().strip(), 20, what="the orphan")
    orphan = int(pidfile.read_text())
    assert orphan not in procs.descendants(c.pid)
    procs.stop([c], grace_s=2.0)
    wait_for(lambda: not procs.alive(orphan), 5, what="the orphan to die")


@pytest.mark.slow
def test_an_orphan_whose_clean_stop_hangs_ends_itself(tmp_path, monkeypatch):
    """A launcher SIGKILLed: the kernel sends its children SIGTERM (die_with_parent); one
    whose clean stop hangs (here: it never looks at its stop event) exits by itself
    ORPHAN_EXIT_S later, since nobody is left to SIGKILL it."""
    pidfile = tmp_path / "grandchild.pid"
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    hang = ("import sys, threading, time; sys.path.insert(0, %r); import bus.session as s; "
            "s.ORPHAN_EXIT_S = 1.0; s.install_stop_signals(threading.Event()); "
            "print('ready', flush=True); time.sleep(60)" % root)
    c = procs.Child("launcher", _py(f"""
        import sys, time
        sys.path.insert(0, {root!r})
        from diffbot.runner import procs
        g = procs.Child("node", [sys.executable, "-c", {hang!r}], {str(tmp_path / 'node.log')!r},
                        die_with_parent=True).start()
        open({str(pidfile)!r}, "w").write(str(g.pid))
        time.sleep(60)
    """), str(tmp_path / "launcher.log")).start()
    wait_for(lambda: pidfile.exists() and pidfile.read_text(), 20, what="the grandchild")
    grandchild = int(pidfile.read_text())
    wait_for(lambda: "ready" in procs.tail(str(tmp_path / "node.log")), 20,
             what="the grandchild to start")
    os.kill(c.pid, signal.SIGKILL)
    c.wait(5)
    wait_for(lambda: not procs.alive(grandchild), 8, what="the orphan to end itself")


@pytest.mark.slow
def test_a_stop_signal_that_comes_again_inside_the_handler_does_not_hang_the_process():
    """The parent-death signal comes once per thread of the child (a node's Zenoh session
    runs a dozen): a burst of SIGTERMs, the next one often while the handler of the first
    is inside Event.set, holding the event's lock. Setting the event again there hung the
    node for good (a fresh-clone CI run: a SIGKILLed launcher's recorder, controller or
    plant still there 40 s later). Here the second signal comes exactly there."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    code = _py("""
        import signal, sys, threading
        sys.path.insert(0, %r)
        from bus.session import install_stop_signals
        stop = threading.Event()
        install_stop_signals(stop)
        handler = signal.getsignal(signal.SIGTERM)
        notify_all = stop._cond.notify_all

        def notify_all_with_a_signal_on_the_way():      # inside Event.set, the lock held
            handler(signal.SIGTERM, None)
            notify_all()
        stop._cond.notify_all = notify_all_with_a_signal_on_the_way
        handler(signal.SIGTERM, None)
        print("stopped" if stop.is_set() else "not stopped")
    """ % root)
    try:
        r = subprocess.run(code, capture_output=True, text=True, timeout=20)
    except subprocess.TimeoutExpired:
        pytest.fail("the process hung in its stop-signal handler")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "stopped"


@pytest.mark.slow
def test_a_stopped_process_whose_exit_outlasts_the_orphan_check_exits_cleanly():
    """The stop handler arms a 0.5 s timer to look whether the parent is gone; the
    interpreter's finalization puts SIGALRM back to its default action, so a process still
    finalizing when that timer fired was killed by it (exit -14: the ROS 2 bridge, whose
    rclpy teardown takes ~0.5 s, about one stop in two)."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    code = _py("""
        import os, signal, sys, threading, time
        sys.path.insert(0, %r)
        from bus.session import install_stop_signals

        class SlowTeardown:                 # native teardown after atexit, made long
            def __del__(self):
                time.sleep(1.0)
        keep = SlowTeardown()
        stop = threading.Event()
        install_stop_signals(stop)
        os.kill(os.getpid(), signal.SIGINT)
        print("stopped" if stop.wait(5) else "not stopped", flush=True)
    """ % root)
    r = subprocess.run(code, capture_output=True, text=True, timeout=20)
    assert r.stdout.strip() == "stopped"
    assert r.returncode == 0, (r.returncode, r.stderr)
