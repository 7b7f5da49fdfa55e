"""A robot's sensors as the plant publishes them: which are due at a tick, and their messages.

Each sensor runs every ``period`` control ticks (its rate rounded to whole ticks). Every
noise stream has a key of its own from (seed, robot, sensor) and a reading's noise is a
function of that key and the tick (:mod:`plant.noise`), so adding a sensor or a reader
never changes another value. Encoder noise is added to each reading (not accumulated);
wheel speeds are reported exact.

The hosts publish the messages the world's core makes (:mod:`plant.core`, every robot at
once); :meth:`RobotSensors.messages` makes the same ones robot by robot and is kept as the
reference the tests compare the core with. :class:`RobotSensors` also stays each robot's
description of its sensors (which are due at a tick, the camera's noise model).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import numpy as np

from bus import codec, packed
from bus.keys import WORLD_FRAME, frame

from . import camera as cam
from . import lidar as lid
from .noise import NoiseModel, stream_key
from .raycast import Scene
from .world import RobotSpec

if TYPE_CHECKING:                      # (plant.sim imports the core, which imports this)
    from .sim import RobotState

JOINTS = ("left_wheel_joint", "right_wheel_joint")

#: ``wanted(topic) -> bool``: whether anyone reads a robot's topic (e.g. Zenoh's matching
#: status of its publisher); a topic nobody reads is not built
Wanted = Callable[[str], bool]


def period_ticks(rate_hz: float, tick_s: float) -> int:
    """Whole control ticks between two readings of a sensor of rate ``rate_hz``."""
    return max(1, int(round(1.0 / (rate_hz * tick_s))))


class RobotSensors:
    def __init__(self, spec: RobotSpec, tick_s: float, seed: int) -> None:
        self.spec = spec
        self.name = spec.name
        s = spec.sensors
        #: the frames this robot's messages carry (docs/PROTOCOL.md: one name everywhere)
        self.frames = {f: frame(self.name, f) for f in ("base_link", "laser", "camera_optical")}

        def model(cfg, stream):
            return (None if cfg.is_zero and cfg.resolution == 0
                    else NoiseModel(cfg, stream_key(seed, self.name, stream)))
        self.enc_noise = model(s.encoder_noise, "encoders")
        self.gps_noise = model(s.gps_noise, "gps")
        self.lidar = s.lidar
        self.camera = s.camera
        self.lidar_noise = model(s.lidar_noise, "lidar") if s.lidar else None
        self.camera_noise = model(s.camera_noise, "camera") if s.camera else None
        self.periods = {"joint_states": 1, "gps": 1, "ground_truth": 1}
        if self.lidar:
            self.periods["scan"] = period_ticks(self.lidar.rate_hz, tick_s)
        if self.camera:
            p = period_ticks(self.camera.rate_hz, tick_s)
            self.periods["camera/image_raw"] = p
            self.periods["camera/camera_info"] = p
            self._info_fields = cam.camera_info(self.camera)

    def prefetch(self, tick: int) -> None:
        """Work that does not depend on the state (the noise of an image due at ``tick``,
        when it is drawn in numpy), done while the plant waits for its nodes."""
        if self.camera_noise is not None and tick % self.periods["camera/image_raw"] == 0:
            self.camera_noise.prefetch_image((self.camera.height, self.camera.width, 3), tick)

    def due(self, tick: int) -> list[str]:
        return [t for t, p in self.periods.items() if tick % p == 0]

    def needs_scene(self, tick: int, wanted: Wanted | None = None) -> bool:
        """Whether a sensor due at ``tick`` casts rays (the lidar, the camera), counting only
        the topics ``wanted`` says someone reads (all if None)."""
        return any(tick % self.periods[t] == 0 and (wanted is None or wanted(t))
                   for t in ("scan", "camera/image_raw") if t in self.periods)

    def lidar_due(self, tick: int) -> bool:
        return self.lidar is not None and tick % self.periods["scan"] == 0

    def messages(self, tick: int, t_ns: int, st: RobotState, scene: Scene | None,
                 exact_scan: np.ndarray | None = None, wanted: Wanted | None = None,
                 encoded: bool = False):
        """(topic, message) pairs due at ``tick``, in a fixed order (the reference the
        core's messages are tested against: :func:`plant.core.sense`). ``exact_scan``: this
        robot's noise-free lidar ranges when the caller cast them already (with
        :func:`scan_all`, for every robot at once). ``wanted(topic)``: whether anyone reads
        that topic (None: every topic is built). A topic nobody reads is not built (no
        rays cast, no frame rendered, no noise drawn, nothing encoded); the noise of a
        reading is a function of the tick, so every value is the same whoever listens.
        ``encoded``: (topic, CDR bytes) pairs instead, the bytes of ``codec.encode`` of
        each message, the per-tick ones packed straight from the values
        (:mod:`bus.packed`), several times faster."""
        want = _every if wanted is None else wanted
        out = []
        if want("joint_states"):
            pos = st.enc_pos
            if self.enc_noise is not None:
                pos = self.enc_noise.apply(pos, tick)
            out.append(("joint_states", packed.joint_state(t_ns, JOINTS, pos, st.enc_vel)
                         if encoded else codec.joint_state(t_ns, JOINTS, pos, st.enc_vel)))
        x, y, z = st.xyz
        if want("gps"):
            gx, gy, gz = (self.gps_noise.apply(np.array([x, y, z]), tick) if self.gps_noise
                          else (x, y, z))
            out.append(("gps", packed.point_stamped(t_ns, float(gx), float(gy), float(gz))
                        if encoded else codec.point_stamped(t_ns, gx, gy, gz)))
        if want("ground_truth"):
            q = st.quaternion
            base = self.frames["base_link"]
            out.append(("ground_truth", packed.odometry(
                t_ns, float(x), float(y), float(z), [float(v) for v in q], float(st.v_body[0]),
                float(st.w_body[2]), frame_id=WORLD_FRAME, child_frame_id=base)
                if encoded else codec.odometry(
                t_ns, x, y, st.yaw, st.v_body[0], st.w_body[2], frame_id=WORLD_FRAME,
                child_frame_id=base, z=z, quaternion=q)))
        enc = codec.encode if encoded else _same
        if self.lidar_due(tick) and want("scan"):
            c = self.lidar
            if exact_scan is None:
                exact_scan = lid.scan(c, st.tf, scene, exclude_owner=self.name)
            ranges = lid.apply_noise(c, exact_scan, self.lidar_noise, tick)
            out.append(("scan", enc(codec.laser_scan(
                t_ns, c.angle_min, c.angle_max, c.angle_increment, 1.0 / c.rate_hz,
                c.min_range_m, c.max_range_m, ranges, frame_id=self.frames["laser"]))))
        if self.camera and tick % self.periods["camera/image_raw"] == 0:
            optical = self.frames["camera_optical"]
            if want("camera/image_raw"):
                rgb = cam.render(self.camera, cam.camera_pose(self.camera, st.tf), scene,
                                 exclude_owner=self.name)
                if self.camera_noise is not None:
                    rgb = self.camera_noise.apply(rgb, tick)
                out.append(("camera/image_raw", enc(codec.image(t_ns, rgb, optical))))
            if want("camera/camera_info"):
                out.append(("camera/camera_info", enc(codec.camera_info(
                    t_ns, **self._info_fields, frame_id=optical))))
        return out


def _same(msg):
    return msg


def _every(topic: str) -> bool:
    return True


def scan_all(sensors: dict[str, RobotSensors], states: dict[str, RobotState], tick: int,
             scene: Scene, wanted: dict[str, Wanted] | None = None) -> dict[str, np.ndarray]:
    """Noise-free ranges of every lidar due at ``tick`` (whose scan someone reads, with
    ``wanted``: robot -> :data:`Wanted`): robots carrying the same lidar are cast together
    (:func:`plant.lidar.scan_many`), the same bits as one by one."""
    groups: dict[lid.LidarConfig, list[str]] = {}
    for name, s in sensors.items():
        if s.lidar_due(tick) and (wanted is None or wanted[name]("scan")):
            groups.setdefault(s.lidar, []).append(name)
    out = {}
    for cfg, names in groups.items():
        rows = lid.scan_many(cfg, [states[n].tf for n in names], scene, names)
        out.update(zip(names, rows))
    return out
