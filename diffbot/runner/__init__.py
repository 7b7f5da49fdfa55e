"""The runner of many runs, used by ``diffbot sweep``, ``diffbot figures`` and ``diffbot bench``.

A run is a plain function of its parameters that returns its result
(:func:`.task.execute`: one command into its own folder; status, exit code, wall time,
summary, log tail, node). Where it runs is the engine's business:

- :class:`.local.LocalEngine` (``--engine local``, the default): a pool on this machine
  sized to its CPUs; nothing to start.
- :class:`.ray_engine.RayEngine` (``--engine ray``): Ray tasks on a cluster
  (``--address auto`` or ``HOST:PORT``) or on a Ray instance started for the purpose; each
  run reserves the CPUs its processes use. Ray is imported only there.

:func:`.core.run_all` drives either: longest first, retries, Ctrl-C cancels queued runs and
stops running ones.
"""
from __future__ import annotations

from bus.jsonio import read_json

from .core import Progress, Run, indent, run_all, run_until_done
from .local import LocalEngine, default_parallel
from .task import execute

__all__ = ["Progress", "Run", "run_all", "run_until_done", "indent", "execute", "read_json", "make_engine",
           "LocalEngine", "default_parallel", "add_engine_args", "ENGINES"]

ENGINES = ("local", "ray")


def make_engine(name: str, address: str | None = None, max_parallel: int | None = None,
                cpus_per_run: float = 1.0):
    """An engine by name (``local`` or ``ray``); ``address`` is Ray's (``auto``,
    ``HOST:PORT``; none: a private Ray instance on this machine)."""
    if name == "ray":
        from .ray_engine import RayEngine
        return RayEngine(address, max_parallel)
    if address:
        raise ValueError("--address is for --engine ray")
    return LocalEngine(max_parallel or default_parallel(cpus_per_run))


def add_engine_args(p, default_parallel_help: str | None) -> None:
    """``--engine``, ``--address`` and (unless ``default_parallel_help`` is None: the
    command has its own option for it) ``--max-parallel`` on a command's parser."""
    from bus.cliargs import positive_int
    p.add_argument("--engine", choices=ENGINES, default="local",
                   help="where runs go: local (a process pool on this machine, the default) "
                        "or ray (a Ray cluster, see --address; needs the [cluster] extra)")
    p.add_argument("--address", default=None, metavar="auto|HOST:PORT",
                   help="the Ray cluster to use with --engine ray (auto: the one this "
                        "machine belongs to); default: start a Ray instance on this machine")
    if default_parallel_help is None:
        return
    p.add_argument("--max-parallel", type=positive_int, default=None, metavar="N",
                   help=f"runs at the same time ({default_parallel_help})")
