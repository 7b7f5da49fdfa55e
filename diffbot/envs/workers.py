"""The batched env's chunks in worker processes (:class:`diffbot.envs.vector.AvoidVectorEnv`
with ``workers=K``): each a fresh interpreter (``python -m diffbot.envs.workers FD``)
holding a :class:`diffbot.envs.worlds.Worlds` and answering its parent's calls over a
socket pair (:func:`diffbot.envs.results.merge` joins the chunks' results)."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import traceback
from multiprocessing.connection import Connection

import numpy as np


def _serve(conn) -> None:
    """A worker process: envs of a batch (:class:`Worlds`, built from the first message,
    (n, kwargs)) answering its parent's calls ((method, args) -> ("ok", result) or
    ("error", exception, traceback)) until ``close``, or until the parent is gone (its end
    of the connection closed; the kernel's SIGTERM too, :func:`diffbot.runner.procs.popen`).
    Ctrl-C is the parent's to handle: it closes the batch."""
    from .worlds import Worlds
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    worlds = None
    try:
        try:
            n, kw = conn.recv()
            worlds = Worlds(n, **kw)
            conn.send(("ok", worlds.spaces()))
        except (EOFError, OSError):
            return
        except Exception as exc:
            conn.send(("error", exc, traceback.format_exc()))
            return
        episodes = _Episodes()
        while True:
            try:
                method, args = conn.recv()
            except (EOFError, OSError):
                return
            if method == "close":
                return
            try:
                value = getattr(worlds, method)(*args)
                conn.send(("ok", episodes.pack(value) if method == "step" else value))
            except Exception as exc:
                conn.send(("error", exc, traceback.format_exc()))
    finally:
        if worlds is not None:
            worlds.close()
        conn.close()


class _Episodes:
    """A step's ``info["plant"]`` across the pipe without the Episodes the parent has: an
    env's :class:`diffbot.envs.episode.Episode` is a new object at each of its resets
    (AvoidTask.reset) and the same one at every step after, so only the rows whose object
    changed since the last step are sent (pickling all of them cost ~8 us an env each way,
    a tenth of a step). The worker :meth:`pack` s, the parent's :class:`_Worker`
    :meth:`unpack` s, each side keeping the column as the last step left it."""

    def __init__(self) -> None:
        self.rows: list = []

    def pack(self, result: tuple) -> tuple:
        col = result[4].get("plant")
        if col is None:
            return result
        if len(self.rows) != len(col):
            self.rows = [None] * len(col)
        changed = [i for i, (e, old) in enumerate(zip(col, self.rows)) if e is not old]
        for i in changed:
            self.rows[i] = col[i]
        return result[:4] + ({**result[4], "plant": (changed, [col[i] for i in changed])},)

    def unpack(self, result: tuple) -> tuple:
        packed = result[4].get("plant")
        if packed is None:
            return result
        changed, episodes = packed
        if len(self.rows) != len(result[1]):
            self.rows = [None] * len(result[1])
        for i, e in zip(changed, episodes):
            self.rows[i] = e
        col = np.empty(len(self.rows), dtype=object)
        col[:] = self.rows
        return result[:4] + ({**result[4], "plant": col},)


class _Worker:
    """A chunk of the batch in a worker process (``python -m diffbot.envs.workers FD``,
    :func:`_serve`, over a socket pair; a fresh interpreter, so a user's script needs no
    ``if __name__ == "__main__"`` guard): the same calls as :class:`Worlds`, sent
    (:meth:`send`) and answered (:meth:`result`) apart, so that the chunks step at once."""

    def __init__(self, n: int, kw: dict) -> None:
        import diffbot
        from diffbot.runner import procs
        ours, theirs = socket.socketpair()
        root = os.path.dirname(os.path.dirname(os.path.abspath(diffbot.__file__)))
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            [root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}
        try:
            self.proc = procs.popen(
                [sys.executable, "-m", "diffbot.envs.workers", str(theirs.fileno())],
                die_with_parent=True, pass_fds=(theirs.fileno(),), env=env,
                stdin=subprocess.DEVNULL)
        finally:
            theirs.close()
        self.conn = Connection(ours.detach())
        self.conn.send((n, kw))
        self._method = ""
        self._episodes = _Episodes()

    def send(self, method: str, *args) -> None:
        self._method = method
        self.conn.send((method, args))

    def result(self):
        try:
            status, value, *tb = self.conn.recv()
        except (EOFError, OSError):
            raise RuntimeError(f"a batch worker process (pid {self.proc.pid}) died, "
                               f"exit code {self.proc.poll()}") from None
        if status == "error":
            raise value from RuntimeError(f"in the batch worker (pid {self.proc.pid}):\n{tb[0]}")
        return self._episodes.unpack(value) if self._method == "step" else value

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.conn.send(("close", ()))
            except (BrokenPipeError, OSError):
                pass
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.conn.close()


def cpus() -> int:
    """The CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:                         # (not on Linux)
        return os.cpu_count() or 1


if __name__ == "__main__":            # a batch's worker process (_Worker)
    _serve(Connection(int(sys.argv[1])))
