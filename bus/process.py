"""The scaffold of every process entry point (plant, nodes, record, replay, view, the ROS 2
bridge, the router): its exit codes, its log, its bus session, its stop signals and its
``--stats`` file, written once here.

    def main(argv=None) -> int:                    # bus.session.add_process_args(parser)
        return process_main(body, build_parser(), argv, "replay")

    def body(proc: Process) -> int:
        session = proc.open("plant")               # a bad endpoint: logged, exit 2
        thing = Thing(session, proc.log)
        proc.stats = thing.stats                   # what --stats writes at exit
        proc.stop_on_signals(thing.stop_event)     # SIGINT/SIGTERM set it, once
        try:
            return thing.run()
        finally:
            thing.close()

:func:`run_process` sets up the log (``--log-level``, the process's name on each line),
turns an :class:`Exit` raised anywhere in the body into its logged message and exit code,
and at the end closes the session (a close that times out is logged, not raised), then
writes ``--stats`` (after the session closed: a path it cannot write is one logged error,
never a hang at exit). A process that seems stuck tells where each of its threads is on
SIGUSR1 (``kill -USR1 PID``: Python's :mod:`faulthandler`, to its stderr, the run's log;
it works while the main thread is blocked inside native code, where no Python signal
handler would run), and goes on.
"""
from __future__ import annotations

import argparse
import faulthandler
import logging
import signal
import sys
import threading
from typing import Callable

import zenoh

from .jsonio import write_stats
from .keys import Keys
from .log import setup_logging
from .plantwatch import EXIT_PLANT_GONE
from .session import BusConfigError, close_session, install_stop_signals, open_node, open_session

#: the exit codes every process shares (docs/failures.md): 0 stopped or done, 1 failed,
#: 2 bad configuration or input (one line, no traceback), 3 the plant went away,
#: 4 an awaited input's producer left the simulation
EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_CONFIG = 2
EXIT_INPUT_GONE = 4
__all__ = ["EXIT_OK", "EXIT_FAILED", "EXIT_BAD_CONFIG", "EXIT_PLANT_GONE", "EXIT_INPUT_GONE",
           "Exit", "Process", "process_main", "run_process"]


class Exit(Exception):
    """End the process with ``code``, logging ``message`` as an error (if any)."""

    def __init__(self, code: int, message: object = "") -> None:
        super().__init__(str(message))
        self.code = code


class Process:
    """What :func:`run_process` hands the body: the parsed ``args``, the ``log``, and the
    session and statistics it closes and writes at the end."""

    def __init__(self, args: argparse.Namespace, name: str) -> None:
        self.args = args
        self.name = name
        self.log: logging.Logger = setup_logging(name, getattr(args, "log_level", "INFO"))
        self.session: zenoh.Session | None = None
        #: what ``--stats`` writes at exit: a dict, or a callable giving one (None: nothing),
        #: called once the session is closed (it may first close what it reads them from)
        self.stats: dict | Callable[[], dict | None] | None = None

    @property
    def keys(self) -> Keys:
        """The keys of ``--namespace`` (ValueError for a bad one)."""
        return Keys(self.args.namespace)

    def open(self, role: str = "node") -> zenoh.Session:
        """The session of the bus options (``--endpoint``, ``--zenoh-config``), closed at
        the end; a bad endpoint or config, or a plant that cannot be reached, is
        ``Exit(EXIT_BAD_CONFIG)``."""
        try:
            self.session = open_session(role, self.args.endpoint, self.args.zenoh_config)
        except BusConfigError as exc:
            raise Exit(EXIT_BAD_CONFIG, exc) from None
        return self.session

    def open_node(self, name: str) -> tuple[Keys, zenoh.Session]:
        """A bus node's keys and session (:func:`bus.session.open_node`: the namespace and
        ``name`` checked first); any of them wrong is ``Exit(EXIT_BAD_CONFIG)``."""
        try:
            keys, self.session = open_node(self.args, name)
        except (BusConfigError, ValueError) as exc:
            raise Exit(EXIT_BAD_CONFIG, exc) from None
        return keys, self.session

    def stop_on_signals(self, event: threading.Event) -> None:
        """SIGINT and SIGTERM set ``event`` (:func:`bus.session.install_stop_signals`)."""
        install_stop_signals(event)

    def _stats(self) -> dict | None:
        return self.stats() if callable(self.stats) else self.stats


def run_process(body: Callable[[Process], int | None], args: argparse.Namespace,
                name: str) -> int:
    """Run ``body(Process(args, name))`` in the scaffold (module docstring); its exit code."""
    proc = Process(args, name)
    try:
        faulthandler.register(signal.SIGUSR1, file=sys.stderr, all_threads=True, chain=False)
    except (AttributeError, ValueError, OSError):
        pass     # run in a host whose stderr is no file (a test's captured output)
    try:
        code = body(proc)
    except Exit as exc:
        if str(exc):
            proc.log.error("%s", exc)
        code = exc.code
    finally:
        if proc.session is not None:
            close_session(proc.session, proc.log)
        write_stats(getattr(args, "stats", None), proc._stats(), proc.log)
    return EXIT_OK if code is None else code


def process_main(body: Callable[[Process], int | None], parser: argparse.ArgumentParser,
                 argv: list[str] | None, name: str | Callable[[argparse.Namespace], str]
                 = lambda args: args.name) -> int:
    """A whole entry point: ``argv`` parsed by ``parser``, then :func:`run_process` with the
    process's ``name`` (a string, or a function of the parsed options; default ``--name``)."""
    args = parser.parse_args(argv)
    return run_process(body, args, name if isinstance(name, str) else name(args))
