"""``diffbot/Avoid-v0``: reach a goal in the living room without touching anything.

One robot starts at a free pose and is given a free goal point 1-3 m away, both drawn
from the episode's seed, which also draws the plant's noise seed. Each step holds the
action ``[v m/s, w rad/s]`` (within the robot's drive limits from the world file; or in
[-1, 1] scaled to them with ``normalize_actions=True``; out of range: clipped, not finite:
ValueError, :mod:`diffbot.envs.actions`) for ``action_repeat`` control ticks: 5 x 20 ms,
so ``dt`` = 0.1 s, the lidar's period, and every observation carries a fresh scan.

Observation (:class:`controllers.learned.AvoidObserver`, the same code the deployed
``diffbot controller policy`` runs): ``scan`` (the lidar's 180 ranges, m, within
:func:`scan_bound`: 9 m in the living room, whose walls close every ray's path well
inside the lidar's 80 m; a deployed controller clips at 80 m, the same readings), ``odom``
(x, y, yaw, v, w dead-reckoned from the wheel encoders, in ``<robot>/odom``: from the
origin, where the episode starts, as the bus's ``<robot>/odom`` topic, REP 105) and
``goal`` (the goal in the robot's own frame ``<robot>/base_link`` by that odometry).
Every bound is finite (odometry and goal clipped at
:data:`controllers.learned.ODOM_HIGH` / ``GOAL_LIMIT_M``, far outside any room).
``info`` (the same keys on reset and step) gives the true ``pose`` and the ``goal`` in
``world``, ``distance``, ``is_success``, ``contact``, sim time ``t`` and ``plant``: the
:class:`diffbot.envs.episode.Episode` that replays the episode on a plant (its noise seed,
start poses, goals, world and overrides).

Reward, judged on ground truth at the end of each step: ``PROGRESS_GAIN`` x the metres
gained toward the goal, minus ``STEP_COST`` each step; ``GOAL_BONUS`` and terminated on
reaching the goal (within ``goal_radius_m``); ``-CONTACT_PENALTY`` and terminated when the
footprint touches a wall, an object or another robot (:mod:`diffbot.envs.geometry`;
checked once per step: the robot moves at most 5 cm in one); truncated after 300 steps
(30 s; the registration's ``max_episode_steps``, Gymnasium's TimeLimit).

:class:`AvoidTask` holds this for any number of robots; the swarm's PettingZoo
environment (:mod:`diffbot.envs.swarm_v0`) is the same task with one agent per robot.
"""
from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from bus import codec
from controllers.learned import GOAL_LIMIT_M, ODOM_HIGH, AvoidObserver
from plant.world import load_world

from .actions import Drive, check_repeat
from .episode import Episode, next_seed
from .geometry import Footprints
from .kinbatch import ArrayTicks
from .transport import Bus, InProc

PROGRESS_GAIN = 1.0
STEP_COST = 0.005
GOAL_BONUS = 1.0
CONTACT_PENALTY = 1.0
#: what the environment reads of each robot
INPUTS = ["joint_states", "ground_truth", "scan"]
_READ = frozenset(INPUTS)
TRANSPORTS = ("inproc", "bus")


def step_reward(before: float, d: float, success: bool, contact: bool) -> float:
    """A robot's reward for a step (module docstring), from its distances to the goal
    before and after it."""
    r = PROGRESS_GAIN * (before - d) - STEP_COST
    if success:
        r += GOAL_BONUS
    if contact:
        r -= CONTACT_PENALTY
    return r


def step_rewards(before: np.ndarray, d: np.ndarray, success: np.ndarray,
                 contact: np.ndarray) -> np.ndarray:
    """:meth:`AvoidTask.end_step`'s rewards of many robots at once (a batch's), from their
    distances to the goal before and after the step: the same numbers."""
    r = PROGRESS_GAIN * (before - d) - STEP_COST
    r = np.where(success, r + GOAL_BONUS, r)
    return np.where(contact, r - CONTACT_PENALTY, r)


def scan_bound(spec, robot: str) -> float:
    """The largest scan reading the env reports (the scan's Box bound; the observer clips
    at it): the lidar's max range or, in a room whose walls stand above the lidar (every ray
    ends on a wall), the room's diagonal plus 1 m for noise, rounded up to whole metres,
    if that is less (the living room: 9 m, where the lidar's range is 80 m)."""
    lid = spec.robot(robot).sensors.lidar
    bound = float(lid.max_range_m)
    if spec.wall_height_m > lid.mount_z_m:
        bound = min(bound, float(math.ceil(math.hypot(*spec.floor_size_m) + 1.0)))
    return bound


def make_transport(spec, world: str, inputs: dict, transport: str, endpoint, disabled,
                   overrides):
    if transport == "inproc":
        if endpoint is not None:
            raise ValueError("endpoint= is for transport='bus'")
        return InProc(spec, disabled, inputs)
    if transport == "bus":
        return Bus(spec, world, inputs, disabled, overrides, endpoint)
    raise ValueError(f"transport must be one of {', '.join(TRANSPORTS)}, got {transport!r}")


def true_pose(msg) -> tuple[float, float, float]:
    return codec.pose_2d(msg)


class AvoidTask:
    """Robots each reaching their own goal without contact (module docstring)."""

    def __init__(self, world: str = "living_room", transport: str = "inproc",
                 endpoint: str | None = None, action_repeat: int = 5,
                 max_steps: int | None = None, goal_radius_m: float = 0.3,
                 overrides: tuple[str, ...] = (), normalize_actions: bool = False) -> None:
        self.action_repeat = check_repeat(action_repeat)
        if max_steps is not None and int(max_steps) < 1:
            raise ValueError("max_steps must be >= 1")
        self.world, self.overrides = world, tuple(overrides)
        #: a generated world's text (the swarm's), which its episodes carry: "" for a file
        self.world_toml = ""
        self.spec = load_world(world, list(overrides))
        self.robots = [r.name for r in self.spec.robots]
        for r in self.spec.robots:
            if r.sensors.lidar is None:
                raise ValueError(f"{world}: robot {r.name} has no lidar (Avoid needs one)")
        self.max_steps = None if max_steps is None else int(max_steps)
        self.goal_radius = float(goal_radius_m)
        self.dt = self.action_repeat * self.spec.control_tick_s
        self.geo = Footprints(self.spec)
        self.observers = {r.name: AvoidObserver(r.drive.wheel_radius_m, r.drive.wheel_separation_m,
                                                r.sensors.lidar.num_rays,
                                                scan_bound(self.spec, r.name))
                          for r in self.spec.robots}
        self.drives = {r.name: Drive(r.drive.max_linear_mps, r.drive.max_angular_radps,
                                     normalize_actions) for r in self.spec.robots}
        self.scans: dict = {}
        self._ticks_left = 1
        self._view = None
        self.transport = None
        self.transport = make_transport(self.spec, world, {r: INPUTS for r in self.robots},
                                        transport, endpoint, ("camera",), tuple(overrides))
        if isinstance(self.transport, InProc):
            # the truth is read at a step's last tick only (it has no noise: not building
            # it at the others changes nothing)
            self.transport.wanted = {r: self._wants for r in self.robots}

    def _wants(self, topic: str) -> bool:
        return topic in _READ and (topic != "ground_truth" or self._ticks_left <= 1)

    # ---------------------------------------------------------------- spaces
    def observation_space(self, robot: str) -> spaces.Dict:
        lid = self.spec.robot(robot).sensors.lidar
        return spaces.Dict({
            "scan": spaces.Box(0.0, np.float32(scan_bound(self.spec, robot)), (lid.num_rays,),
                               np.float32),
            "odom": spaces.Box(-ODOM_HIGH, ODOM_HIGH, (5,), np.float32),
            "goal": spaces.Box(-GOAL_LIMIT_M, GOAL_LIMIT_M, (2,), np.float32)})

    def action_space(self, robot: str) -> spaces.Box:
        return self.drives[robot].space

    # ---------------------------------------------------------------- episode
    def reset(self, rng: np.random.Generator) -> tuple[dict, dict]:
        seed = int(rng.integers(0, 2**31))
        poses, goals, starts = {}, {}, []
        for name in self.robots:
            p = self.geo.free_point(rng, 0.3, avoid=starts, away_m=1.0)
            starts.append(p)
            poses[name] = (float(p[0]), float(p[1]), float(rng.uniform(-math.pi, math.pi)))
        for name, p in zip(self.robots, starts):
            g = self.geo.free_point(rng, 0.2, avoid=[q for q in starts if q is not p],
                                    away_m=0.8, within=(p, 1.0, 3.0))
            goals[name] = (float(g[0]), float(g[1]))
        self.goals = goals
        self.steps = 0
        self.active = set(self.robots)
        for name in self.robots:
            self.observers[name].reset(poses[name], goals[name])
        self._ticks_left = 1
        self.episode = Episode(seed, poses, goals, self.world, self.overrides, ("camera",),
                               world_toml=self.world_toml)
        self.transport.reset(seed, poses, self._observe)
        return self._obs(), {r: self._info(r, False) for r in self.robots}

    def _observe(self, t_ns: int, msgs: dict, judge: bool = True) -> bool:
        """Every tick: the odometry integrates the encoders. At the step's last tick (and
        at reset): the ground truth and (``judge``; else the caller, :meth:`centres`, as a
        batch does for all its worlds at once) the contacts. Whether it was the last."""
        self.t_ns = t_ns
        for name in self.robots:
            self.observers[name].feed(t_ns, msgs[name])
            self.scans[name] = msgs[name].get("scan")
        self._ticks_left -= 1
        if self._ticks_left > 0:
            return False
        self.truth = {name: true_pose(msgs[name]["ground_truth"]) for name in self.robots}
        if judge:
            self.touched = self.geo.contacts(self.centres())
        return True

    def centres(self) -> dict[str, np.ndarray]:
        """The robots' footprint centres by the ground truth of the step's end."""
        return {n: Footprints.centre(*p) for n, p in self.truth.items()}

    def _distance(self, robot: str) -> float:
        x, y, _ = self.truth[robot]
        g = self.goals[robot]
        return math.hypot(g[0] - x, g[1] - y)

    def _obs(self) -> dict:
        return {r: self.observers[r].observation() for r in self.robots}

    def _info(self, robot: str, success: bool, distance: float | None = None,
              t_ns: int | None = None) -> dict:
        return {"pose": np.array(self.truth[robot]), "goal": np.array(self.goals[robot]),
                "distance": self._distance(robot) if distance is None else distance,
                "is_success": success, "contact": robot in self.touched,
                "t": (self.t_ns if t_ns is None else t_ns) * 1e-9, "plant": self.episode}

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        cmds = self.begin_step(actions)
        self.transport.advance(self.action_repeat, lambda t, m: cmds, self._observe,
                               constant=True)
        return self.end_step()

    def begin_step(self, actions: dict) -> dict:
        """A step's first half: the robots' commands ({robot: (v, w)}) for its ticks. The
        ticks (``transport.advance(action_repeat, ..., self._observe)``, or a batch's,
        :mod:`diffbot.envs.vector`) come between this and :meth:`end_step`."""
        cmds = {name: self.drives[name].command(actions[name], name)
                for name in self.robots if name in self.active}
        self._before = {r: self._distance(r) for r in self.active}
        self._ticks_left = self.action_repeat
        return cmds

    def end_step(self) -> tuple[dict, dict, dict, dict, dict]:
        """A step's second half, after its ticks: observations, rewards, flags, infos (a
        batch of kinematic worlds makes them for all its worlds at once:
        :meth:`diffbot.envs.worlds.Worlds._step_arrays`)."""
        before = self._before
        self.steps += 1
        obs = self._obs()
        rew, term, trunc, info = {}, {}, {}, {}
        for name in list(self.active):
            rew[name], term[name], trunc[name], info[name] = self.end_robot(
                name, before[name], self.t_ns)
        return obs, rew, term, trunc, info

    def end_robot(self, name: str, before: float, t_ns: int) -> tuple[float, bool, bool, dict]:
        """An active robot's reward, flags and info at the end of step ``steps`` (its truth
        and contact as the step left them; ``before``: its distance to the goal before the
        step); it leaves the episode if that ended it (a batch: ``step_rewards``)."""
        d = self._distance(name)
        success = d < self.goal_radius
        contact = name in self.touched
        term = success or contact
        trunc = not term and self.max_steps is not None and self.steps >= self.max_steps
        if term or trunc:
            self.active.discard(name)
        return (step_reward(before, d, success, contact), term, trunc,
                self._info(name, success and not contact, d, t_ns))

    def render(self) -> np.ndarray:
        """The top-down view (:mod:`diffbot.envs.render`): room, robots, goals, rays."""
        if self._view is None:
            from .render import TopDown
            self._view = TopDown(self.spec)
        return self._view.frame(self.truth, self.goals, self.scans, self.goal_radius)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()
            self.transport = None


class AvoidEnv(gym.Env):
    """``diffbot/Avoid-v0`` (module docstring). ``transport="inproc"`` (default) runs the
    plant's code in this process; ``"bus"`` starts a lockstep plant and joins it over
    Zenoh (or joins the one at ``endpoint``): same seed and actions, same numbers.

    In-process (a world without a physics process), a step's ticks are the batched env's
    fast path for one world (:class:`diffbot.envs.kinbatch.ArrayTicks`: its ticks in the
    plant's C kernels, the numbers the messages give, to the bit), and the task's objects
    (its observer, odometry, world) are brought up to date when something reads them: a
    render, a reset, :attr:`task`."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, transport: str = "inproc", endpoint: str | None = None,
                 world: str = "living_room", action_repeat: int = 5,
                 goal_radius_m: float = 0.3, overrides: tuple[str, ...] = (),
                 normalize_actions: bool = False, render_mode: str | None = None) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array' (a top-down view; "
                             f"diffbot view watches a bus env live), got {render_mode!r}")
        self.render_mode = render_mode
        self._task = AvoidTask(world, transport, endpoint, action_repeat, None, goal_radius_m,
                               overrides, normalize_actions)
        if len(self._task.robots) != 1:
            self._task.close()
            raise ValueError(f"{world} has {len(self._task.robots)} robots; Avoid-v0 drives one "
                             "(diffbot.envs.swarm_v0 drives many)")
        self.robot = self._task.robots[0]
        self.transport_name = transport
        self.observation_space = self._task.observation_space(self.robot)
        self.action_space = self._task.action_space(self.robot)
        self.dt = self._task.dt
        self.metadata = {**type(self).metadata, "render_fps": round(1.0 / self.dt)}
        self._arrays = None           # the fast path (kinbatch.ArrayTicks), when it applies
        self._fresh = np.ones(1, bool)          # its state to be read from the objects

    @property
    def task(self) -> AvoidTask:
        """The task, its objects up to date (the fast path writes them back when asked)."""
        if self._arrays is not None:
            self._arrays.flush()
        return self._task

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is None:                # the next seed of the stream (episode.next_seed)
            if self._np_random is None:
                super().reset()
            seed = next_seed(self.np_random)
        super().reset(seed=seed)
        task = self.task
        obs, info = task.reset(self.np_random)
        task.episode.seed = seed
        self._fresh[0] = True
        self._arrays = self._fast_path()
        return obs[self.robot], info[self.robot]

    def _fast_path(self) -> ArrayTicks | None:
        task = self._task
        if not ArrayTicks.eligible([task]):
            return None
        if self._arrays is None:
            return ArrayTicks(1)
        return self._arrays

    def step(self, action):
        task = self._task
        if not task.active:
            raise RuntimeError("the episode is over: call reset()")
        if self._arrays is not None:
            return self._step_arrays(task, action)
        obs, rew, term, trunc, info = task.step({self.robot: action})
        r = self.robot
        return obs[r], float(rew[r]), bool(term[r]), bool(trunc[r]), info[r]

    def _step_arrays(self, task: AvoidTask, action):
        """:meth:`AvoidTask.step` of the one robot through the fast path: the same numbers
        (``tests/envs/test_envs_identity.py``: a plant over the bus beside it, every noise on)."""
        robot = self.robot
        cmd = task.drives[robot].command(action, robot)
        fresh = self._fresh
        before = task._distance(robot)          # (its truth: the reset's or the last step's)
        made = self._arrays.advance([task], np.array([cmd]), _ROW0, fresh)
        fresh[0] = False
        truth = made.truth[0].tolist()
        task.truth = {robot: tuple(truth)}
        # geo.contacts of the one robot: its footprint against the walls and objects
        contact = bool(task.geo.touching(Footprints.centre(*truth)[None])[0])
        task.touched = {robot} if contact else set()
        task.steps += 1
        r, term, trunc, info = task.end_robot(robot, before, int(made.t_ns[0]))
        return {k: v[0] for k, v in made.obs.items()}, r, term, trunc, info

    def render(self):
        """``rgb_array``: the top-down view of the room (H x W x 3 uint8), robot, goal and
        lidar rays where the ground truth has them (:mod:`diffbot.envs.render`)."""
        if self.render_mode == "rgb_array":
            return self.task.render()
        return None

    def close(self) -> None:
        self._arrays = None
        self._task.close()


_ROW0 = np.zeros(1, np.int64)
