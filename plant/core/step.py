"""The core's step: one call a tick for every robot of a world.

:func:`observe` reads every robot's true state into the :class:`~plant.core.data.Data`
arrays (a kinematic world's straight from its arrays, with the arithmetic of
:meth:`plant.sim.Simulation.kin_state`; a dynamic one's from DART). :func:`sense` makes the
messages due at the tick: the per-tick values of all robots at once (encoders, GPS, ground
truth), every due lidar of one configuration in one kernel call
(:func:`plant.lidar.scan_many`), the sensor noise (each stream's draws of every robot in
one call of :func:`plant.noise.normals`: a draw is a function of the robot's stream key and
the tick), and the per-tick messages' CDR bytes packed for all robots in one pass
(:class:`bus.packed.Rows`). Cameras, where due, render robot by robot. The bytes equal the
per-message path's (:func:`plant.tick.tick_messages` with
:class:`plant.sensors.RobotSensors`), which the tests keep as the oracle.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from bus import codec

from .. import camera as cam
from .. import lidar as lid
from .. import noise
from ..raycast import Scene
from ..sim import rotation_to_quaternion
from .data import Data
from .model import EVERY_TICK, Model

_F8 = np.dtype("<f8")
_F4 = np.dtype("<f4")
#: up to this many robots a kinematic world's state is read robot by robot (numpy's cost
#: per call outweighs the arrays' below it)
_FEW = 8


def observe(model: Model, data: Data, w: int, stepper) -> None:
    """World ``w``'s robots' true state into ``data`` (``stepper``: its
    :class:`plant.stepper.Stepper`), and its tick."""
    sim = stepper.sim
    data.tick[w] = sim.time_ns // model.tick_ns
    kin = sim.kin is not None and stepper.physics is None
    if kin and len(model.robots) > _FEW:
        _observe_kinematic(data, w, sim.kin)
        return
    for i, name in enumerate(model.robots):      # DART's state (or a few), robot by robot
        st = sim.kin_state(sim.kin, i) if kin else stepper.state(name)
        data.tf[w, i] = st.tf
        data.yaw[w, i] = st.yaw
        data.v[w, i] = st.v_body[0]
        data.w[w, i] = st.w_body[2]
        data.enc_pos[w, i] = st.enc_pos
        data.enc_vel[w, i] = st.enc_vel
        data.quaternion[w, i] = rotation_to_quaternion(st.tf)


def _observe_kinematic(data: Data, w: int, kin) -> None:
    """:meth:`Simulation.kin_state` of every robot at once: the sines and cosines from
    Python's math (the per-robot path's, to the bit), the rest element by element."""
    yaw = kin.pose[:, 2].tolist()
    c = np.array(list(map(math.cos, yaw)))
    s = np.array(list(map(math.sin, yaw)))
    tf = data.tf[w]
    tf[:, 0, 0], tf[:, 0, 1], tf[:, 0, 3] = c, -s, kin.pose[:, 0]
    tf[:, 1, 0], tf[:, 1, 1], tf[:, 1, 3] = s, c, kin.pose[:, 1]
    tf[:, 2, 3] = kin.radius
    data.yaw[w] = list(map(math.atan2, s.tolist(), c.tolist()))
    data.v[w] = kin.vel[:, 0]
    data.w[w] = kin.vel[:, 1]
    data.enc_pos[w] = kin.wheels
    data.enc_vel[w] = kin.speeds
    # plant.sim.rotation_to_quaternion of [[c, -s, 0], [s, c, 0], [0, 0, 1]], both branches
    tr = (c + c) + 1.0
    pos = tr > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        s1 = np.sqrt(np.where(pos, tr, 0.0) + 1.0) * 2      # trace > 0
        s2 = np.sqrt(((1.0 + 1.0) - c) - c) * 2             # else the z axis leads
        q = data.quaternion[w]
        q[:, 0] = np.where(pos, 0.0 / s1, 0.0 / s2)
        q[:, 1] = 0.0
        q[:, 2] = np.where(pos, (s - -s) / s1, 0.25 * s2)
        q[:, 3] = np.where(pos, 0.25 * s1, (s - -s) / s2)


def wanted_masks(model: Model, tick: int, wanted) -> tuple[dict[str, np.ndarray], set]:
    """(topic -> (R,) bool: due at ``tick`` and read; the topics someone reads). ``wanted``:
    robot -> ``wanted(topic)`` (None, or a robot it leaves out: every due topic is read),
    asked once for each robot's topic due at the tick, the answers kept for the tick
    (:func:`plant.tick.settled`)."""
    masks, rows = model.due(tick)
    if wanted is None:
        return masks, set(rows)
    out, some = dict(masks), set()
    names = model.robots
    for topic, due in rows.items():
        mask = None
        for i in due:
            f = wanted.get(names[i])
            if f is not None and not f(topic):
                if mask is None:
                    mask = out[topic] = masks[topic].copy()
                mask[i] = False
        if mask is None or mask.any():
            some.add(topic)
    return out, some


def sense(model: Model, data: Data, w: int, t_ns: int, shapes: Callable,
          wanted=None) -> list[tuple[str, str, bytes | None]]:
    """(robot, topic, CDR bytes) of every sensor due at ``t_ns`` in world ``w``, in the
    plant's order (robot by robot, each robot's topics in its order), ``None`` for a due
    topic nobody reads (``wanted``: not built, no noise drawn). ``data``
    holds the world's state (:func:`observe`); ``shapes()`` gives its solids or their
    Scene (called only when a lidar or a camera is due and read)."""
    tick = t_ns // model.tick_ns
    read, some = wanted_masks(model, tick, wanted)
    R = len(model.robots)
    out: dict[str, list] = {t: [None] * R for t in model.periods}
    # encoders and GPS of the robots whose topic someone reads, each stream's rows in one draw
    pos, gps = data.enc_pos[w].copy(), data.xyz[w].copy()
    for stream, topic, x in (("encoders", "joint_states", pos), ("gps", "gps", gps)):
        if topic in some and model.any_noise[stream]:
            rows = np.flatnonzero(read[topic])
            x[rows] = _noisy(model, data, w, stream, rows, x[rows], tick)
    _pack_every_tick(model, data, w, t_ns, read, some, out, pos, gps)
    scene = None
    if "scan" in some or "camera/image_raw" in some:
        scene = Scene.from_shapes(shapes())
    tfs = data.tf[w]
    for cfg, group in (model.lidar_groups.items() if "scan" in some else ()):
        due = read["scan"][group]
        if not due.any():
            continue
        rows = group[due]
        exact = lid.scan_many(cfg, tfs[rows], scene, [model.robots[i] for i in rows])
        ranges = lid.apply_noise(cfg, _noisy(model, data, w, "lidar", rows, exact, tick))
        at = np.searchsorted(group, rows)
        msgs = model.scan_rows[cfg].pack(t_ns, {"ranges": ranges.astype(_F4)}, at)
        for i, m in zip(rows.tolist(), msgs):
            out["scan"][i] = m
    for i in model.due(tick)[1].get("camera/image_raw", ()):
        _camera(model, data.streams[w][model.robots[i]].camera_noise, i, t_ns, tick, tfs[i],
                scene, bool(read["camera/image_raw"][i]), bool(read["camera/camera_info"][i]),
                out)
    return [(name, topic, out[topic][i]) for i, name, topic, p in model.order if tick % p == 0]


def _noisy(model: Model, data: Data, w: int, stream: str, rows: np.ndarray, x: np.ndarray,
           tick: int) -> np.ndarray:
    """``x`` (the values of robots ``rows``, one a row) with ``stream``'s noise where the
    robot has it: ``quantise(x + (bias + mean) + Z std)``, Z the normals of each robot's key
    at ``tick`` (:func:`plant.noise.normals`: every row in one call), with the arithmetic of
    :meth:`plant.noise.NoiseModel.apply` row by row (the same bits); ``inf`` stays."""
    out = np.array(x, dtype=float)
    idx = np.flatnonzero(model.noisy[stream][rows])
    if not len(idx):
        return out
    law = model.noise[stream][rows[idx]]
    std, res = law[:, 0], law[:, 3]
    sub = out[idx] + (law[:, 2] + law[:, 1])[:, None]
    drawn = std > 0
    if drawn.any():
        z = noise.normals(data.keys[stream][w, rows[idx[drawn]]], tick, sub.shape[1])
        sub[drawn] = sub[drawn] + z * std[drawn, None]
    q = res > 0
    if q.any():
        r = res[q, None]
        with np.errstate(invalid="ignore"):
            sub[q] = np.where(np.isfinite(sub[q]), np.round(sub[q] / r) * r, sub[q])
    out[idx] = sub
    return out


def _pack_every_tick(model: Model, data: Data, w: int, t_ns: int, read: dict, some: set,
                     out: dict, pos: np.ndarray, gps: np.ndarray) -> None:
    """joint_states, gps and ground_truth of every robot that someone reads, packed."""
    R = len(model.robots)
    rows_of = {t: (None if read[t].all() else np.flatnonzero(read[t])) for t in EVERY_TICK
               if t in some}

    def pick(a, rows):
        return a if rows is None else a[rows]

    def put(topic, msgs):
        rows = rows_of[topic]
        if rows is None:
            out[topic] = msgs
        else:
            for i, m in zip(rows.tolist(), msgs):
                out[topic][i] = m
    if "joint_states" in some:
        r = rows_of["joint_states"]
        put("joint_states", model.joint_rows.pack(t_ns, {
            "position": pick(pos, r).astype(_F8), "velocity": pick(data.enc_vel[w], r).astype(_F8)},
            r))
    if "gps" in some:
        r = rows_of["gps"]
        put("gps", model.gps_rows.pack(t_ns, {"point": pick(gps, r).astype(_F8)}, r))
    if "ground_truth" in some:
        r = rows_of["ground_truth"]
        pose = np.concatenate([data.xyz[w], data.quaternion[w]], axis=1)
        twist = np.zeros((R, 6))
        twist[:, 0], twist[:, 5] = data.v[w], data.w[w]
        put("ground_truth", model.odom_rows.pack(t_ns, {
            "pose": pick(pose, r).astype(_F8), "twist": pick(twist, r).astype(_F8)}, r))


def _camera(model: Model, image_noise, i: int, t_ns: int, tick: int, tf: np.ndarray, scene,
            image: bool, info: bool, out: dict) -> None:
    """Robot ``i``'s camera messages (render, ``image_noise`` at ``tick``, encode), as
    RobotSensors makes them."""
    c = model.cameras[i]
    optical = model.frames["camera_optical"][i]
    if image:
        rgb = cam.render(c, cam.camera_pose(c, tf), scene, exclude_owner=model.robots[i])
        if image_noise is not None:
            rgb = image_noise.apply(rgb, tick)
        out["camera/image_raw"][i] = codec.encode(codec.image(t_ns, rgb, optical))
    if info:
        out["camera/camera_info"][i] = codec.encode(codec.camera_info(
            t_ns, **model.camera_info[i], frame_id=optical))
