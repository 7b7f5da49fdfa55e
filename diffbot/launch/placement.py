"""``diffbot run SCENARIO --place NAME=HOST,...``: a scenario's processes on a Ray cluster.

A :class:`Placement` is data: which process runs on which Ray node, the bus they share, and
the engine that starts each placed process's command there. :func:`place` makes one from the
command line; :class:`diffbot.launch.scenario_run.ScenarioRun` takes it (``placement=``) and starts,
watches and stops every process the same way, local or placed (this module imports nothing
of the run's).

Each placed process is a task of the runner's Ray engine (:mod:`diffbot.runner.ray_engine`)
pinned to its node: :func:`diffbot.runner.task.execute` starts the command there and stops
it by PID whatever happens. Processes not placed (and the launcher's own observer, which
the analysis reads) run on this machine. The bus:

- **plain TCP** (default): the plant listens on ``tcp/<its node's address>:<a free port of
  that node>``, every other process connects to it (the plant's node's address must be
  reachable from every node: a trusted network).
- ``--tls``: every process is a client of your TLS router (docs/several-machines.md), with
  the shipped config of its role (``diffbot/launch/configs/<role>_tls.json5``); the ``DIFFBOT_*``
  variables of this environment are passed to every process.
- ``--zenoh-config FILE``: every process uses that file, as in a local run.

A placed process writes its log and statistics into ``OUT/placed/NAME/`` on its node; the
folder comes back with the task's result when the node is another machine, and its files
are moved to ``OUT/logs/`` as in a local run, so ``summary.json``, the plots and the
results are those of a local run. Stopping (the end of the run, Ctrl-C, a failure) cancels
the tasks: each stops its command, and the launcher waits for every task to report.

``HOST`` is a Ray node's id (or a unique prefix of it, at least 6 characters), its IP
address, its host name, or the name of a custom resource it was started with
(``ray start --resources '{"robot": 1}'``); it must name exactly one live node. ``NAME`` is
a process name of the scenario (``diffbot run --place`` lists them when one is wrong),
``plant``, or a prefix of names up to ``_`` (``square_path`` places
``square_path_robot1``); ``*`` places every process not named otherwise.
"""
from __future__ import annotations

import os
import shutil
import signal
import socket
import time
from dataclasses import dataclass

from bus.session import make_config

from ..runner import procs
from .. import runner

CONFIGS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "configs")
#: how long the observer keeps trying to reach a plant that a Ray worker is still starting
OBSERVER_JOIN_S = 60.0
#: how long a stopped run waits for its tasks to report, then their workers are killed
TASKS_STOP_S = 45.0
EVERY = "*"


class PlacementError(ValueError):
    """A bad --place: an unknown process or host (exit 2)."""


def add_args(p) -> None:
    g = p.add_argument_group("across machines (a Ray cluster; docs/several-machines.md)")
    g.add_argument("--place", action="append", default=[], metavar="NAME=HOST[,...]",
                   help="start process NAME (plant, a scenario process, a prefix such as "
                        "square_path, or * for the rest) on the Ray node HOST (node id, IP, "
                        "host name or custom resource); repeatable; the rest run here")
    g.add_argument("--address", default=None, metavar="auto|HOST:PORT",
                   help="the Ray cluster of --place (default auto: the one this machine "
                        "belongs to; RAY_AUTH_MODE/RAY_AUTH_TOKEN from the environment)")
    g.add_argument("--tls", action="store_true",
                   help="with --place: every process connects to your TLS router with the "
                        "shipped config of its role (diffbot/launch/configs/*_tls.json5; "
                        "DIFFBOT_CERTS, DIFFBOT_ROUTER, DIFFBOT_PORT from the environment)")


def wanted(args) -> bool:
    """The command line asks for a placed run (or misuses its options: checked later)."""
    return bool(args.place or args.tls or args.address)


def parse_place(values: list[str]) -> dict[str, str]:
    """``["plant=a,square_path=b", "*=c"]`` -> {name: host}, in order."""
    out: dict[str, str] = {}
    for value in values:
        for item in filter(None, (v.strip() for v in value.split(","))):
            name, eq, host = item.partition("=")
            if not eq or not name.strip() or not host.strip():
                raise PlacementError(f"--place {item!r}: expected NAME=HOST")
            if name.strip() in out:
                raise PlacementError(f"--place: {name.strip()!r} placed twice")
            out[name.strip()] = host.strip()
    return out


def assign(place: dict[str, str], names: list[str]) -> dict[str, str]:
    """Which process goes where: process name -> host, for the placed ones. A name's own
    key wins over a prefix key, a prefix over ``*``; a key that matches nothing is an
    error naming the processes there are."""
    out: dict[str, str] = {}
    for key in place:
        if key != EVERY and not any(n == key or n.startswith(key + "_") for n in names):
            raise PlacementError(f"--place {key}=...: no such process in this run "
                                 f"(processes: {', '.join(names)})")
    for n in names:
        prefixes = [k for k in place if k != EVERY and n.startswith(k + "_")]
        if n in place:
            out[n] = place[n]
        elif prefixes:
            out[n] = place[max(prefixes, key=len)]
        elif EVERY in place:
            out[n] = place[EVERY]
    return out


def resolve(host: str, nodes: list[dict]) -> dict:
    """The one live node that ``host`` names (see the module docstring)."""
    def names(n: dict) -> bool:
        return (n["id"] == host or (len(host) >= 6 and n["id"].startswith(host))
                or host in (n["address"], n["hostname"]) or host in n["resources"])
    found = [n for n in nodes if names(n)]
    listing = "; ".join(f"{n['id'][:12]} {n['address']} {n['hostname']}"
                        + (f" resources {','.join(n['resources'])}" if n["resources"] else "")
                        for n in nodes)
    if not found:
        raise PlacementError(f"--place: no live Ray node is {host!r} (nodes: {listing})")
    if len(found) > 1:
        raise PlacementError(f"--place: {host!r} names {len(found)} Ray nodes; use a node id "
                             f"or a custom resource (nodes: {listing})")
    return found[0]


def free_port(address: str) -> int:
    """A TCP port free on this node's ``address`` now (runs on the plant's node)."""
    with socket.socket() as s:
        s.bind((address, 0))
        return s.getsockname()[1]


def tls_config(role: str) -> str:
    """The shipped TLS config of a process of this role (plant, recorder, view, bridge,
    node): diffbot/launch/configs/<role>_tls.json5."""
    return os.path.join(CONFIGS, f"{role}_tls.json5")


def set_option(argv: list[str], option: str, value: str) -> None:
    """Replace the value of ``option`` in a command line."""
    argv[argv.index(option) + 1] = value


class RemoteChild(procs.Child):
    """A scenario process run as a Ray task on a chosen node; the launcher sees it as the
    local process it replaces (poll, signal, exit code, log tail, ``required``,
    ``ends_run``). It has no process on this machine (``running()`` is False), so a local
    SIGKILL never concerns it: :meth:`Placement.wait_tasks` waits for its task."""

    def __init__(self, child: procs.Child, engine, node: dict, out: str,
                 timeout_s: float) -> None:
        folder = os.path.join(out, "placed", child.name)
        super().__init__(child.name, list(child.argv),
                         log_path=os.path.join(folder, f"{child.name}.log"))
        self.required, self.ends_run = child.required, child.ends_run
        self.final_log = child.log_path
        self.engine, self.node, self.folder = engine, node, folder
        set_option(self.argv, "--stats", os.path.join(folder, f"{child.name}.json"))
        self.task = runner.Run(child.name, self.argv, folder, self.log_path, cpus=0.0,
                         timeout_s=timeout_s)
        self.ref = None
        self.error = ""
        self.log_tail = ""
        self._asked = 0

    @property
    def started(self) -> bool:
        return self.ref is not None

    def start(self, env: dict | None = None) -> "RemoteChild":
        env = env if env is not None else os.environ
        self.task.env = {k: v for k, v in env.items() if k.startswith("DIFFBOT_")}
        self.task.env["PYTHONUNBUFFERED"] = "1"
        self.ref = self.engine.start_on(self.node["id"], self.task)
        self.t_start = time.monotonic()
        return self

    def running(self) -> bool:
        return False

    def poll(self) -> int | None:
        if self.ref is not None and self.exit_code is None:
            for _, result in self.engine.wait([self.ref], timeout_s=0):
                self._take(result)
        return self.exit_code

    def _take(self, result) -> None:
        if isinstance(result, BaseException):     # never ran, or its worker or node died
            self.error = f"{type(result).__name__}: {str(result).splitlines()[0][:300]}"
            code = -(self._asked or signal.SIGKILL)
        else:
            code = result["exit_code"] if result["exit_code"] is not None else 1
            self.log_tail = result.get("log_tail", "")
        self._collect()
        self._ended(code)

    def _collect(self) -> None:
        """Its log and statistics into OUT/logs/, where a local run has them."""
        for src, dst in ((self.log_path, self.final_log),
                         (os.path.join(self.folder, f"{self.name}.json"),
                          os.path.join(os.path.dirname(self.final_log), f"{self.name}.json"))):
            if os.path.exists(src):
                os.replace(src, dst)
        shutil.rmtree(self.folder, ignore_errors=True)
        self.log_path = self.final_log
        if self.error:
            with open(self.log_path, "a") as f:
                f.write(f"diffbot run: {self.name} on Ray node {self.node['id']} "
                        f"({self.node['address']}): {self.error}\n")

    def signal(self, sig: int) -> None:
        """SIGKILL: its worker is killed; any other signal: the task stops its command
        (SIGINT, a grace period, SIGKILL to its tree), once."""
        if self.ref is None or self.poll() is not None:
            return
        if sig == signal.SIGKILL or not self._asked:
            self._asked = sig
            self.engine.stop(self.ref, force=sig == signal.SIGKILL)

    def stopped(self) -> bool:
        return False

    def tail(self, n: int = procs.TAIL_LINES) -> str:
        return procs.tail(self.log_path, n) or self.log_tail

    def describe_exit(self) -> str:
        where = f" on Ray node {self.node['id'][:12]} ({self.node['address']})"
        if self.error:
            return f"was lost{where}: {self.error}"
        return super().describe_exit() + where


@dataclass
class Placement:
    """Where a run's processes go: the data :class:`diffbot.launch.scenario_run.ScenarioRun` takes.

    ``where`` maps a process name to the Ray node it runs on (the others run here);
    ``engine`` starts, watches and stops the placed commands (the runner's Ray engine);
    ``endpoint``/``zenoh_config`` are the bus every process uses and the launcher's own
    config; with ``tls`` every process gets the shipped TLS config of its role."""
    where: dict
    engine: object = None
    endpoint: str = ""
    zenoh_config: str | None = None
    tls: bool = False
    #: how long the launcher keeps trying to reach a plant a Ray worker is still starting
    observer_join_s: float = OBSERVER_JOIN_S

    def child(self, c: procs.Child, out: str, timeout_s: float) -> procs.Child:
        """``c`` as it runs: a :class:`RemoteChild` on its node if placed, else itself."""
        if c.name not in self.where:
            return c
        return RemoteChild(c, self.engine, self.where[c.name], out, timeout_s)

    def wait_tasks(self, children: list, out: str) -> None:
        """After the local stop (a remote process is asked first, as a local one is sent
        SIGINT): wait for every task to report; a task that does not is killed."""
        remote = [c for c in children if isinstance(c, RemoteChild) and c.started]
        if not procs.wait_all(remote, TASKS_STOP_S):
            for c in remote:
                c.signal(signal.SIGKILL)
            procs.wait_all(remote, 10.0)
        for c in remote:
            if c.poll() is None:
                c.error = "its task did not stop"
                c._collect()
                c._ended(-signal.SIGKILL)
        try:
            os.rmdir(os.path.join(out, "placed"))   # empty once all came back
        except OSError:
            pass

    def close(self) -> None:
        if self.engine is not None:
            self.engine.close()


def place(args, names: list[str], endpoint: str, zenoh_config: str | None) -> Placement:
    """The :class:`Placement` the command line asks for, over a run's processes ``names``
    and its bus (``endpoint``, ``zenoh_config``: the user's, if any): Ray joined, hosts
    resolved, the bus chosen. Raises :class:`PlacementError` (or BusConfigError) for bad
    input."""
    if args.tls and args.zenoh_config:
        raise PlacementError("--tls and --zenoh-config: choose one (--tls uses the shipped "
                             "configs, --zenoh-config one file for every process)")
    if args.tls and args.endpoint:
        raise PlacementError("--tls: the processes connect to your router "
                             "(DIFFBOT_ROUTER), not to --endpoint")
    asked = parse_place(args.place)
    if not asked:
        raise PlacementError("--address/--tls are for a placed run: add --place NAME=HOST")
    hosts = assign(asked, names)
    observer_config = zenoh_config
    if args.tls:
        observer_config = tls_config("recorder")
        make_config("observer", "", observer_config)   # unset DIFFBOT_* -> an error now
    from ..runner.ray_engine import RayEngine
    address = args.address or "auto"
    try:
        engine = RayEngine(address)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise PlacementError(f"cannot join the Ray cluster at {address}: {exc}") from None
    try:
        nodes = engine.nodes()
        where = {name: resolve(host, nodes) for name, host in hosts.items()}
        if not (args.tls or zenoh_config or endpoint):
            plant = where.get("plant") or next(n for n in nodes
                                               if n["id"] == engine.local_node_id())
            port = engine.call_on(plant["id"], free_port, plant["address"])
            endpoint = f"tcp/{plant['address']}:{port}"
        return Placement(where, engine, endpoint, observer_config, args.tls)
    except BaseException:
        engine.close()
        raise


def where_ran(run) -> dict[str, dict]:
    """Each process's Ray node (id, address, host name) for ``summary.json``; ``{}`` for
    the ones that ran on this machine."""
    return {c.name: ({k: c.node[k] for k in ("id", "address", "hostname")}
                     if isinstance(c, RemoteChild) else {}) for c in run.children}


def describe(run) -> str:
    """Where each process runs, for the launcher's first line."""
    here = [c.name for c in run.children if not isinstance(c, RemoteChild)]
    parts = [f"{c.name} on {c.node['address']} ({c.node['id'][:8]})"
             for c in run.children if isinstance(c, RemoteChild)]
    if here:
        parts.append(f"{', '.join(here)} here")
    return f"bus {run.endpoint or run.zenoh_config}; " + "; ".join(parts)
