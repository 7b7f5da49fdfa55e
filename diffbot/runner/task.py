"""One run, as a plain function of its parameters that returns its result.

:func:`execute` starts one command (a ``diffbot run ...``, an experiment) as a
:class:`procs.Child` into its own output folder, waits for it, and returns a dict: status,
exit code, wall time, its ``summary.json``, the tail of its log, and the host it ran on.
It neither knows nor cares where it runs: the local engine calls it in a thread, the Ray
engine in a task on any node of a cluster. Whatever stops it -- ``cancel`` set, its
timeout, an exception such as the ``KeyboardInterrupt`` with which Ray cancels a task --
stops the command by PID (SIGINT, a grace period, SIGKILL to its whole tree) before it
returns or raises, so a run never leaves a process behind, on any node.
"""
from __future__ import annotations

import io
import os
import shutil
import socket
import tarfile
import time

from bus.jsonio import read_json

from . import procs

STOP_GRACE_S = 20.0            # a run's own shutdown (a scenario analyses its run on SIGINT too)
LOG_TAIL_LINES = 15
POLL_S = 0.05
#: the largest output folder a remote run ships back to the driver (bytes)
SHIP_LIMIT_BYTES = 64 * 1024 * 1024


def execute(argv: list[str], out: str, log_path: str, timeout_s: float = 900.0,
            cancel=None, node: str = "", ship: bool = False, env: dict | None = None) -> dict:
    """Run ``argv`` into ``out`` (emptied first), its output in ``log_path``.

    ``cancel`` is anything with ``is_set()`` (a :class:`threading.Event`): once set, the
    command is stopped and the status is ``interrupted``. ``node`` names where it ran in
    the result (default: the host name). ``ship`` puts the output folder, as a tar archive,
    into the result (``files``), for a driver on another machine. ``env``: variables set
    for the command on top of this process's environment.
    """
    if os.path.isdir(out):
        shutil.rmtree(out)                     # no stale outputs from an earlier attempt
    os.makedirs(out)
    os.makedirs(os.path.dirname(os.path.abspath(log_path)), exist_ok=True)
    child = procs.Child(os.path.basename(out), argv, log_path, die_with_parent=True,
                        env=dict(os.environ, **env) if env else None)
    status = "failed"
    host = socket.gethostname()
    try:
        child.start()
        while child.poll() is None:
            if cancel is not None and cancel.is_set():
                status = "interrupted"
                break
            if child.wall_s > timeout_s:
                status = "timeout"
                break
            time.sleep(POLL_S)
    except KeyboardInterrupt:                  # how Ray cancels a running task
        status = "interrupted"
    finally:
        # any way out (an exception, Ray's KeyboardInterrupt) stops the command first
        procs.stop([child], STOP_GRACE_S)
    code = child.exit_code
    if status == "failed" and code == 0:
        status = "ok"
    result = {"status": status, "exit_code": code, "wall_time_s": child.wall_s,
              "summary": read_json(os.path.join(out, "summary.json")),
              "log_tail": "" if status == "ok" else child.tail(LOG_TAIL_LINES),
              "host": host, "node": node or host, "pid": child.pid}
    if ship:
        result["files"] = pack(out)
    return result


def pack(folder: str) -> bytes | None:
    """The folder as a gzip'd tar archive (None if larger than :data:`SHIP_LIMIT_BYTES`)."""
    size = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(folder) for f in fs)
    if size > SHIP_LIMIT_BYTES:
        return None
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        tar.add(folder, arcname=".")
    return buf.getvalue()


def unpack(data: bytes, folder: str) -> None:
    """Write an archive from :func:`pack` into ``folder`` (replacing what was there)."""
    if os.path.isdir(folder):
        shutil.rmtree(folder)
    os.makedirs(folder)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        tar.extractall(folder, filter="data")
