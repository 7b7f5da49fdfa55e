"""``diffbot/Follow-v0``: the study's follow task, with the follower learned.

The leader drives the follow scenario's wander loop (:class:`controllers.wander.Wander`,
run by the environment at every control tick on its ground truth, on both transports);
the learner drives the follower and sees its camera: ``image`` (120 x 160 x 3, uint8), and
with ``detection=True`` also ``ball`` = [seen, u / width, v / height, radius / width] from
the ball follower's own detector (:func:`controllers.ball_follower.detect_ball`).

The camera runs at 25 Hz, every 2nd 20 ms tick, so a step holds the action ``[v, w]``
for ``action_repeat`` = 2 ticks: ``dt`` = 0.04 s, a fresh image every step (the action as
Avoid's: in the drive's units or ``normalize_actions=True``, :mod:`diffbot.envs.actions`).

Reward, on ground truth (the follow analysis's distance, camera to ball): 1 while it is
inside the 0.60-0.70 m band, else minus the distance outside it (at most 1); the episode
is terminated when the follower's footprint touches anything (the leader too) and
truncated after 750 steps (30 s; the registration's ``max_episode_steps``).

The seed draws the start: the leader somewhere on its wander loop, heading along it, the
follower 1.0-1.25 m behind it (0.1 m either side, heading within 0.2 rad of the leader's),
both clear of everything (``fixed_start=True``: the world file's poses, the study's), and
the plant's noise seed (``overrides`` can turn noise on, e.g.
``("robots.follower.camera.noise={std = 10.0}",)`` as in the scenario). ``info`` (the same
keys on reset and step): ``distance``, ``t``, the true ``pose`` and ``leader_pose``,
``contact``, and ``plant`` (:class:`diffbot.envs.episode.Episode`: what replays the episode
on a plant).
"""
from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from bus import codec
from bus.node import Observation
from controllers.ball_follower import detect_ball
from controllers.wander import Wander
from diffbot.analysis.bands import BAND_M, FOLLOWER, LEADER, ball_offset, pose_matrix_of
from plant.footprint import CONTACT_MARGIN_M, FOOTPRINT_RADIUS_M
from plant.world import load_world

from .actions import Drive, check_repeat
from .avoid import make_transport, true_pose
from .episode import Episode, next_seed
from .geometry import Footprints

INPUTS = {LEADER: ["ground_truth"], FOLLOWER: ["joint_states", "ground_truth", "camera/image_raw"]}


class FollowEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(self, transport: str = "inproc", endpoint: str | None = None,
                 world: str = "living_room_follow", action_repeat: int = 2,
                 detection: bool = False, overrides: tuple[str, ...] = (),
                 normalize_actions: bool = False, fixed_start: bool = False,
                 render_mode: str | None = None) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.transport = None
        self.spec_ = spec = load_world(world, list(overrides))
        names = {r.name for r in spec.robots}
        if names != {LEADER, FOLLOWER} or spec.robot(FOLLOWER).sensors.camera is None:
            raise ValueError(f"{world}: Follow-v0 needs robots {LEADER!r} and {FOLLOWER!r}, "
                             "the follower with a camera")
        self.world, self.overrides = world, tuple(overrides)
        self.action_repeat = check_repeat(action_repeat)
        self.fixed_start = bool(fixed_start)
        self.dt = self.action_repeat * spec.control_tick_s
        self.metadata = {**type(self).metadata, "render_fps": round(1.0 / self.dt)}
        self._view = None
        self.detection = bool(detection)
        cam = spec.robot(FOLLOWER).sensors.camera
        self.cam_size = (cam.height, cam.width)
        self.cam_mount = cam.mount_pose()
        self.ball = ball_offset(spec)
        self.geo = Footprints(spec)
        self.start = {r.name: tuple(r.pose) for r in spec.robots}
        drive = spec.robot(FOLLOWER).drive
        self.drive = Drive(drive.max_linear_mps, drive.max_angular_radps, normalize_actions)
        obs = {"image": spaces.Box(0, 255, (cam.height, cam.width, 3), np.uint8)}
        if self.detection:
            obs["ball"] = spaces.Box(0.0, 1.0, (4,), np.float32)
        self.observation_space = spaces.Dict(obs)
        self.action_space = self.drive.space
        self.transport = make_transport(spec, world, INPUTS, transport, endpoint, ("lidar",),
                                        tuple(overrides))

    # ---------------------------------------------------------------- ticks
    def _observe(self, t_ns: int, msgs: dict) -> None:
        self.t_ns, self.msgs = t_ns, msgs

    def _command(self, t_ns: int, msgs: dict) -> dict:
        tw = self.leader.step(Observation(t_ns, LEADER, dict(msgs[LEADER])))
        return {LEADER: (float(tw.linear), float(tw.angular)), FOLLOWER: self.action}

    def _obs(self) -> dict:
        msg = self.msgs[FOLLOWER].get("camera/image_raw")
        img = (codec.image_to_array(msg).copy() if msg is not None
               else np.zeros((*self.cam_size, 3), np.uint8))
        self.image = img
        out = {"image": img}
        if self.detection:
            det = detect_ball(img)
            h, w = self.cam_size
            out["ball"] = (np.zeros(4, np.float32) if det is None else np.clip(
                np.array([1.0, det.u / w, det.v / h, det.radius / w], np.float32), 0.0, 1.0))
        return out

    def _distance(self) -> float:
        lt = pose_matrix_of(self.msgs[LEADER]["ground_truth"])
        ft = pose_matrix_of(self.msgs[FOLLOWER]["ground_truth"])
        return float(np.linalg.norm((lt @ self.ball)[:3] - (ft @ self.cam_mount)[:3, 3]))

    def _info(self) -> dict:
        centres = {n: Footprints.centre(*true_pose(self.msgs[n]["ground_truth"]))
                   for n in (LEADER, FOLLOWER)}
        return {"distance": self._distance(), "t": self.t_ns * 1e-9,
                "pose": np.array(true_pose(self.msgs[FOLLOWER]["ground_truth"])),
                "leader_pose": np.array(true_pose(self.msgs[LEADER]["ground_truth"])),
                "contact": FOLLOWER in self.geo.contacts(centres),
                "plant": self.episode}

    def _draw_start(self, rng: np.random.Generator) -> dict:
        """The leader on its loop, heading along it; the follower behind (module doc)."""
        loop = Wander()
        need = FOOTPRINT_RADIUS_M + CONTACT_MARGIN_M + 0.05
        for _ in range(1000):
            th = rng.uniform(0.0, 2 * math.pi)
            lx, ly = loop.cx + loop.a * math.cos(th), loop.cy + loop.b * math.sin(th)
            heading = math.atan2(loop.b * math.cos(th), -loop.a * math.sin(th))
            gap, side = rng.uniform(1.0, 1.25), rng.uniform(-0.1, 0.1)
            c, s = math.cos(heading), math.sin(heading)
            fx, fy = lx - gap * c - side * s, ly - gap * s + side * c
            fyaw = heading + rng.uniform(-0.2, 0.2)
            poses = {LEADER: (float(lx), float(ly), float(heading)),
                     FOLLOWER: (float(fx), float(fy), float(fyaw))}
            if all(self.geo.clearance(Footprints.centre(*p)) >= need for p in poses.values()):
                return poses
        raise RuntimeError("no free start for the follower behind the leader")

    # ---------------------------------------------------------------- gymnasium
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is None:                # the next seed of the stream (episode.next_seed)
            if self._np_random is None:
                super().reset()
            seed = next_seed(self.np_random)
        super().reset(seed=seed)
        self.leader = Wander()
        self.action = (0.0, 0.0)
        self.over = False
        plant_seed = int(self.np_random.integers(0, 2**31))
        poses = self.start if self.fixed_start else self._draw_start(self.np_random)
        self.episode = Episode(plant_seed, poses, {}, self.world, self.overrides, ("lidar",),
                               seed)
        self.transport.reset(plant_seed, poses, self._observe)
        return self._obs(), self._info()

    def step(self, action):
        if self.over:
            raise RuntimeError("the episode is over: call reset()")
        self.action = self.drive.command(action, FOLLOWER)
        self.transport.advance(self.action_repeat, self._command, self._observe)
        info = self._info()
        d = info["distance"]
        lo, hi = BAND_M
        reward = 1.0 if lo <= d <= hi else -min(lo - d if d < lo else d - hi, 1.0)
        terminated = self.over = bool(info["contact"])
        return self._obs(), float(reward), terminated, False, info

    def render(self):
        """``rgb_array``: the top-down view of the room with both robots (leader first, in
        blue; the follower in orange), and beside it the follower's camera image, scaled by
        a whole factor to the view's height (:mod:`diffbot.envs.render`)."""
        if self.render_mode != "rgb_array":
            return None
        from .render import TopDown, beside
        if self._view is None:
            self._view = TopDown(self.spec_)
        poses = {n: true_pose(self.msgs[n]["ground_truth"]) for n in (LEADER, FOLLOWER)}
        return beside(self._view.frame(poses), self.image)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()
            self.transport = None
