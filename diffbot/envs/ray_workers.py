"""The batched env's chunks on a Ray cluster (``AvoidVectorEnv(..., workers=K,
engine="ray")``, the ``cluster`` extra): each of the K chunks a Ray actor holding a
:class:`diffbot.envs.worlds.Worlds`, one CPU each, spread over the cluster's nodes; env i is
the same env, to the bit, wherever its chunk runs. The actors answer the same calls as
a worker process (:class:`diffbot.envs.workers._Worker`): ``send`` then ``result``, so the
chunks step at once.

``address``: a running cluster's (``ray start --head``; with token auth, RAY_AUTH_MODE and
RAY_AUTH_TOKEN in the environment, as ``diffbot sweep --engine ray``); None: a Ray
instance this process already runs, or a private one on this machine, started here and
shut down with the env. The only module of :mod:`diffbot.envs` that imports Ray.
"""
from __future__ import annotations

import importlib.util
import shutil

from .workers import _Episodes


class _Chunk:
    """The actor: a chunk of the batch (:class:`diffbot.envs.worlds.Worlds`)."""

    def __init__(self, n: int, kw: dict) -> None:
        from .worlds import Worlds
        self.worlds = Worlds(n, **kw)
        self.episodes = _Episodes()

    def call(self, method: str, args: tuple):
        value = getattr(self.worlds, method)(*args)
        return self.episodes.pack(value) if method == "step" else value

    def node(self) -> str:
        import ray
        return ray.get_runtime_context().get_node_id()

    def close(self) -> None:
        self.worlds.close()


class Session:
    """This process's connection to Ray (module docstring): :meth:`chunk` makes actors;
    :meth:`close` shuts a private instance down."""

    def __init__(self, address: str | None) -> None:
        if importlib.util.find_spec("ray") is None:
            raise ImportError("engine='ray' needs Ray: the cluster extra "
                              "(pip install -e '.[cluster]'; make setup installs it)")
        from diffbot.runner.ray_engine import init_ray, ray_for
        self.ray = ray = ray_for(address)
        self._tmp: str | None = None
        self.owned = False
        if ray.is_initialized():
            return
        self._tmp = init_ray(ray, address)
        self.owned = True

    def chunk(self, n: int, kw: dict) -> "RayChunk":
        return RayChunk(self.ray, n, kw)

    def close(self) -> None:
        if self.owned and self.ray.is_initialized():
            self.ray.shutdown()
        self.owned = False
        if self._tmp:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None


class RayChunk:
    """A chunk of the batch in a Ray actor: the calls of a worker process
    (:class:`diffbot.envs.workers._Worker`); its first :meth:`result` is its spaces."""

    def __init__(self, ray, n: int, kw: dict) -> None:
        self.ray = ray
        cls = ray.remote(num_cpus=1, scheduling_strategy="SPREAD", max_restarts=0)(_Chunk)
        self.actor = cls.remote(n, kw)
        self._episodes = _Episodes()
        self.send("spaces")

    def send(self, method: str, *args) -> None:
        self._method = method
        self._ref = self.actor.call.remote(method, args)

    def result(self):
        ray = self.ray
        try:
            value = ray.get(self._ref)
        except ray.exceptions.RayTaskError as exc:     # the chunk's own error, as raised
            raise exc.as_instanceof_cause() from None
        except ray.exceptions.RayActorError as exc:
            raise RuntimeError(f"a batch chunk's Ray actor died: {exc}") from None
        return self._episodes.unpack(value) if self._method == "step" else value

    def node(self) -> str:
        """The Ray node the chunk runs on."""
        return self.ray.get(self.actor.node.remote())

    def close(self) -> None:
        try:
            self.ray.get(self.actor.close.remote(), timeout=30)
        except Exception:
            pass
        self.ray.kill(self.actor)
