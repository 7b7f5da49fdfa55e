"""``diffbot fmu-node FMU --robot R``: any co-simulation FMU as a bus node, from the command
line (:class:`fmus.fmu_node.FmuNode`; docs/fmu.md)."""
from __future__ import annotations

import argparse
import math
import sys

from bus.cliargs import name_arg
from bus.log import setup_logging
from bus.node import node_arg_parser, run_node_args
from bus.process import EXIT_BAD_CONFIG

from .fmu_node import open_node
from .mapping import FmuNodeError


def _pairs(what: str):
    """argparse type: NAME=VALUE."""
    def parse(text: str) -> tuple[str, str]:
        name, eq, value = text.partition("=")
        if not eq or not name or not value:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return name, value
    parse.__name__ = what
    return parse


def _step_arg(text: str) -> str | float:
    if text in ("fmu", "tick"):
        return text
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not v > 0 or not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected fmu, tick or a step in s > 0, got {text!r}")
    return v


def main(argv: list[str] | None = None) -> int:
    p = node_arg_parser("Run a co-simulation FMU (FMI 2 or 3) as a node on the bus: with no "
                        "mapping, every output on fmu/<instance>/<variable> and every input "
                        "read from there (docs/fmu.md).")
    p.prog = "diffbot fmu-node"
    p.add_argument("fmu", metavar="FMU",
                   help="FMU file, or a name built into fmus/build (odometry, odometry_fmi3)")
    p.add_argument("--mapping", metavar="FILE",
                   help="TOML mapping of robot messages to FMU variables (default "
                        "fmus/<modelIdentifier>/mapping.toml if there is one, else none)")
    p.add_argument("--instance", type=name_arg("FMU instance name"),
                   help="the <instance> of its fmu/<instance>/... keys (default: the model "
                        "identifier)")
    p.add_argument("--connect", action="append", type=_pairs("VAR=fmu/INSTANCE/VARIABLE"),
                   default=[], metavar="VAR=KEY",
                   help="feed input VAR from another FMU node's key (awaited every tick in "
                        "lockstep); repeatable")
    p.add_argument("--param", action="append", type=_pairs("NAME=VALUE"), default=[],
                   metavar="NAME=VALUE",
                   help="set a parameter (checked against its min / max); repeatable")
    p.add_argument("--step-size", type=_step_arg, default=None, metavar="fmu|tick|S",
                   help="the FMU's communication step: its DefaultExperiment stepSize "
                        "(fmu, the default unless the mapping file says otherwise; one doStep "
                        "per tick if it declares none), one doStep per control tick (tick), "
                        "or S seconds")
    p.add_argument("--from-zero", action="store_true",
                   help="start the model only at bus time 0 (a plant started with --expect "
                        "this node, or after a reset) instead of at the current bus time")
    args = p.parse_args(argv)
    try:
        _check_unique(args.connect, "--connect")
        _check_unique(args.param, "--param")
        node = open_node(args.fmu, args.mapping, instance_name=args.name or "fmu",
                         instance=args.instance,
                         connect=dict(args.connect), start_values=dict(args.param),
                         step=args.step_size, from_zero=args.from_zero)
    except FmuNodeError as exc:
        setup_logging(args.name or "fmu-node", args.log_level).error("%s", exc)
        return EXIT_BAD_CONFIG
    name = args.name or (f"{node.name}_{args.robot}" if node.builders else node.instance)
    node.log = node.rejects.log = node.fmu.log = setup_logging(name, args.log_level)
    node.node_name = name
    node.log.info("%s: FMI %s, instance %s, %s; inputs %s; outputs %s", node.fmu.name,
                  node.fmu.md.fmiVersion, node.instance,
                  f"own step {node.step_size:g} s" if node.step_size else
                  "one doStep per control tick",
                  ", ".join(f"{f.var.name} <- {f.topic}" for f in node.feeds) or "none",
                  ", ".join(node.generic_topics + [o.topic for o in node.builders]) or "none")
    return run_node_args(node, args, name)     # (it closes the node and adds its stats)


def _check_unique(pairs: list[tuple[str, str]], option: str) -> None:
    seen = set()
    for name, _ in pairs:
        if name in seen:
            raise FmuNodeError(f"{option}: {name!r} is given twice")
        seen.add(name)


if __name__ == "__main__":
    sys.exit(main())
