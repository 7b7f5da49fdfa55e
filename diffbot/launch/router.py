"""``diffbot router``: a Zenoh router for a simulation spread over several machines.

    diffbot router --listen tcp/192.168.1.10:7447            # plain TCP, one interface
    diffbot router --zenoh-config diffbot/launch/configs/router_tls.json5   # TLS + access control

Every diffbot process (plant included) then runs as a client of the router, with
``--zenoh-config`` pointing at its role's shipped config (``diffbot/launch/configs/plant_tls.json5``,
``node_tls.json5``, ...; ``client.json5`` for plain TCP); docs/several-machines.md. It is a Python
Zenoh session in router mode (no zenohd needed): it routes, it declares nothing. Without a
config file, scouting (multicast, gossip) is off, the lease is diffbot's 1 s, and it listens
only where ``--listen`` says (default loopback). ``--listen`` also replaces the listen
endpoints of a config file. Stops on Ctrl-C / SIGTERM; exit 2 on a bad endpoint or config.

It logs every session: opened and closed at INFO with the client's address and the common
name of its certificate (Zenoh's ``Link.auth_identifier``, on TLS links with mutual TLS),
and every session Zenoh refused (a TLS handshake that failed: no client certificate, an
unknown CA, ...) at WARNING with Zenoh's reason. Zenoh reports a refused handshake only in
its own log, without the client's address, so the router reads that log (Zenoh writes it to
stdout; the router takes over its stdout for that) and repeats the refusals in its own.
"""
from __future__ import annotations

import json
import os
import re
import sys
import threading

import zenoh

from bus.cliargs import ArgumentParser
from bus.linkcheck import ConfigFileError, diagnose, load_config
from bus.log import RejectCounter
from bus.process import EXIT_BAD_CONFIG, Exit, Process, process_main
from bus.session import DEFAULT_LEASE_MS, BusConfigError, add_log_arg

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


def router_config(listen: list[str] | None, config_file: str | None) -> zenoh.Config:
    if config_file:
        # the file's listen endpoint (and its ${DIFFBOT_ROUTER}) is replaced by --listen
        env = dict(os.environ, DIFFBOT_ROUTER="--listen") if listen else None
        try:
            conf = load_config(config_file, env)
        except ConfigFileError as exc:
            raise BusConfigError(str(exc)) from None
        conf.insert_json5("mode", '"router"')
    else:
        conf = zenoh.Config()
        for key, value in (("mode", "router"), ("scouting/multicast/enabled", False),
                           ("scouting/gossip/enabled", False), ("scouting/delay", 0),
                           ("connect/endpoints", []),
                           ("transport/link/tx/lease", DEFAULT_LEASE_MS),
                           ("transport/link/tx/keep_alive", 4),
                           ("timestamping/enabled", False)):
            conf.insert_json5(key, json.dumps(value))
        listen = listen or [DEFAULT_LISTEN]
    if listen:
        try:
            conf.insert_json5("listen/endpoints", json.dumps(listen))
        except Exception as exc:
            raise BusConfigError(f"bad --listen {listen}: {exc}") from None
    return conf


def log_sessions(session: zenoh.Session, log) -> object:
    """INFO line per link opened or closed: the client's address, certificate name, ZID."""
    def on_link(event) -> None:
        link = event.link
        what = "opened" if event.kind == zenoh.SampleKind.PUT else "closed"
        cert = f"certificate {link.auth_identifier!r}" if link.auth_identifier else \
            "no client certificate"
        log.info("session %s: %s (%s, zid %s)", what, link.dst, cert, link.zid)
    # history: links opened between the session's start and this declaration are told too
    return session.info.declare_link_events_listener(on_link, history=True)


#: a Zenoh log line: time, level, thread..., target: message (colours stripped)
_ZLOG = re.compile(r"^\S+\s+(?P<level>[A-Z]+)\s.*?(?P<target>zenoh[\w:]*): (?P<msg>.*)$")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


#: Zenoh's words for a refused TLS handshake -> what they mean here (kept after them)
_REFUSAL_HINTS = (
    ("InvalidContentType", "not TLS: a client dialling tcp/ at this tls/ endpoint?"),
    ("peer sent no certificates", "a client without a certificate, under mutual TLS"),
    ("UnknownIssuer", "a client certificate of another CA"),
    ("BadSignature", "a client certificate of another CA"),
    ("alert: UnknownCA", "the client does not know this router's CA: another CA in its "
                         "root_ca_certificate?"),
    ("alert: DecryptError", "the client's certificate or CA is another PKI's"),
    ("alert: BadCertificate", "the client rejected this router's certificate"),
)


def refusal_words(msg: str) -> str:
    """Zenoh's reason for a refused session, with what it means in a diffbot setup."""
    for needle, hint in _REFUSAL_HINTS:
        if needle in msg:
            return f"{msg} ({hint})"
    return msg


def relay_zenoh_log(log) -> None:
    """Route Zenoh's own log (stdout, WARN and up) into ours: a refused TLS handshake is a
    "refused a session" warning (rate limited per reason), anything else a warning."""
    read, write = os.pipe()
    real_stdout = os.dup(1)
    os.dup2(write, 1)
    os.close(write)
    sys.stdout = os.fdopen(real_stdout, "w", buffering=1)
    refused = RejectCounter(log, verb="refused a session:")

    def pump() -> None:
        with os.fdopen(read, "r", errors="replace") as f:
            for line in f:
                m = _ZLOG.match(_ANSI.sub("", line.strip()))
                if not m:
                    continue
                msg = m.group("msg").split(". Hint:")[0]
                if "zenoh_link_tls" in m.group("target") or "zenoh_link_tcp" in m.group("target"):
                    refused.reject(refusal_words(msg))
                else:
                    log.warning("zenoh: %s", msg)
    threading.Thread(target=pump, name="zenoh-log", daemon=True).start()
    zenoh.init_log_from_env_or("warn")


def main(argv: list[str] | None = None) -> int:
    p = ArgumentParser(prog="diffbot router", description=__doc__.split("\n\n")[0])
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help=f"endpoint to listen on, repeatable (default {DEFAULT_LISTEN}; "
                        "e.g. tcp/192.168.1.10:7447, tls/host:7447)")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="a Zenoh JSON5 router config used as it is (TLS, access control)")
    add_log_arg(p)
    return process_main(_run, p, argv, "router")


def _run(proc: Process) -> int:
    args, log = proc.args, proc.log
    relay_zenoh_log(log)
    try:
        conf = router_config(args.listen, args.zenoh_config)
    except BusConfigError as exc:
        raise Exit(EXIT_BAD_CONFIG, exc) from None
    try:
        session = proc.session = zenoh.open(conf)
    except Exception as exc:  # zenoh.ZError: cannot listen there
        raise Exit(EXIT_BAD_CONFIG, f"cannot start the router: {'; '.join(diagnose(conf))} "
                                    f"({exc})") from None
    stop = threading.Event()
    proc.stop_on_signals(stop)
    sessions = log_sessions(session, log)
    try:
        where = json.loads(conf.get_json("listen/endpoints"))
        log.info("router %s listening on %s", session.info.zid(),
                 ", ".join(where) if isinstance(where, list) else where)
        while not stop.wait(0.5):
            pass
        log.info("stopping")
        return 0
    finally:
        try:
            sessions.undeclare()
        except Exception as exc:
            log.warning("closing the session: %s", exc)


if __name__ == "__main__":
    sys.exit(main())
