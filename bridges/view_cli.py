"""``diffbot view``: the live Foxglove view's command line (:class:`bridges.view.View`)."""
from __future__ import annotations

import argparse
import sys


from bus.cliargs import ArgumentParser, nonneg_float, port, positive_float, positive_int
from bus.process import EXIT_BAD_CONFIG, EXIT_PLANT_GONE, Exit, Process, process_main
from bus.session import add_process_args, query_info

from .view import SUBPROTOCOL, View


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="diffbot view",
        description="Serve the simulation live to Foxglove (ws://HOST:PORT, subprotocol "
                    "foxglove.sdk.v1) and take teleop from it. Runs until Ctrl-C.")
    p.add_argument("--port", type=port, default=8765, help="WebSocket port (default 8765; "
                   "0 picks a free one, logged at start)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default 127.0.0.1: this machine only)")
    p.add_argument("--rate", type=nonneg_float, default=30.0, metavar="HZ",
                   help="send each topic's latest message at most this many times per wall "
                        "second (default 30; 0: every message). Recordings keep every one")
    p.add_argument("--image-rate", type=positive_float, default=15.0, metavar="HZ",
                   help="at most this many frames per second per camera (wall clock); "
                        "older frames are dropped (default 15)")
    p.add_argument("--backlog", type=positive_int, default=256, metavar="N",
                   help="messages queued per client before the oldest are dropped (default 256)")
    p.add_argument("--name", default="view", help="node name on the bus (default view)")
    p.add_argument("--info-timeout", type=positive_float, default=15.0, metavar="S",
                   help="wait this long for the plant at the start (default 15)")
    add_process_args(p)
    return p


def main(argv: list[str] | None = None) -> int:
    return process_main(_run, build_parser(), argv)


def _run(proc: Process) -> int:
    args, log = proc.args, proc.log
    try:
        import foxglove  # noqa: F401
    except ImportError:
        raise Exit(EXIT_BAD_CONFIG, "diffbot view needs foxglove-sdk: "
                                    "pip install 'diffbot-cosim[view]'") from None
    keys, session = proc.open_node(args.name)
    view = View(session, keys, log, args.name, args.image_rate, args.rate)
    proc.stats = view.stats
    proc.stop_on_signals(view.stop_event)
    try:
        try:
            view.load_info(query_info(session, keys, args.info_timeout))
        except (TimeoutError, ValueError) as exc:
            raise Exit(EXIT_PLANT_GONE, exc) from None
        try:
            server = view.start_server(args.host, args.port, args.backlog)
        except Exception as exc:             # port in use, bad address
            raise Exit(EXIT_BAD_CONFIG, f"cannot serve on {args.host}:{args.port}: "
                                        f"{exc}") from None
        view.subscribe()
        log.info("serving ws://%s:%d, WebSocket subprotocol %s (Foxglove: Open connection -> "
                 "Foxglove WebSocket; layout bridges/foxglove_layout.json; docs/live-view.md); "
                 "world %s, robots %s", args.host, server.port, SUBPROTOCOL,
                 view.info.get("world"), ", ".join(view.info.get("robots", {})))
        return view.run()
    finally:
        view.close()


if __name__ == "__main__":
    sys.exit(main())
