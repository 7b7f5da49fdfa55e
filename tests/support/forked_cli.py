"""Many ``diffbot`` commands for one interpreter's start-up: ``python -m tests.support.forked_cli``
reads a JSON list of argument lists on stdin and prints, as JSON, each command's
``[exit code, stderr]``.

It imports the command line's modules once, then forks a child per command, all at once.
A child is a process of its own, and runs ``diffbot.cli.main`` as ``python -m diffbot.cli
ARGS`` does: its own session, stdin and stdout /dev/null, stderr (file descriptor 2) a file,
its exit code what ``sys.exit(main())`` would give. Only the interpreter's start-up and the
imports (~0.3 s of CPU per command: tests/bus/test_fuzz.py runs ~80) are shared. For tests of
refusals that exit before anything starts; a command that does not exit within the timeout
is killed with its process group, and its code is -9.
"""
from __future__ import annotations

import importlib
import json
import os
import signal
import sys
import tempfile
import time
import traceback

#: the modules the commands' refusals run through (diffbot.cli imports them on demand)
PRELOAD = ("diffbot.cli", "diffbot.launch.launcher", "plant.process_cli", "fmus.fmu_node_cli",
           "controllers.square_path", "controllers.odometry", "controllers.teleop")
#: (s) how long a command may take
TIMEOUT_S = 60.0


def _child(argv: list[str], err_path: str) -> None:
    """In the forked child: run the command and leave with its exit code."""
    code = 1
    try:
        os.setsid()
        null = os.open(os.devnull, os.O_RDWR)
        err = os.open(err_path, os.O_WRONLY)
        os.dup2(null, 0)
        os.dup2(null, 1)
        os.dup2(err, 2)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        from diffbot import cli
        sys.argv = ["diffbot", *argv]
        try:
            code = cli.main(argv) or 0
        except SystemExit as exc:           # as the interpreter treats sys.exit's argument
            if exc.code is None or isinstance(exc.code, int):
                code = exc.code or 0
            else:
                print(exc.code, file=sys.stderr)
                code = 1
    except BaseException:                   # noqa: BLE001  (the interpreter would print it)
        traceback.print_exc()
        code = 1
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code if isinstance(code, int) else 1)


def run_all(commands: list[list[str]]) -> list[tuple[int, str]]:
    """Fork a child per command, all at once (as many processes started together), and
    wait for them: (exit code, stderr) each. Those still running after TIMEOUT_S are killed
    with their process groups."""
    with tempfile.TemporaryDirectory(prefix="forked_cli-") as tmp:
        errs = [os.path.join(tmp, f"{i}.err") for i in range(len(commands))]
        pids = []
        for argv, err in zip(commands, errs):
            open(err, "w").close()
            pid = os.fork()
            if pid == 0:
                _child(argv, err)
            pids.append(pid)
        status: dict[int, int] = {}
        deadline = time.monotonic() + TIMEOUT_S
        while len(status) < len(pids):
            for pid in pids:
                if pid not in status:
                    done, st = os.waitpid(pid, os.WNOHANG)
                    if done:
                        status[pid] = st
            if len(status) < len(pids):
                if time.monotonic() > deadline:
                    for pid in set(pids) - set(status):
                        os.killpg(pid, signal.SIGKILL)
                        status[pid] = os.waitpid(pid, 0)[1]
                time.sleep(0.005)
        out = []
        for pid, err in zip(pids, errs):
            with open(err) as f:
                out.append((os.waitstatus_to_exitcode(status[pid]), f.read()))
        return out


def main() -> int:
    commands = json.load(sys.stdin)
    for name in PRELOAD:
        importlib.import_module(name)
    json.dump(run_all([[str(a) for a in argv] for argv in commands]), sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
