"""``diffbot router``: a Zenoh router for a simulation spread over several machines.

    diffbot router --listen tcp/192.168.1.10:7447            # plain TCP, one interface
    diffbot router --zenoh-config diffbot/configs/router_tls.json5   # TLS + access control

Every diffbot process (plant included) then runs as a client of the router, with
``--zenoh-config`` pointing at a copy of ``diffbot/configs/client.json5``. It is a Python
Zenoh session in router mode (no zenohd needed): it routes, it declares nothing. Without a
config file, scouting (multicast, gossip) is off, the lease is diffbot's 1 s, and it listens
only where ``--listen`` says (default loopback). ``--listen`` also replaces the listen
endpoints of a config file. Stops on Ctrl-C / SIGTERM; exit 2 on a bad endpoint or config.
"""
from __future__ import annotations

import json
import signal
import sys
import threading

import zenoh

from bus.cliargs import ArgumentParser
from bus.log import setup_logging
from bus.session import DEFAULT_LEASE_MS, BusConfigError, make_config

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


def router_config(listen: list[str] | None, config_file: str | None) -> zenoh.Config:
    if config_file:
        conf = make_config("router", config_file=config_file)
        conf.insert_json5("mode", '"router"')
    else:
        conf = zenoh.Config()
        for key, value in (("mode", "router"), ("scouting/multicast/enabled", False),
                           ("scouting/gossip/enabled", False), ("connect/endpoints", []),
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


def main(argv: list[str] | None = None) -> int:
    p = ArgumentParser(prog="diffbot router", description=__doc__.split("\n\n")[0])
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help=f"endpoint to listen on, repeatable (default {DEFAULT_LISTEN}; "
                        "e.g. tcp/192.168.1.10:7447, tls/host:7447)")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="a Zenoh JSON5 router config used as it is (TLS, access control)")
    p.add_argument("--log-level", default="INFO")
    args = p.parse_args(argv)
    log = setup_logging("router", args.log_level)
    try:
        conf = router_config(args.listen, args.zenoh_config)
        session = zenoh.open(conf)
    except BusConfigError as exc:
        log.error("%s", exc)
        return 2
    except Exception as exc:  # zenoh.ZError: cannot listen there
        log.error("cannot start the router: %s", exc)
        return 2
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
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
            session.close()
        except Exception as exc:
            log.warning("closing the session: %s", exc)


if __name__ == "__main__":
    sys.exit(main())
