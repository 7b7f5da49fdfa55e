"""Zenoh sessions with safe defaults.

The plant opens a *router* session listening on exactly one endpoint (loopback
TCP by default, or a unix socket); every other node opens a *client* session
connected to it, so messages between nodes are routed through the plant's
session and nothing else listens anywhere. Multicast and gossip scouting are off.
A user's own Zenoh JSON5 config (router, TLS, remote machines) replaces these
defaults unchanged.
"""
from __future__ import annotations

import argparse
import atexit
import json
import math
import os
import re
import signal
import threading
import time
import weakref

import zenoh

from .keys import Keys, check_name
from .linkcheck import ConfigFileError, diagnose, load_config, refusals

DEFAULT_ENDPOINT = os.environ.get("DIFFBOT_ENDPOINT", "tcp/127.0.0.1:7450")

#: Lease after which a frozen (not killed) peer is declared gone, ms.
DEFAULT_LEASE_MS = 1000
#: Handshake limit for opening a link, ms (bounds close() while the router is frozen).
OPEN_TIMEOUT_MS = 500
#: A client session is opened in attempts this long (of the config's connect/timeout_ms);
#: between two the endpoints are probed, so a refusal (TLS, a tcp/ client at a tls/ router)
#: is reported within a few seconds rather than when the whole timeout has run out.
ATTEMPT_MS = 1000


class BusConfigError(ValueError):
    """A bad endpoint or Zenoh configuration file."""


def make_config(role: str, endpoint: str = DEFAULT_ENDPOINT, config_file: str | None = None,
                lease_ms: int = DEFAULT_LEASE_MS) -> zenoh.Config:
    """Zenoh configuration for ``role`` ("plant" listens, anything else connects).

    With ``config_file`` the user's file is used as it is: their config, their rules
    (``${VAR}`` filled in from the environment, see ``bus.linkcheck``).
    """
    if config_file:
        try:
            return load_config(config_file)
        except ConfigFileError as exc:
            raise BusConfigError(str(exc)) from None
    conf = zenoh.Config()

    def put(key: str, value) -> None:
        conf.insert_json5(key, json.dumps(value))

    put("scouting/multicast/enabled", False)
    put("scouting/gossip/enabled", False)
    # With scouting off there is nobody to scout for, but a router's open still waits
    # scouting/delay (500 ms by default) for them: half a second of every plant's start-up.
    put("scouting/delay", 0)
    put("transport/link/tx/lease", int(lease_ms))
    put("transport/link/tx/keep_alive", 4)
    # A frozen (SIGSTOPped) router still accepts connections in the kernel, so a client's
    # reconnect hangs in the handshake and close() waits for it (10 s by default).
    put("transport/unicast/open_timeout", OPEN_TIMEOUT_MS)
    put("timestamping/enabled", False)
    try:
        if role == "plant":
            put("mode", "router")
            put("listen/endpoints", [endpoint])
            put("connect/endpoints", [])
        else:
            put("mode", "client")
            put("listen/endpoints", [])
            put("connect/endpoints", [endpoint])
            # Try for a while before giving up on a plant that is still starting.
            put("connect/timeout_ms", 15000)
            put("connect/exit_on_failure", True)
            put("connect/retry", {"period_init_ms": 50, "period_max_ms": 500,
                                  "period_increase_factor": 1.5})
    except Exception as exc:
        raise BusConfigError(f"bad endpoint {endpoint!r}: {exc}") from None
    return conf


_RUST_SOURCE = re.compile(r"\s+at\s+\S+\.rs:\d+\.?")
_NO_LISTENER = re.compile(r"Unable to connect to any of \[.*\]\.?\s*Timeout!?\.?")


def zenoh_error(exc: BaseException) -> str:
    """A Zenoh error as a user reads it: without the Rust source path it carries
    (``at /root/.cargo/.../orchestrator.rs:388``), "nothing listens there" in words."""
    text = _RUST_SOURCE.sub("", str(exc)).strip()
    return _NO_LISTENER.sub("nothing answered there (timed out)", text) or type(exc).__name__


def open_session(role: str, endpoint: str = DEFAULT_ENDPOINT,
                 config_file: str | None = None,
                 lease_ms: int = DEFAULT_LEASE_MS) -> zenoh.Session:
    """A session, or BusConfigError naming each endpoint and why it failed (refused,
    timeout, unknown CA, name mismatch, certificate required, ...) and the config file.
    ``lease_ms``: after how long frozen the others drop this process (:func:`make_config`)."""
    conf = make_config(role, endpoint, config_file, lease_ms)
    try:
        return _open_in_attempts(conf)
    except BusConfigError as exc:
        src = f" (config {config_file})" if config_file else ""
        raise BusConfigError(f"{exc}{src}") from None
    except Exception as exc:
        causes = "; ".join(diagnose(conf)) or zenoh_error(exc)
        src = f" (config {config_file})" if config_file else ""
        hint = "" if config_file or role == "plant" or "running" in causes else \
            " [is `diffbot plant` running with the same --endpoint?]"    # (asked once)
        raise BusConfigError(f"{causes}{src}{hint}") from None


def _json(conf: zenoh.Config, key: str):
    try:
        return json.loads(conf.get_json(key))
    except Exception:
        return None


def _open_in_attempts(conf: zenoh.Config) -> zenoh.Session:
    """``zenoh.open(conf)``; a client that Zenoh would keep retrying for its whole
    ``connect/timeout_ms`` (with ``exit_on_failure``) tries in ATTEMPT_MS slices instead,
    and between two, a refusal that retrying cannot change (:func:`bus.linkcheck.refusals`:
    an unknown CA, a missing certificate, a tcp/ client at a tls/ router, ...) is a
    BusConfigError at once, naming the endpoint and the cause. A router not up yet (refused,
    no socket file) is waited for as long as the config says."""
    total = _json(conf, "connect/timeout_ms")
    if (_json(conf, "mode") != "client" or _json(conf, "connect/exit_on_failure") is not True
            or not isinstance(total, (int, float)) or isinstance(total, bool)
            or 0 <= total <= ATTEMPT_MS):
        return zenoh.open(conf)
    deadline = time.monotonic() + (total / 1000 if total >= 0 else math.inf)
    conf.insert_json5("connect/timeout_ms", str(ATTEMPT_MS))
    try:
        while True:
            try:
                return zenoh.open(conf)
            except Exception as exc:
                if "connect" not in str(exc).lower() or time.monotonic() >= deadline:
                    raise
            refused = refusals(conf)
            if refused:
                raise BusConfigError("; ".join(refused))
    finally:
        conf.insert_json5("connect/timeout_ms", json.dumps(total))   # (diagnose reads it)


def open_when_listening(endpoint: str, missed, pause_s: float = 0.2) -> zenoh.Session:
    """A client session to ``endpoint`` (the default config), tried again until a router
    listens there: a Zenoh client cannot open without its router, and one not up yet is
    waited for (``diffbot node --wait``, an environment starting its plant). Each attempt
    gives up after ATTEMPT_MS; then ``missed(exc)`` is called, which may raise to stop
    (a deadline, a plant that exited), and the next attempt follows ``pause_s`` later. An
    error that is not about connecting (a bad endpoint) is a BusConfigError at once."""
    conf = make_config("node", endpoint)
    conf.insert_json5("connect/timeout_ms", str(ATTEMPT_MS))
    while True:
        try:
            return zenoh.open(conf)
        except Exception as exc:
            if "connect" not in str(exc).lower():
                raise BusConfigError(f"bad endpoint {endpoint!r}: {exc}") from None
            missed(exc)
        time.sleep(pause_s)


def add_bus_args(parser: argparse.ArgumentParser) -> None:
    """The bus options every diffbot process takes."""
    g = parser.add_argument_group("bus")
    g.add_argument("--endpoint", default=DEFAULT_ENDPOINT,
                   help="Zenoh endpoint the plant listens on and others connect to "
                        f"(default {DEFAULT_ENDPOINT}; e.g. unixsock-stream//tmp/diffbot.sock)")
    g.add_argument("--zenoh-config", metavar="FILE", default=None,
                   help="use this Zenoh JSON5 config file as it is (router, TLS, remote peers)")
    g.add_argument("--namespace", default="",
                   help="prefix for every key, so several simulations share one Zenoh network")


def add_process_args(parser: argparse.ArgumentParser, stats: str = "counters") -> None:
    """The options every diffbot process takes: ``--stats FILE`` (its ``stats`` as JSON at
    exit), ``--log-level`` and the bus options (:func:`add_bus_args`)."""
    parser.add_argument("--stats", metavar="FILE", help=f"write {stats} as JSON at exit")
    add_log_arg(parser)
    add_bus_args(parser)


def add_log_arg(parser: argparse.ArgumentParser) -> None:
    """``--log-level`` (every process; a process without the bus options too: the router)."""
    parser.add_argument("--log-level", default="INFO",
                        help="DEBUG, INFO (default), WARNING or ERROR")


def open_node(args: argparse.Namespace, name: str) -> tuple[Keys, zenoh.Session]:
    """A bus node's keys (``--namespace``) and client session (``--endpoint``,
    ``--zenoh-config``) once its ``name`` is checked. Raises ValueError for a bad
    namespace or name, BusConfigError when the plant cannot be reached: both are the
    caller's one-line error and exit 2."""
    keys = Keys(args.namespace)
    check_name(name, "node name")
    return keys, open_session("node", args.endpoint, args.zenoh_config)


#: a ``sim/info`` unanswered this long is said (``query_info(log=...)``) while it is waited for
INFO_SILENCE_S = 4.0


def query_info(session: zenoh.Session, keys: Keys, timeout_s: float = 15.0,
               log=None) -> dict:
    """Ask the plant for ``sim/info``; retry until it answers or ``timeout_s`` passes. With a
    ``log``, a silence of INFO_SILENCE_S is said once, with its likely causes (the session is
    open, so the link is not one: no plant yet, another namespace, or a router's access
    control that admits this process but not its queries)."""
    start = time.monotonic()
    deadline = start + timeout_s
    said = log is None
    while True:
        for reply in session.get(keys.info, timeout=1.0):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        now = time.monotonic()
        if now > deadline:
            raise TimeoutError(f"no plant answered {keys.info} within {timeout_s:.0f} s")
        if not said and now - start >= INFO_SILENCE_S:
            said = True
            log.warning("no answer to %s for %.0f s: no plant yet, a plant of another "
                        "--namespace, or (through a router with access control) a certificate "
                        "it does not admit: the router's log names who came; still asking",
                        keys.info, now - start)
        time.sleep(0.1)


def close_session(session: zenoh.Session, log) -> None:
    """Close, even when the far end is gone (a close that times out is logged, not raised)."""
    try:
        session.close()
    except Exception as exc:       # zenoh.ZError: "close operation timed out"
        log.warning("closing the Zenoh session: %s", exc)


def undeclare_all(handles) -> None:
    """Undeclare each subscriber, queryable or token of ``handles``, whatever the others do
    (one whose session is gone raises)."""
    for h in handles:
        try:
            h.undeclare()
        except Exception:
            pass


#: A process whose parent (``diffbot run``) was killed gets SIGTERM from the kernel
#: (diffbot/runner/procs.py) and stops cleanly; nobody is left to SIGKILL it if that hangs (a
#: session closing towards a router that went at the same moment), so it ends itself this
#: many seconds later (the launcher gives its recorder as long).
ORPHAN_EXIT_S = 10.0
#: how long after a stop signal the process looks whether its parent is gone (the kernel
#: sends the parent-death signal while it re-parents, so at once it may not show yet)
ORPHAN_CHECK_S = 0.5
_PARENT = os.getppid()
_orphan_ending = False


def _check_orphan_soon() -> None:
    """On a stop signal: in ORPHAN_CHECK_S, if this process's parent is gone, have the
    kernel end it (SIGALRM, default action) ORPHAN_EXIT_S later, whether or not its clean
    stop has finished by then. Signals and a timer only: no lock, no thread, so it is safe
    inside a signal handler and works however the clean stop hangs."""
    if _orphan_ending:
        return
    signal.signal(signal.SIGALRM, _orphan_check)
    signal.setitimer(signal.ITIMER_REAL, ORPHAN_CHECK_S)


def _orphan_check(signum, frame) -> None:
    global _orphan_ending
    _wake_waiters()          # (a Python handler too: the wait it interrupted must not hang)
    if os.getppid() != _PARENT:
        _orphan_ending = True
        signal.signal(signal.SIGALRM, signal.SIG_DFL)
        signal.setitimer(signal.ITIMER_REAL, ORPHAN_EXIT_S)


@atexit.register
def _cancel_orphan_check() -> None:
    """A clean exit within ORPHAN_CHECK_S of the stop signal cancels the pending check:
    the interpreter's finalization (after atexit) puts SIGALRM back to its default action,
    and the check's timer firing then killed a process that was exiting cleanly (exit code
    -14 instead of 0, about one stop in two for the ROS 2 bridge, whose exit takes ~0.5 s).
    An orphan's end timer stays armed."""
    if not _orphan_ending:
        signal.setitimer(signal.ITIMER_REAL, 0)


#: what a stop signal wakes besides its event: the inboxes (:func:`wake_on_stop`)
_WAKE_ON_STOP: weakref.WeakSet = weakref.WeakSet()


def wake_on_stop(waiter) -> None:
    """Have a stop signal call ``waiter.wake()`` after it set the stop event (``waiter``
    kept weakly): an inbox puts a wake-up in its queue, so a main thread waiting on it
    looks at the event at once.

    It must: CPython 3.11's ``SimpleQueue.get(timeout=...)``, interrupted by a signal whose
    handler runs past the timeout's deadline, waits on with no timeout at all, until
    something is put (``_queuemodule.c``: the recomputed timeout comes out negative, which
    means forever). A realtime plant with no node left got its SIGINT there about once in
    forty stops, kept stepping, and was SIGKILLed by the launcher after its grace."""
    _WAKE_ON_STOP.add(waiter)


def _wake_waiters() -> None:
    """Each registered waiter's ``wake()``: what every Python signal handler here calls
    (the stop signals', and the orphan check's SIGALRM half a second later)."""
    for waiter in list(_WAKE_ON_STOP):
        waiter.wake()


def install_stop_signals(stop_event: threading.Event) -> None:
    """SIGINT/SIGTERM stop the process cleanly: ``stop_event`` is set, once, and what
    waits for events is woken (:func:`wake_on_stop`); the session is closed on the way
    out.

    The handler runs on the main thread between two bytecodes of whatever it interrupted,
    so it does no more than it must. A process started with ``die_with_parent`` gets one
    SIGTERM per thread when its parent dies (the kernel's parent-death signal is kept per
    thread, and a Zenoh session runs a dozen), and an ``Event.set`` entered again by the
    next signal while the first holds the event's lock hangs the process for good: later
    signals only look again whether the parent is gone."""
    stopping = []        # (not stop_event.is_set(): its flag is set inside its lock)

    def handler(signum, frame):
        _check_orphan_soon()
        if not stopping:
            stopping.append(signum)
            stop_event.set()
            _wake_waiters()
    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
