"""A learned Avoid policy as a controller: the observation the Gymnasium environment
``diffbot/Avoid-v0`` gives, built here from the robot's bus messages, and a small numpy
MLP that maps it to a twist.

The observation (:class:`AvoidObserver`) is the one place that turns messages into what
a policy sees, used by the environment (``diffbot.envs``) in training and by
``diffbot controller policy`` in deployment, so a policy trained in-process sees the
same numbers on the bus:

* ``scan``: the lidar's ranges (m; no return -> the range maximum);
* ``odom``: x, y (m), yaw (rad, wrapped), v (m/s), w (rad/s) dead-reckoned from the wheel
  encoders (:class:`controllers.odometry.Odometry`) in the robot's odometry frame
  ``<robot>/odom``: as the odometry node's ``<robot>/odom`` topic (REP 105), it starts at
  the origin, where the robot starts; ``world -> <robot>/odom`` is the start pose;
* ``goal``: the goal in the robot's own frame ``<robot>/base_link`` (m): the world goal
  taken into ``<robot>/odom`` through the start pose, then relative to that odometry.

A policy file (``.npz``, numpy only, no pickles) holds an MLP over :func:`features`
(``W0 b0 W1 b1 ...``, one pair per layer), the action limits and the action repeat it was
trained with.
"""
from __future__ import annotations

import argparse
import math

import numpy as np

from bus.cliargs import positive_float
from bus.node import Twist, node_arg_parser, run_node_args

from .odometry import Odometry

#: lidar sectors the policy features keep (the minimum range of each)
SCAN_BINS = 12
#: ranges beyond this (m) look the same to the policy
SCAN_CLIP_M = 2.5
GOAL_CLIP_M = 5.0
#: the observation's finite bounds (far outside any room or drive limit; values beyond
#: are clipped to them): odom x, y (m), yaw (rad), v (m/s), w (rad/s); goal x, y (m)
ODOM_HIGH = np.array([100.0, 100.0, math.pi, 10.0, 20.0], np.float32)
GOAL_LIMIT_M = np.float32(100.0)


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def in_frame(pose, x: float, y: float) -> tuple[float, float]:
    """The point (x, y) (m) in the frame whose origin and heading are ``pose`` = (x0, y0,
    yaw0), both given in the same parent frame."""
    x0, y0, th0 = (float(v) for v in pose[:3])
    c, s = math.cos(th0), math.sin(th0)
    dx, dy = x - x0, y - y0
    return dx * c + dy * s, -dx * s + dy * c


def as_action(a) -> np.ndarray:
    """An action [v, w] as the environments take it: through float32, their action
    space's type (so a policy run by the controller commands the very same numbers)."""
    return np.asarray(a, dtype=np.float32).astype(np.float64).reshape(-1)


class AvoidObserver:
    """One robot's Avoid observation, fed every control tick with its latest messages."""

    def __init__(self, wheel_radius_m: float, wheel_separation_m: float, num_rays: int,
                 max_range_m: float) -> None:
        self.r, self.d = wheel_radius_m, wheel_separation_m
        self.num_rays = num_rays
        self.max_range = float(max_range_m)
        self.reset((0.0, 0.0, 0.0), (0.0, 0.0))

    def reset(self, pose0, goal) -> None:
        """``pose0``: the start pose in ``world`` (``world -> <robot>/odom``); ``goal``:
        the goal (x, y) in ``world``."""
        self.odom = Odometry(self.r, self.d, (0.0, 0.0, 0.0))
        self.goal = in_frame(pose0, float(goal[0]), float(goal[1]))
        self.scan = np.full(self.num_rays, self.max_range, dtype=np.float32)
        self._scan_msg = None

    def feed(self, t_ns: int, msgs) -> None:
        """One tick's messages (topic -> latest message): joint_states every tick, scan
        whenever one is there."""
        js = msgs.get("joint_states")
        if js is not None:
            self.odom.update(float(js.position[0]), float(js.position[1]), t_ns * 1e-9)
        scan = msgs.get("scan")
        if scan is not None and scan is not self._scan_msg:     # a new scan
            self._scan_msg = scan
            r = np.asarray(scan.ranges, dtype=np.float32)
            self.scan = np.where(np.isfinite(r), np.clip(r, 0.0, self.max_range),
                                 np.float32(self.max_range)).astype(np.float32)

    def goal_in_robot_frame(self) -> tuple[float, float]:
        o = self.odom
        return in_frame((o.x, o.y, o.theta), *self.goal)

    def observation(self) -> dict:
        o = self.odom
        odom = np.array([o.x, o.y, wrap(o.theta), o.v, o.w], dtype=np.float32)
        goal = np.array(self.goal_in_robot_frame(), dtype=np.float32)
        return {"scan": self.scan.copy(),
                "odom": np.clip(odom, -ODOM_HIGH, ODOM_HIGH),
                "goal": np.clip(goal, -GOAL_LIMIT_M, GOAL_LIMIT_M)}


def features(obs: dict, fov_rad: float = math.pi) -> np.ndarray:
    """What the MLP reads: the lidar binned into SCAN_BINS sectors (min range, clipped and
    scaled to 0..1), the goal's distance (scaled) and bearing (cos, sin), and v, w."""
    scan = np.minimum(np.asarray(obs["scan"], dtype=np.float64), SCAN_CLIP_M) / SCAN_CLIP_M
    n = len(scan)
    edges = np.linspace(0, n, SCAN_BINS + 1).round().astype(int)
    bins = np.array([scan[a:b].min() if b > a else 1.0 for a, b in zip(edges[:-1], edges[1:])])
    gx, gy = (float(v) for v in obs["goal"])
    dist = math.hypot(gx, gy)
    bearing = math.atan2(gy, gx)
    v, w = float(obs["odom"][3]), float(obs["odom"][4])
    return np.concatenate([bins, [min(dist, GOAL_CLIP_M) / GOAL_CLIP_M, math.cos(bearing),
                                  math.sin(bearing), v, w / 2.0]])


N_FEATURES = SCAN_BINS + 5


class MLPPolicy:
    """tanh MLP, features -> (v, w) scaled to the action limits: ``layers`` is a list of
    ``(W, b)``, tanh after each; one layer is a linear policy (squashed)."""

    def __init__(self, layers, v_max: float, w_max: float, action_repeat: int,
                 v_min: float | None = None) -> None:
        self.layers = [(np.asarray(W, float), np.asarray(b, float)) for W, b in layers]
        shapes = [W.shape for W, _ in self.layers]
        n_in = N_FEATURES
        for (W, b) in self.layers:
            if W.ndim != 2 or W.shape[0] != n_in or b.shape != (W.shape[1],):
                raise ValueError(f"policy layers {shapes} do not chain from {N_FEATURES} "
                                 "features")
            n_in = W.shape[1]
        if n_in != 2:
            raise ValueError(f"policy layers {shapes} do not end in 2 outputs (v, w)")
        self.v_max, self.w_max = float(v_max), float(w_max)
        self.v_min = -self.v_max if v_min is None else float(v_min)
        self.action_repeat = int(action_repeat)

    @staticmethod
    def shapes(hidden=()) -> list[tuple[int, int]]:
        sizes = [N_FEATURES, *hidden, 2]
        return list(zip(sizes[:-1], sizes[1:]))

    @classmethod
    def size(cls, hidden=()) -> int:
        """Number of parameters of a policy with these hidden layer sizes."""
        return sum(a * b + b for a, b in cls.shapes(hidden))

    @classmethod
    def from_vector(cls, theta: np.ndarray, hidden=(), **kw) -> "MLPPolicy":
        theta = np.asarray(theta, float)
        if theta.shape != (cls.size(hidden),):
            raise ValueError(f"{theta.shape[0]} parameters for hidden layers {tuple(hidden)}, "
                             f"which take {cls.size(hidden)}")
        i, layers = 0, []
        for a, b in cls.shapes(hidden):
            W = theta[i:i + a * b].reshape(a, b)
            i += a * b
            layers.append((W, theta[i:i + b]))
            i += b
        return cls(layers, **kw)

    def act(self, obs: dict) -> tuple[float, float]:
        h = features(obs)
        for W, b in self.layers:
            h = np.tanh(h @ W + b)
        v = self.v_min + (h[0] + 1.0) / 2.0 * (self.v_max - self.v_min)
        return float(v), float(h[1] * self.w_max)

    def save(self, path: str) -> None:
        arrays = {}
        for k, (W, b) in enumerate(self.layers):
            arrays[f"W{k}"], arrays[f"b{k}"] = W, b
        np.savez(path, **arrays, limits=np.array([self.v_min, self.v_max, self.w_max]),
                 action_repeat=np.array(self.action_repeat))

    @classmethod
    def load(cls, path: str) -> "MLPPolicy":
        try:
            with np.load(path, allow_pickle=False) as z:
                v_min, v_max, w_max = (float(x) for x in z["limits"])
                n = sum(1 for k in z.files if k.startswith("W"))
                layers = [(z[f"W{k}"], z[f"b{k}"]) for k in range(n)]
                return cls(layers, v_max, w_max, int(z["action_repeat"]), v_min=v_min)
        except (OSError, KeyError, ValueError, TypeError) as exc:
            raise ValueError(f"{path}: not a policy file ({exc})") from None


class PolicyController:
    """Drives a robot to ``goal`` with a trained :class:`MLPPolicy`, deciding every
    ``action_repeat`` ticks as in training; done when odometry puts it within
    ``goal_radius_m`` of the goal."""
    name = "policy"
    inputs = ["joint_states", "scan"]

    def __init__(self, policy: MLPPolicy, goal: tuple[float, float],
                 goal_radius_m: float = 0.3) -> None:
        self.policy = policy
        self.goal = goal
        self.goal_radius = goal_radius_m
        self.observer: AvoidObserver | None = None
        self.action = (0.0, 0.0)
        self.ticks = 0
        self.done = False

    def configure(self, info: dict, robot: str) -> None:
        """From the plant's sim/info: the start pose, the wheels and the lidar."""
        r = info["robots"][robot]
        lidar = (r.get("sensors") or {}).get("lidar")
        if not lidar:
            raise ValueError(f"{robot} has no lidar: the policy needs its scan")
        self.observer = AvoidObserver(r["wheel_radius_m"], r["wheel_separation_m"],
                                      int(lidar["num_rays"]), float(lidar["max_range_m"]))
        self.observer.reset(r["pose"], self.goal)

    def step(self, obs):
        self.observer.feed(obs.t_ns, obs.msgs)
        if self.ticks % max(1, self.policy.action_repeat) == 0:
            o = self.observer.observation()
            if math.hypot(*o["goal"]) < self.goal_radius:
                self.done = True
                return Twist(0.0, 0.0)
            self.action = tuple(float(v) for v in as_action(self.policy.act(o)))
        self.ticks += 1
        return Twist(*self.action)


def _goal(value: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in value.split(","))
    except ValueError:
        raise ValueError(f"--goal takes X,Y in metres, got {value!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f"--goal must be finite, got {value!r}")
    return x, y


def main(argv=None) -> int:
    p = node_arg_parser("Drive to a goal with a policy trained on diffbot/Avoid-v0 "
                        "(examples/learn).")
    p.add_argument("--file", required=True, metavar="POLICY.npz", help="the trained policy")
    p.add_argument("--goal", required=True, metavar="X,Y", type=lambda v: _checked(_goal, v),
                   help="the goal in world coordinates, m")
    p.add_argument("--goal-radius", type=positive_float, default=0.3, metavar="M",
                   help="done within this distance of the goal (default 0.3 m)")
    args = p.parse_args(argv)
    try:
        policy = MLPPolicy.load(args.file)
    except ValueError as exc:
        p.exit(2, f"diffbot controller policy: {exc}\n")
    return run_node_args(PolicyController(policy, args.goal, args.goal_radius), args,
                         args.name or f"policy_{args.robot}")


def _checked(fn, value):
    try:
        return fn(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
