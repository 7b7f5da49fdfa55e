"""The batched ``diffbot/Avoid-v0`` as a Stable-Baselines3 ``VecEnv`` (the ``sb3`` extra).

    from diffbot.envs.sb3 import AvoidVecEnv
    from stable_baselines3 import PPO
    venv = AvoidVecEnv(32, normalize_actions=True, overrides=("world.mode=kinematic",))
    venv.seed(0)
    model = PPO("MultiInputPolicy", venv).learn(100_000)

:class:`AvoidVecEnv` drives :class:`diffbot.envs.vector.AvoidVectorEnv` (N worlds in one
process, or ``workers=K``) in its same-step autoreset mode and gives what SB3's own
``DummyVecEnv`` over ``Monitor``-wrapped single envs gives:

- ``step_async``/``step_wait``: observations (a dict of (N, ...) arrays), float32 rewards,
  ``dones`` (terminated or truncated) and one ``info`` dict per env, the env's step info;
- an env whose episode ended is reset at once: its row of the observation is the new
  episode's first, its info holds the last one as ``"terminal_observation"``,
  ``"TimeLimit.truncated"`` (truncated and not terminated: PPO bootstraps from it), and
  ``"episode"``: ``{"r": return, "l": length, "t": seconds since the env was made}``, as
  ``Monitor`` writes it (so ``evaluate_policy`` and the logger's ``ep_rew_mean`` read
  it); its reset info goes to ``reset_infos[i]``;
- ``reset()`` takes no seed: ``seed(s)`` sets env i's next reset seed to ``s + i`` (env i
  is then the single env after ``reset(seed=s + i)``, to the bit), used once.

``spec`` is the single env's spec with the same settings (``gymnasium.make(venv.spec)``
makes one, for evaluation; ``spec.to_json()`` beside a saved model tells a deployed policy
its action scaling). Attributes are the batch's (``get_attr("dt")``, ``get_attr("render_mode")``: one value
per env); ``env_method("render")`` gives each env's frame (``render_mode="rgb_array"``).
Stable-Baselines3 is imported only here.
"""
from __future__ import annotations

import time
from typing import Any, Iterable, Sequence

import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from .results import autoreset_mode
from .vector import AvoidVectorEnv


class BatchVecEnv(VecEnv):
    """What an SB3 VecEnv over one of the project's batched envs (``self.venv``, whose
    envs share their settings) does the same whatever the batch: the episode tallies that
    ``Monitor`` would keep, ``step_async``, attributes set and read for the whole batch,
    ``env_method("render")``. A subclass says what its envs are (``_unit``, ``_what``: the
    error messages' words) and steps them."""

    _unit = "env"
    _what = "the batch"

    def _start(self, num_envs: int, observation_space, action_space) -> None:
        """VecEnv's own set-up (the batch closed if it fails) and the tallies at zero."""
        try:
            super().__init__(num_envs, observation_space, action_space)
        except BaseException:
            self.venv.close()
            raise
        self._returns = np.zeros(self.num_envs)
        self._lengths = np.zeros(self.num_envs, np.int64)
        self._t0 = time.time()
        self._actions: np.ndarray | None = None

    def _restart_tallies(self) -> None:
        self._returns[:] = 0.0
        self._lengths[:] = 0

    def _take_actions(self) -> np.ndarray:
        """The actions ``step_async`` was given, once."""
        if self._actions is None:
            raise RuntimeError("step_wait() without step_async()")
        actions, self._actions = self._actions, None
        return actions

    def _now(self) -> float:
        """Seconds since the env was made, as ``Monitor`` writes an episode's ``"t"``."""
        return round(time.time() - self._t0, 6)

    def _end_episode(self, info: dict, i: int, truncated: bool, now: float) -> None:
        """Env ``i``'s episode ended at this step: ``info`` gets ``"TimeLimit.truncated"``
        (PPO bootstraps from it) and, with ``episode_stats``, ``Monitor``'s ``"episode"``
        (return, length, ``now``); the env's tallies start again."""
        info["TimeLimit.truncated"] = truncated
        if self.episode_stats:
            info["episode"] = {"r": round(float(self._returns[i]), 6),
                               "l": int(self._lengths[i]), "t": now}
        self._returns[i], self._lengths[i] = 0.0, 0

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        """The batch's attribute, once per env asked (the envs share their settings)."""
        value = getattr(self.venv, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        if list(self._get_indices(indices)) != list(range(self.num_envs)):
            raise ValueError(f"the batch's {self._unit}s share their attributes: set one for all")
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs
                   ) -> list[Any]:
        idx = list(self._get_indices(indices))
        if method_name == "render":
            frames = self.get_images()
            return [frames[i] for i in idx]
        raise AttributeError(f"{self._what} has no per-{self._unit} method {method_name!r} "
                             "(only 'render')")

    def env_is_wrapped(self, wrapper_class: type, indices=None) -> list[bool]:
        """``Monitor``: whether the infos carry its ``"episode"`` statistics."""
        wrapped = self.episode_stats and issubclass(Monitor, wrapper_class)
        return [wrapped for _ in self._get_indices(indices)]


class AvoidVecEnv(BatchVecEnv):
    """``num_envs`` Avoid worlds as an SB3 VecEnv (module docstring); ``kwargs`` are the
    batched env's (``normalize_actions``, ``overrides``, ``workers``, ``max_episode_steps``,
    ...; ``autoreset_mode`` is SAME_STEP, SB3's). ``episode_stats=False`` leaves out the
    ``"episode"`` infos (for a ``VecMonitor`` of your own)."""

    _what = "the batched Avoid env"

    def __init__(self, num_envs: int = 8, episode_stats: bool = True, **kwargs) -> None:
        mode = autoreset_mode(kwargs.pop("autoreset_mode", AutoresetMode.SAME_STEP))
        if mode != AutoresetMode.SAME_STEP:
            raise ValueError("SB3 resets an ended episode in the step that ends it: "
                             f"autoreset_mode must be SAME_STEP, got {mode.name}")
        self.venv = AvoidVectorEnv(num_envs, autoreset_mode=AutoresetMode.SAME_STEP, **kwargs)
        self.episode_stats = bool(episode_stats)
        #: the single env's spec with these settings (``gymnasium.make(spec)`` makes one of
        #: the envs; ``spec.to_json()`` keeps it beside a model: SB3Policy reads it)
        self.spec = _spec(kwargs, self.venv.max_episode_steps)
        self._start(self.venv.num_envs, self.venv.single_observation_space,
                    self.venv.single_action_space)

    # ------------------------------------------------------------------ stepping
    def reset(self):
        if any(self._options):
            raise ValueError("the Avoid env takes no reset options (set_options)")
        seeds = None if all(s is None for s in self._seeds) else list(self._seeds)
        obs, infos = self.venv.reset(seed=seeds)
        self.reset_infos = _rows(infos, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        self._restart_tallies()
        return obs

    def step_wait(self):
        obs, rew, term, trunc, infos = self.venv.step(self._take_actions())
        dones = term | trunc
        ended = np.flatnonzero(dones).tolist()
        out = _rows(infos, self.num_envs)
        self._returns += rew
        self._lengths += 1
        if ended:
            final = _rows(infos["final_info"], self.num_envs, ended)
            final_obs = infos["final_obs"]
            now = self._now()
            for i in ended:
                self.reset_infos[i] = out[i]
                info = final[i]
                info["terminal_observation"] = final_obs[i]
                self._end_episode(info, i, bool(trunc[i] and not term[i]), now)
                out[i] = info
        for i in np.flatnonzero(~dones).tolist():
            out[i]["TimeLimit.truncated"] = False
        return obs, rew.astype(np.float32), dones, out

    # ------------------------------------------------------------------ the rest
    def get_images(self) -> Sequence[np.ndarray | None]:
        if self.venv.render_mode != "rgb_array":
            return [None] * self.num_envs
        return list(self.venv.render())


#: the batched env's arguments that are not the single env's
_BATCH_ONLY = ("workers", "threads", "max_episode_steps", "render_mode")


def _spec(kwargs: dict, max_episode_steps: int | None):
    """``diffbot/Avoid-v0``'s registered spec with the env arguments of ``kwargs``."""
    import dataclasses

    import gymnasium
    env_kw = {k: (list(v) if isinstance(v, tuple) else v) for k, v in kwargs.items()
              if k not in _BATCH_ONLY}
    base = gymnasium.spec("diffbot/Avoid-v0")
    return dataclasses.replace(base, kwargs={**base.kwargs, **env_kw},
                               max_episode_steps=max_episode_steps)


def _rows(infos: dict, n: int, which: Iterable[int] | None = None) -> list[dict]:
    """Gymnasium's batched ``infos`` (each key with its ``_key`` mask) as one dict per env
    (rows ``which`` only: the others empty), as the single env gives them (Python scalars,
    array rows)."""
    out: list[dict] = [{} for _ in range(n)]
    rows = list(range(n)) if which is None else list(which)
    for key, col in infos.items():
        if key.startswith("_") or key in ("final_obs", "final_info"):
            continue
        mask = infos.get(f"_{key}")
        if isinstance(col, dict):
            for i, sub in zip(range(n), _rows(col, n, rows)):
                if sub:
                    out[i][key] = sub
            continue
        values = col.tolist() if col.dtype != object and col.ndim == 1 else col
        for i in rows:
            if mask is None or mask[i]:
                out[i][key] = values[i]
    return out
