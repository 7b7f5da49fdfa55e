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

from typing import Callable

import numpy as np

from bus import codec

from .. import camera as cam
from .. import kernels
from .. import lidar as lid
from ..raycast import Scene
from .data import Data
from .model import EVERY_TICK, Model
from .outgoing import Layout, Outgoing


def outgoing(model: Model, data: Data, w: int) -> Outgoing:
    """World ``w``'s message buffer and kernel calls (made the first time)."""
    got = data.outgoing[w]
    if got is None:
        layout = data.layout
        if layout is None:
            layout = data.layout = Layout(model)
        got = data.outgoing[w] = Outgoing(model, data, w, layout)
    return got


def observe(model: Model, data: Data, w: int, stepper) -> None:
    """World ``w``'s robots' true state into ``data`` (``stepper``: its
    :class:`plant.stepper.Stepper`), and its tick: a kinematic world's in one kernel call
    from its arrays, a dynamic one's from DART robot by robot (the orientations then as
    quaternions in one call)."""
    sim = stepper.sim
    data.tick[w] = sim.time_ns // model.tick_ns
    if sim.kin is not None and stepper.physics is None:
        outgoing(model, data, w).observe_kinematic(sim.kin)
        return
    states = [stepper.state(name) for name in model.robots]
    data.tf[w] = [st.tf for st in states]
    data.yaw[w] = [st.yaw for st in states]
    data.v[w] = [st.v_body[0] for st in states]
    data.w[w] = [st.w_body[2] for st in states]
    data.enc_pos[w] = [st.enc_pos for st in states]
    data.enc_vel[w] = [st.enc_vel for st in states]
    kernels.quaternions(data.tf[w], data.quaternion[w])


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
    out = outgoing(model, data, w)
    read = out.read
    if wanted is None:
        masks, due = model.due(tick)
        some = due.keys()
        if not read.all():
            read[:] = 1
    else:
        masks, some = wanted_masks(model, tick, wanted)
        due = model.due(tick)[1]
        for k, topic in enumerate(EVERY_TICK):
            read[:, k] = masks[topic]
    out.sense(tick, t_ns)                  # every per-tick message in one call
    raw = out.buffer.tobytes()
    order = out.layout.order
    if len(due) == len(EVERY_TICK):        # (no lidar nor camera due anywhere)
        if wanted is None:
            return [(name, topic, raw[a:b]) for name, topic, a, b in order]
        return [(name, topic, raw[a:b] if r else None)
                for (name, topic, a, b), r in zip(order, read.ravel().tolist())]
    R = len(model.robots)
    got: dict[str, list] = {t: [None] * R for t in model.periods}
    for (name, topic, a, b), r in zip(order, read.ravel().tolist()):
        if r:
            got[topic][model.index[name]] = raw[a:b]
    scene = None
    if "scan" in some or "camera/image_raw" in some:
        scene = Scene.from_shapes(shapes())
    tfs = data.tf[w]
    for cfg, group in (model.lidar_groups.items() if "scan" in some else ()):
        rows = group[masks["scan"][group]]
        if not len(rows):
            continue
        exact = lid.scan_many(cfg, tfs[rows], scene, [model.robots[i] for i in rows])
        ranges = kernels.lidar_noise(np.ascontiguousarray(exact, float),
                                     data.keys["lidar"][w, rows], model.noise["lidar"][rows],
                                     tick, cfg.min_range_m, cfg.max_range_m, cfg.resolution_m)
        at = np.searchsorted(group, rows)
        msgs = model.scan_rows[cfg].pack(t_ns, {"ranges": ranges}, at)
        for i, m in zip(rows.tolist(), msgs):
            got["scan"][i] = m
    for i in due.get("camera/image_raw", ()):
        _camera(model, data.streams[w][model.robots[i]].camera_noise, i, t_ns, tick, tfs[i],
                scene, bool(masks["camera/image_raw"][i]), bool(masks["camera/camera_info"][i]),
                got)
    return [(name, topic, got[topic][i]) for i, name, topic, p in model.order if tick % p == 0]


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
