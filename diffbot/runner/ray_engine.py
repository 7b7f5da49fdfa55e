"""The Ray engine: each run a Ray task on any node of a cluster (or of a Ray instance this
process starts on its own machine), reserving the CPUs its processes use.

The only module of ``diffbot`` that imports Ray (the ``cluster`` extra). A task is
:func:`.task.execute` itself, so a run behaves the same wherever it lands. Ray re-runs a
task whose worker or node died (``max_retries``); :func:`.core.run_all` re-submits a run
that failed. Cancelling a running task raises ``KeyboardInterrupt`` in it, and
``execute`` stops its command by PID before it returns: nothing is left on any node.

:meth:`RayEngine.start_on` starts one command on a given node and gives back a handle
whose result holds its exit code, summary and log tail: the building block for placing a
scenario's processes on nodes.
"""
from __future__ import annotations

import logging
import os
import secrets
import shutil
import socket
import sys
import tempfile
import time

from .task import STOP_GRACE_S, execute, unpack

#: Ray's own retries of a task whose worker process or node died
SYSTEM_RETRIES = 3
#: how long a cancel waits for running tasks to stop their commands (s)
CANCEL_WAIT_S = STOP_GRACE_S + 30.0
#: Ray's own resources (the rest of a node's resources are the user's: ``--resources``)
_RAY_RESOURCES = {"CPU", "GPU", "memory", "object_store_memory", "accelerator_type"}


def _ray():
    already = "ray" in sys.modules
    try:
        import ray
        if already:                            # it read RAY_AUTH_MODE before we set it
            from ray._raylet import Config
            Config.initialize("")
    except ImportError:
        raise SystemExit("diffbot: --engine ray needs Ray: pip install -e '.[cluster]' "
                         "(make setup installs it)") from None
    return ray


def ray_for(address: str | None):
    """The ``ray`` module, imported for ``address`` (a cluster's; None: a private instance
    on this machine, which gets its own token, in the environment only: Ray would otherwise
    write one into ~/.ray/auth_token for this user's later clusters; set before Ray reads
    its configuration, at import)."""
    if not address and not os.environ.get("RAY_AUTH_TOKEN"):
        os.environ.setdefault("RAY_AUTH_MODE", "token")
        os.environ["RAY_AUTH_TOKEN"] = secrets.token_hex(32)
    return _ray()


def init_ray(ray, address: str | None) -> str | None:
    """Connect ``ray`` to the cluster at ``address`` (with token auth, RAY_AUTH_MODE and
    RAY_AUTH_TOKEN come from the environment), or start a private instance on this machine;
    the private instance's temporary folder (to remove after ``ray.shutdown()``), or None."""
    quiet = dict(log_to_driver=False, logging_level=logging.WARNING)
    if address:
        ray.init(address=address, **quiet)
        return None
    tmp = tempfile.mkdtemp(prefix="diffbot-ray-")
    try:
        ray.init(num_cpus=os.cpu_count(), include_dashboard=False,
                 _temp_dir=tmp, _node_ip_address="127.0.0.1", **quiet)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return tmp


def _on_node(argv, out, log_path, timeout_s, driver_host, env=None):
    """The task: :func:`execute` with the Ray node id as ``node``; the output folder comes
    back in the result when this node is not the driver's machine."""
    import ray
    node = ray.get_runtime_context().get_node_id()
    return execute(argv, out, log_path, timeout_s, node=node,
                   ship=socket.gethostname() != driver_host, env=env)


def _started(run, since: float) -> bool:
    """A cancelled task had started its run: the run's log was written after it was
    submitted (Ray reports running and queued tasks alike as cancelled; the log is seen
    where the output folder is shared with the driver's machine)."""
    try:
        return os.path.getmtime(run.log_path) >= since
    except OSError:
        return False


class RayEngine:
    name = "ray"

    def __init__(self, address: str | None = None, max_parallel: int | None = None) -> None:
        ray = self.ray = ray_for(address)
        self._tmp = init_ray(ray, address)
        self.address = address or "local"
        self._task = ray.remote(_on_node)
        self._host = socket.gethostname()
        self.slots = max_parallel              # None: every run queued in Ray at once
        self.max_parallel = max_parallel
        self._refs: dict = {}                  # ref -> run
        self._submitted: dict = {}             # ref -> when (wall clock)

    def describe(self) -> str:
        nodes = [n for n in self.ray.nodes() if n.get("Alive")]
        cpus = self.ray.cluster_resources().get("CPU", 0)
        return (f"Ray engine ({self.address}): {len(nodes)} node(s), {cpus:g} CPU(s)"
                + (f", at most {self.max_parallel} run(s) at a time" if self.max_parallel else ""))

    def nodes(self) -> list[dict]:
        """The cluster's live nodes: id, address, host name, CPUs, and the names of the
        custom resources each was started with (``ray start --resources``)."""
        return [{"id": n["NodeID"], "address": n["NodeManagerAddress"],
                 "hostname": n.get("NodeManagerHostname", ""),
                 "cpus": n["Resources"].get("CPU", 0),
                 "resources": sorted(k for k in n["Resources"] if k not in _RAY_RESOURCES
                                     and not k.startswith("node:"))}
                for n in self.ray.nodes() if n.get("Alive")]

    def local_node_id(self) -> str:
        """The node of this machine that this driver joined."""
        return self.ray.get_runtime_context().get_node_id()

    def call_on(self, node_id: str, fn, *args, timeout_s: float = 120.0):
        """``fn(*args)`` run on the given node (no CPU reserved); its value."""
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy
        ref = self.ray.remote(fn).options(
            num_cpus=0, scheduling_strategy=NodeAffinitySchedulingStrategy(node_id, soft=False)
        ).remote(*args)
        return self.ray.get(ref, timeout=timeout_s)

    def stop(self, handle, force: bool = False) -> None:
        """Ask a task to stop without waiting: a running one gets ``KeyboardInterrupt`` (its
        command is stopped by PID, gracefully) or, with ``force``, its worker is killed
        (the command gets SIGTERM from the kernel: ``die_with_parent``)."""
        self.ray.cancel(handle, force=force)

    def submit(self, run, node_id: str | None = None):
        """Queue ``run`` (its ``cpus`` reserved) on any node, spread over the cluster, or on
        ``node_id`` only."""
        if node_id:
            from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy
            strategy = NodeAffinitySchedulingStrategy(node_id, soft=False)
        else:
            strategy = "SPREAD"
        # more CPUs than the largest node has would queue it forever
        ref = self._task.options(num_cpus=min(run.cpus, self._largest_node()), max_retries=SYSTEM_RETRIES,
                                 scheduling_strategy=strategy, name=run.name).remote(
            run.argv, run.out, run.log_path, run.timeout_s, self._host, run.env or None)
        self._refs[ref] = run
        self._submitted[ref] = time.time()
        return ref

    def _largest_node(self) -> float:
        return max((n["cpus"] for n in self.nodes()), default=1.0) or 1.0

    def start_on(self, node_id: str, run):
        """Start one command (a :class:`.core.Run`) on the given node; ``wait`` gives its
        result (exit code, summary, log tail)."""
        return self.submit(run, node_id)

    def wait(self, handles: list, timeout_s: float) -> list[tuple]:
        ready, _ = self.ray.wait(handles, num_returns=1, timeout=timeout_s)
        if ready:                              # and whatever else is ready by now
            ready, _ = self.ray.wait(handles, num_returns=len(handles), timeout=0)
        return [(h, self._get(h)) for h in ready]

    def _get(self, ref):
        run = self._refs.pop(ref, None)
        try:
            result = self.ray.get(ref)
        except Exception as exc:               # a task the cluster could not run
            return exc
        files = result.pop("files", None)
        if files and run is not None:          # it ran on another machine: its folder
            unpack(files, run.out)
        return result

    def cancel(self, handles: list) -> dict:
        """Cancel queued tasks, interrupt running ones (they stop their commands) and wait
        for them: a handle's result, or None for a run that never started."""
        for h in handles:
            self.ray.cancel(h, force=False)
        ready, _ = self.ray.wait(handles, num_returns=len(handles), timeout=CANCEL_WAIT_S)
        out = {}
        for h in handles:
            run = self._refs.get(h)
            r = self._get(h) if h in ready else None
            out[h] = None if isinstance(r, BaseException) else r
            if out[h] is None and run is not None and _started(run, self._submitted.get(h, 0)):
                out[h] = {"status": "interrupted", "exit_code": None, "wall_time_s": None,
                          "summary": {}, "log_tail": "", "node": "", "host": ""}
        return out

    def close(self) -> None:
        self.ray.shutdown()
        if self._tmp:
            shutil.rmtree(self._tmp, ignore_errors=True)
