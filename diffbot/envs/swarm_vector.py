"""``diffbot.envs.swarm_v0.vector_env``: W swarm worlds of N robots stepped together.

    from diffbot.envs import swarm_v0
    venv = swarm_v0.vector_env(num_worlds=8, n_robots=4, mode="kinematic", robot="avoid")
    obs, infos = venv.reset(seed=0)              # obs["scan"]: (8, 4, 180)
    obs, rew, term, trunc, infos = venv.step(venv.action_space.sample())   # (8, 4, 2)

PettingZoo has no vector API; multi-agent RL libraries take a batch of worlds as arrays
shaped (worlds, agents, ...), and that is what :class:`SwarmVectorEnv` gives: every
observation key a (W, N, ...) array, rewards (W, N) float64, terminations and truncations
(W, N) bool, actions (W, N, 2), robots in ``possible_agents`` order. World i is a
:class:`diffbot.envs.swarm.SwarmEnv` made with the same arguments: after
``reset(seed=s)`` it plays what ``swarm_v0.parallel_env(...)`` plays after
``reset(seed=s + i)`` (a list of seeds: one each), step for step, to the bit. Each step
drives every world's robots as arrays (:mod:`diffbot.envs.swarm_arrays`: every robot of
every world a row of the same kernel calls, no message built; where a world is not made for
that, or with ``arrays=False``, tick by tick through each robot's messages,
:func:`diffbot.envs.worlds.advance_together`, the path the arrays are tested against).

A robot's episode ends alone (its goal, a contact; the others go on, it stands still): the
step that ends it has its flag set, later steps of that episode give its row zeros
(observation, reward, flags, info: "black death", as SuperSuit's wrappers pad ended
agents) and ``infos["active"][i, j]`` False. ``active`` says which rows of the
observation and of ``infos`` hold this call's values: the robots live at the step's start,
or every robot of a world (re)set by the call. ``infos``: the single env's per-robot keys
(``pose`` (W, N, 3), ``goal``, ``distance``, ``is_success``, ``contact``, ``t``), each
(W, N, ...), and ``plant``: each world's :class:`diffbot.envs.episode.Episode` (W,).

A world's episode ends when all its robots' have; it is then reset, as Gymnasium's vector
envs do (``autoreset_mode=``, ``metadata["autoreset_mode"]``):

- ``NEXT_STEP`` (the default): the next ``step`` ignores the world's actions, resets it and
  returns its new episode's first observation, rewards 0 and the flags False;
- ``SAME_STEP``: the step that ends it resets it at once: the new episode's first
  observation and reset infos take its rows, its last observation goes to
  ``infos["final_obs"][i]`` (a dict of (N, ...) arrays) and that step's infos to
  ``infos["final_info"]`` (the same layout, rows of the ended worlds), each with its
  ``_final_obs``/``_final_info`` mask (W,);
- ``DISABLED``: a step of an ended world is refused (RuntimeError); reset it with
  ``reset(options={"reset_mask": m})`` (W,) bool, which resets the worlds where ``m`` is
  True in any mode (the others keep their rows of the observation, ``active`` False).

An autoreset, like the single env's ``reset()`` without a seed, draws the next episode's
seed from the world's own stream (``infos["plant"][i].seed``). ``state()`` is each world's
global state (W, 5 N); ``render()`` a frame per world; :meth:`SwarmVectorEnv.sync` brings
the worlds' objects (``envs``) up to date with the arrays. In-process worlds only.
"""
from __future__ import annotations

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode

from .actions import check_action
from .results import autoreset_mode as autoreset_mode_of
from .results import reset_mask
from .swarm import SwarmEnv
from .swarm_arrays import SwarmArrays
from .worlds import advance_together


def _tile(box: spaces.Box, lead: tuple[int, ...]) -> spaces.Box:
    """``box`` repeated over the leading dimensions ``lead``."""
    return spaces.Box(np.broadcast_to(box.low, lead + box.shape).copy(),
                      np.broadcast_to(box.high, lead + box.shape).copy(), dtype=box.dtype)


class _Rows:
    """One call's results laid out (W, N, ...) (module docstring), filled world by world."""

    def __init__(self, w: int, n: int, obs_space: spaces.Dict) -> None:
        self.w, self.n = w, n
        self.obs = {k: np.zeros((w, n, *sp.shape), sp.dtype) for k, sp in obs_space.items()}
        self.rew = np.zeros((w, n))
        self.term = np.zeros((w, n), bool)
        self.trunc = np.zeros((w, n), bool)
        self.infos: dict = {"active": np.zeros((w, n), bool)}

    def _column(self, key: str, value) -> np.ndarray:
        col = self.infos.get(key)
        if col is None:
            if key == "plant":                           # one episode a world
                col = np.full(self.w, None, dtype=object)
            else:
                v = np.asarray(value)
                col = np.zeros((self.w, self.n, *v.shape), v.dtype)
            self.infos[key] = col
        return col

    def put_block(self, at: list[int], live: np.ndarray, obs: dict, rew: np.ndarray,
                  term: np.ndarray, trunc: np.ndarray, infos: dict) -> None:
        """:meth:`put` of worlds ``at`` at once, from (K, N, ...) arrays
        (:meth:`diffbot.envs.swarm_arrays.SwarmArrays.step`'s), rows ``live`` (K, N) only."""
        rows = np.asarray(at, np.int64)
        for k, a in self.obs.items():
            a[rows] = np.where(live.reshape(live.shape + (1,) * (a.ndim - 2)), obs[k], 0)
        self.rew[rows] = np.where(live, rew, 0.0)
        self.term[rows], self.trunc[rows] = term & live, trunc & live
        self.infos["active"][rows] = live
        for key, value in infos.items():
            if key == "plant":
                col = self._column(key, None)
                for i, ep in zip(rows.tolist(), value):
                    col[i] = ep
                continue
            value = np.asarray(value)
            col = self._column(key, value[0, 0])
            col[rows] = np.where(live.reshape(live.shape + (1,) * (value.ndim - 2)), value, 0)

    def put(self, i: int, agents: list[str], obs: dict, infos: dict, rew: dict | None = None,
            term: dict | None = None, trunc: dict | None = None) -> None:
        """World ``i``'s values from the single env's dicts (agent -> value), rows of the
        agents in ``obs`` (the others keep theirs: zeros, in a fresh instance; a world put
        again is a reset, every agent in it); ``rew``/``term``/``trunc`` None: a reset
        (0, False)."""
        for j, agent in enumerate(agents):
            if agent not in obs:
                continue
            for k, a in self.obs.items():
                a[i, j] = obs[agent][k]
            if rew is not None:
                self.rew[i, j], self.term[i, j], self.trunc[i, j] = \
                    rew[agent], term[agent], trunc[agent]
            else:
                self.rew[i, j], self.term[i, j], self.trunc[i, j] = 0.0, False, False
            self.infos["active"][i, j] = True
            for key, value in infos[agent].items():
                col = self._column(key, value)
                if key == "plant":
                    col[i] = value
                else:
                    col[i, j] = value


class SwarmVectorEnv:
    """``num_worlds`` swarm worlds (module docstring); ``kwargs`` are
    :func:`diffbot.envs.swarm_v0.parallel_env`'s, the same for every world."""

    metadata = {"name": "diffbot_swarm_v0_vector", "render_modes": ["rgb_array"],
                "render_fps": 10, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_worlds: int = 1,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 arrays: bool = True, **kwargs) -> None:
        mode = autoreset_mode_of(autoreset_mode)
        if kwargs.get("transport", "inproc") != "inproc" or kwargs.get("endpoint"):
            raise ValueError("the swarm's vector env batches in-process worlds "
                             "(transport='inproc'); over the bus, one parallel_env per plant")
        if int(num_worlds) < 1:
            raise ValueError(f"num_worlds must be >= 1, got {num_worlds!r}")
        self.num_worlds = int(num_worlds)
        self.envs: list[SwarmEnv] = []
        try:
            for _ in range(self.num_worlds):
                self.envs.append(SwarmEnv(**kwargs))
        except BaseException:
            self.close()
            raise
        first = self.envs[0]
        self.possible_agents = list(first.possible_agents)
        self.n_robots = len(self.possible_agents)
        self.render_mode = first.render_mode
        self.dt = first.dt
        self.autoreset_mode = mode
        self.metadata = {**type(self).metadata, "render_fps": first.metadata["render_fps"],
                         "autoreset_mode": mode}
        # every robot of a swarm world is alike: one agent's spaces are all agents'
        self.single_observation_space = first.observation_space(self.possible_agents[0])
        self.single_action_space = first.action_space(self.possible_agents[0])
        lead = (self.num_worlds, self.n_robots)
        self.observation_space = spaces.Dict(
            {k: _tile(sp, lead) for k, sp in self.single_observation_space.items()})
        self.action_space = _tile(self.single_action_space, lead)
        self.state_space = _tile(first.state_space, (self.num_worlds,))
        self._needs_reset = np.zeros(self.num_worlds, bool)
        self._obs: dict | None = None
        #: the worlds stepped as arrays where they can be (None: every world through its
        #: messages, the path the arrays are tested against)
        self.arrays = SwarmArrays(self.num_worlds, self.possible_agents) if arrays else None

    @property
    def num_agents(self) -> int:
        """Agents in the batch: worlds x robots."""
        return self.num_worlds * self.n_robots

    # ---------------------------------------------------------------- episodes
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Every world, or (``options={"reset_mask": m}``) the worlds where ``m`` is True.
        ``seed``: None (each world draws its own), an int (world i: ``seed + i``) or a list
        of one per world (a masked reset reads the masked worlds' only)."""
        w = self.num_worlds
        if seed is None:
            seeds = [None] * w
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(w)]
        else:
            seeds = list(seed)
            if len(seeds) != w:
                raise ValueError(f"{len(seeds)} seeds for {w} worlds")
        mask = reset_mask(options, w)
        if mask is not None and self._obs is None:
            raise RuntimeError("reset_mask resets some worlds of a running batch: call "
                               "reset() without it first")
        rows = _Rows(w, self.n_robots, self.single_observation_space)
        if mask is not None:                   # the other worlds keep their observation
            for k, a in rows.obs.items():
                a[:] = self._obs[k]
        for i in range(w) if mask is None else np.flatnonzero(mask).tolist():
            obs, infos = self._reset_world(i, seeds[i])
            rows.put(i, self.possible_agents, obs, infos)
            self._needs_reset[i] = False
        self._obs = rows.obs
        return rows.obs, rows.infos

    def step(self, actions):
        """Every world's step (module docstring): ``actions`` (W, N, 2), robot j of world i
        its row ``[i, j]`` (ignored for a robot out of its episode, or a world being reset)."""
        if self._obs is None:
            raise RuntimeError("call reset() before step()")
        w, n = self.num_worlds, self.n_robots
        if self.autoreset_mode == AutoresetMode.DISABLED and self._needs_reset.any():
            ended = ", ".join(map(str, np.flatnonzero(self._needs_reset).tolist()))
            raise RuntimeError(
                f"the episodes of world {ended} are over and autoreset_mode is DISABLED: "
                "reset them first, reset(options={'reset_mask': ...})")
        actions = np.asarray(actions)
        if actions.shape != (w, n, 2):
            raise ValueError(f"actions must have shape ({w}, {n}, 2), got {actions.shape}")
        stepping = np.flatnonzero(~self._needs_reset).tolist()
        live = {i: list(self.envs[i].agents) for i in stepping}
        index = {a: j for j, a in enumerate(self.possible_agents)}
        used = np.zeros((w, n), bool)          # the live robots' rows
        for i, agents in live.items():
            if len(agents) == n:
                used[i] = True
            else:
                used[i, [index[a] for a in agents]] = True
        self._check(actions, used)             # before any world moves
        rows = _Rows(w, n, self.single_observation_space)
        for i in np.flatnonzero(self._needs_reset).tolist():           # NEXT_STEP
            obs, infos = self._reset_world(i, None)
            rows.put(i, self.possible_agents, obs, infos)
        tasks = [self.envs[i].task for i in stepping]
        if tasks and self.arrays is not None and self.arrays.fits(tasks, stepping):
            self._step_arrays(stepping, tasks, actions, used[stepping], rows)
        elif tasks:
            if self.arrays is not None:
                self.arrays.flush(stepping)
            cmds = [t.begin_step({a: actions[i, index[a]] for a in live[i]})
                    for i, t in zip(stepping, tasks)]
            advance_together(tasks, cmds)
            for i, task in zip(stepping, tasks):
                obs, rew, term, trunc, infos = self.envs[i].ended(live[i], *task.end_step())
                rows.put(i, self.possible_agents, obs, infos, rew, term, trunc)
        done = np.array([not e.agents for e in self.envs]) & ~self._needs_reset
        if self.autoreset_mode == AutoresetMode.SAME_STEP:
            self._reset_ended(rows, done)
            self._needs_reset[:] = False
        else:
            self._needs_reset = done
        self._obs = rows.obs
        return rows.obs, rows.rew, rows.term, rows.trunc, rows.infos

    def _step_arrays(self, stepping: list[int], tasks: list, actions: np.ndarray,
                     mask: np.ndarray, rows: _Rows) -> None:
        """The step of worlds ``stepping`` as arrays (:mod:`diffbot.envs.swarm_arrays`),
        ``mask`` (K, N) their live robots: the numbers the message path gives."""
        obs, rew, term, trunc, infos = self.arrays.step(tasks, stepping, actions[stepping],
                                                        mask)
        rows.put_block(stepping, mask, obs, rew, term, trunc, infos)
        going = mask & ~(term | trunc)
        changed = (going != mask).any(1)
        for j in np.flatnonzero(changed).tolist():      # (the others' agents stay)
            self.envs[stepping[j]].agents = [a for a, on in zip(self.possible_agents,
                                                                going[j].tolist()) if on]

    def _reset_world(self, i: int, seed: int | None) -> tuple[dict, dict]:
        """World ``i``'s reset (its objects brought up to date with the arrays first)."""
        if self.arrays is not None:
            self.arrays.forget(i)
        return self.envs[i].reset(seed=seed)

    def _check(self, actions: np.ndarray, used: np.ndarray) -> None:
        """The actions of the live robots, ``used`` (W, N) (check_action's ValueError, naming
        the first bad one, before any world steps)."""
        try:
            ok = bool(np.isfinite(actions[used].astype(np.float32)).all())
        except (TypeError, ValueError):
            ok = False
        if not ok:
            for i, j in zip(*np.nonzero(used)):
                check_action(actions[i, j], f"world {i}, agent {self.possible_agents[j]}")

    def _reset_ended(self, rows: _Rows, done: np.ndarray) -> None:
        """Same-step autoreset (module docstring) of the worlds ``done`` (W,)."""
        final_obs = np.full(self.num_worlds, None, dtype=object)
        final_info = {k: v.copy() for k, v in rows.infos.items()}
        for i in np.flatnonzero(done).tolist():
            final_obs[i] = {k: a[i].copy() for k, a in rows.obs.items()}
            rew, term, trunc = rows.rew[i].copy(), rows.term[i].copy(), rows.trunc[i].copy()
            obs, infos = self._reset_world(i, None)
            rows.put(i, self.possible_agents, obs, infos)
            rows.rew[i], rows.term[i], rows.trunc[i] = rew, term, trunc
        rows.infos.update({"final_obs": final_obs, "_final_obs": done.copy(),
                           "final_info": final_info, "_final_info": done.copy()})

    # ---------------------------------------------------------------- the rest
    def state(self) -> np.ndarray:
        """Each world's global state (:meth:`SwarmEnv.state`), (W, 5 N)."""
        self.sync()
        return np.stack([e.state() for e in self.envs])

    def render(self):
        """``rgb_array``: each world's top-down frame (a tuple, world by world)."""
        if self.render_mode != "rgb_array":
            return None
        self.sync()
        return tuple(e.render() for e in self.envs)

    def sync(self) -> list[SwarmEnv]:
        """The worlds, their objects brought up to date with the array steps' state (written
        back only when asked: :meth:`SwarmArrays.flush`)."""
        if self.arrays is not None:
            self.arrays.flush()
        return self.envs

    def close(self) -> None:
        self.arrays = None
        for e in self.envs:
            e.close()
        self.envs = []

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
