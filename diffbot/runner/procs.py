"""Child processes, started and stopped one way: by PID, never by name.

Every process ``diffbot`` starts (a scenario's nodes, the figures' jobs, the bench's
plants, an experiment's plant) is a :class:`Child`: its own session (process group, so a
Ctrl-C in the terminal reaches only the parent, which decides the order of shutdown),
its output in a log file, its exit code polled, its log's last lines at hand, and a
stop that escalates: a signal (SIGINT by default), a grace period, then SIGKILL to the
child, to every process below it that is still there (from /proc) and to its process
group, so nothing is orphaned even when a child dies before its own children.

    c = Child("plant", diffbot_argv("plant", ...), "out/logs/plant.log").start()
    ...
    stop([c], grace_s=1.5)          # SIGINT, wait, SIGKILL the rest of the tree
    print(c.exit_code, c.tail())
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections import deque
from contextlib import contextmanager
from typing import Iterator

#: lines of a log shown when a child failed
TAIL_LINES = 12
_SIGINT = signal.SIGINT      # (Child.signal shadows the module inside the class)


def diffbot_argv(*args: str) -> list[str]:
    """argv of a ``diffbot`` sub-command run with this interpreter."""
    return [sys.executable, "-m", "diffbot.cli", *args]


def _preexec(die_with_parent: bool):
    """What runs in the child before it execs: SIGINT and SIGTERM back to their defaults
    and unblocked (a parent that ignores them, e.g. while it shuts down, or a thread that
    blocks them, as a Ray task's does, must not pass that on: ignored and blocked signals
    survive exec, and the child would never see the stop request), and on Linux, if asked, SIGTERM from the kernel
    when this process dies, so a child never outlives a parent that was SIGKILLed. The
    libc function is looked up here, in the parent; the child only calls it."""
    prctl = None
    if die_with_parent and sys.platform.startswith("linux"):
        try:
            import ctypes
            prctl = ctypes.CDLL(None, use_errno=True).prctl
        except (OSError, AttributeError):
            prctl = None
    PR_SET_PDEATHSIG = 1
    parent = os.getpid()

    def preexec() -> None:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, (signal.SIGINT, signal.SIGTERM))
        if prctl is not None:
            prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM))
            if os.getppid() != parent:       # the parent died before prctl: no signal comes
                os.kill(os.getpid(), signal.SIGTERM)
    return preexec


def popen(argv: list[str], *, die_with_parent: bool = False, **kw) -> subprocess.Popen:
    """Start a child as every child of ours starts (``subprocess.Popen(argv, **kw)``): stop
    signals at their defaults in it, and with ``die_with_parent`` a SIGTERM from the kernel
    when this process dies. For a child that needs what :class:`Child` does not give, e.g.
    a descriptor passed on (``pass_fds``) and this process's own output."""
    return subprocess.Popen(argv, preexec_fn=_preexec(die_with_parent), **kw)


class Child:
    """One child process with a log file (see the module docstring).

    ``interactive`` keeps the terminal (stdin, stdout and the foreground process group,
    e.g. teleop); only stderr goes to the log. ``die_with_parent`` has the kernel send it
    SIGTERM if this process dies without stopping it.
    """

    def __init__(self, name: str, argv: list[str], log_path: str, *, env: dict | None = None,
                 cwd: str | None = None, interactive: bool = False,
                 die_with_parent: bool = False) -> None:
        self.name = name
        self.argv = list(argv)
        self.log_path = log_path
        self.env = env
        self.cwd = cwd
        self.interactive = interactive
        self.die_with_parent = die_with_parent
        self.proc: subprocess.Popen | None = None
        self.exit_code: int | None = None
        self.t_start = 0.0
        self.t_end = 0.0
        self._log = None

    # ---------------------------------------------------------------- life
    def start(self, env: dict | None = None) -> "Child":
        env = dict(env if env is not None else (self.env or os.environ))
        env.setdefault("PYTHONUNBUFFERED", "1")
        self._log = open(self.log_path, "wb")
        kw = dict(env=env, cwd=self.cwd, stderr=self._log if self.interactive
                  else subprocess.STDOUT)
        kw["die_with_parent"] = self.die_with_parent
        try:
            if self.interactive:
                self.proc = popen(self.argv, **kw)
            else:
                self.proc = popen(self.argv, stdin=subprocess.DEVNULL, stdout=self._log,
                                  start_new_session=True, **kw)
        except OSError:
            self.close_log()
            raise
        self.t_start = time.monotonic()
        return self

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    @property
    def started(self) -> bool:
        return self.proc is not None

    def poll(self) -> int | None:
        """The exit code once it ended (negative: killed by that signal), else None."""
        if self.proc is not None and self.exit_code is None:
            code = self.proc.poll()
            if code is not None:
                self._ended(code)
        return self.exit_code

    def running(self) -> bool:
        return self.proc is not None and self.poll() is None

    def wait(self, timeout_s: float | None = None) -> int | None:
        """Wait up to ``timeout_s`` for it to end; its exit code, or None if it still runs."""
        if self.proc is None:
            return None
        try:
            self._ended(self.proc.wait(timeout_s))
        except subprocess.TimeoutExpired:
            pass
        return self.exit_code

    def _ended(self, code: int) -> None:
        if self.exit_code is None:
            self.exit_code = code
            self.t_end = time.monotonic()
        self.close_log()

    @property
    def wall_s(self) -> float | None:
        if not self.t_start:
            return None
        return (self.t_end or time.monotonic()) - self.t_start

    def signal(self, sig: int) -> None:
        """Send ``sig`` to the child (by PID) if it still runs."""
        if self.running():
            _kill(self.proc.pid, sig)

    def stopped(self) -> bool:
        """The process is stopped (SIGSTOP, a debugger): state T or t in /proc."""
        return self.running() and _state(self.proc.pid) in ("T", "t")

    def stop(self, grace_s: float = 1.5, sig: int = _SIGINT) -> int | None:
        """Stop this child (see :func:`stop`); its exit code."""
        stop([self], grace_s, sig)
        return self.exit_code

    # ---------------------------------------------------------------- output
    def tail(self, n: int = TAIL_LINES) -> str:
        """The last ``n`` lines of its log."""
        return tail(self.log_path, n)

    def describe_exit(self) -> str:
        code = self.exit_code
        if code is not None and code < 0:
            try:
                return f"was killed by {signal.Signals(-code).name} (exit code {code})"
            except ValueError:
                pass
        return f"failed with exit code {code}"

    def close_log(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None


def stop(children: list[Child], grace_s: float = 1.5, sig: int = signal.SIGINT) -> None:
    """Send ``sig`` to every running child, wait up to ``grace_s`` for them all, then SIGKILL
    each one still there and every process of its tree that is left (by PID, from /proc:
    the tree is read before the signal too, so grandchildren orphaned meanwhile are found),
    and reap them. Children that already ended only get their log closed."""
    running = [c for c in children if c.running()]
    # (pid, start time): a PID that ends during the grace and is reused meanwhile by an
    # unrelated process is then not ours, and is left alone
    trees = {id(c): [(p, _start_time(p)) for p in descendants(c.pid)] for c in running}
    for c in running:
        _kill(c.pid, sig)
    deadline = time.monotonic() + grace_s
    while time.monotonic() < deadline and any(c.poll() is None for c in running):
        time.sleep(0.02)
    for c in running:
        left = [p for p, t0 in trees[id(c)] if alive(p) and _start_time(p) == t0]
        left += [p for p in descendants(c.pid) if alive(p)]
        if c.poll() is None:
            _kill(c.pid, signal.SIGKILL)
        if not c.interactive:                 # its own process group: daemonised ones too
            _killpg(c.pid, signal.SIGKILL)
        for p in left:
            _kill(p, signal.SIGKILL)
        if c.wait(5.0) is None:               # unkillable (D state): give up on it, said so
            c._ended(-signal.SIGKILL)
    for c in children:
        c.close_log()


def wait_all(children: list[Child], timeout_s: float) -> bool:
    """Wait up to ``timeout_s`` for every child to end; True if they all did."""
    deadline = time.monotonic() + timeout_s
    while any(c.poll() is None for c in children if c.started):
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.02)
    return True


def tail(path: str, n: int = TAIL_LINES) -> str:
    """The last ``n`` lines of a text file ("" if it cannot be read)."""
    try:
        with open(path, "rb") as f:
            return b"".join(deque(f, maxlen=n)).decode("utf-8", "replace").rstrip()
    except OSError:
        return ""


def descendants(pid: int | None) -> list[int]:
    """PIDs of every process below ``pid`` (from /proc), deepest last."""
    if pid is None:
        return []
    children: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(d))
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def alive(pid: int) -> bool:
    """The process exists and is not a zombie."""
    return _state(pid) not in (None, "Z")


def _start_time(pid: int) -> int | None:
    """When the process started (clock ticks since boot, /proc/<pid>/stat field 22)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return int(f.read().rsplit(")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return None


def _state(pid: int) -> str | None:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return None


def _kill(pid: int, sig: int) -> None:
    try:
        os.kill(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def _killpg(pgid: int, sig: int) -> None:
    """Signal a non-interactive child's process group (its PID: it leads its own session),
    which also reaches members that left the tree (double-forked, daemonised)."""
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        pass


@contextmanager
def stop_requests() -> Iterator[list[str]]:
    """A supervisor's stop signals: inside, SIGINT and SIGTERM do not end this process but
    append their names to the list it yields (the supervisor stops its children in order,
    then reports); on the way out the old handlers are back."""
    flag: list[str] = []

    def on_signal(signum, frame):
        flag.append(signal.Signals(signum).name)
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for s, h in old.items():
            signal.signal(s, h)
