"""The core's step: one call a tick for every robot of a world.

:func:`observe` reads every robot's true state into the :class:`~plant.core.data.Data`
arrays (a kinematic world's in one kernel call from its arrays, with the arithmetic of
:meth:`plant.sim.Simulation.kin_state`; a dynamic one's from DART). :func:`sense` makes the
messages due at the tick: every robot's encoders, GPS and ground truth in one call of
plant/kernels/sense.c (their noise drawn, a draw a function of the robot's stream key and
the tick, and their CDR bytes written into one buffer: :mod:`plant.core.outgoing`), every
due lidar of one configuration cast in one kernel call (:func:`plant.lidar.scan_many`) and
its ranges' noise in another. Cameras, where due, render robot by robot. The bytes equal the
per-message path's (:func:`plant.tick.tick_messages` with
:class:`plant.sensors.RobotSensors`), which the tests keep as the oracle.
"""
from __future__ import annotations

import struct
from typing import Callable

import numpy as np

from bus import codec
from bus.keys import WORLD_FRAME

from .. import camera as cam
from .. import kernels
from .. import lidar as lid
from ..raycast import Scene
from ..sensors import JOINTS
from .data import Data
from .model import EVERY_TICK, Model
from .outgoing import Layout, Outgoing, Poses


def outgoing(model: Model, data: Data, w: int) -> Outgoing:
    """World ``w``'s message buffer and kernel calls (made the first time)."""
    got = data.outgoing[w]
    if got is None:
        layout = data.layout
        if layout is None:
            layout = data.layout = Layout(model)
        got = data.outgoing[w] = Outgoing(model, data, w, layout)
    return got


def poses(model: Model, data: Data, w: int, t_ns: int) -> bytes:
    """World ``w``'s ``sim/poses`` at ``t_ns``: every robot's true pose in one
    tf2_msgs/msg/TFMessage (:class:`~plant.core.outgoing.Poses`), of the state
    :func:`observe` read (the poses its ``ground_truth`` messages carry, to the bit)."""
    enc = data.poses
    if enc is None:
        enc = data.poses = Poses(model)
    return enc.encode(data, w, t_ns)


def observe(model: Model, data: Data, w: int, stepper, velocities: bool = True) -> None:
    """World ``w``'s robots' true state into ``data`` (``stepper``: its
    :class:`plant.stepper.Stepper`), and its tick: a kinematic world's in one kernel call
    from its arrays, a dynamic one's as every robot's row of DART's state in one pass
    (:meth:`plant.stepper.Stepper.rows`: the values :meth:`plant.sim.Simulation.state`
    gives, to the bit), the orientations then as quaternions in one call. Without
    ``velocities`` (no ground_truth is made this tick: :func:`reads_truth`) a dynamic
    world's forward speeds and yaw rates may be left NaN."""
    sim = stepper.sim
    data.tick[w] = sim.time_ns // model.tick_ns
    out = outgoing(model, data, w)
    if sim.kin is not None and stepper.physics is None:
        out.observe_kinematic(sim.kin)
        return
    rows = stepper.rows(velocities)
    out.observe_rows(rows)                                  # (all but the yaw: one call)
    data.yaw[w] = np.arctan2(rows[:, 4], rows[:, 0])        # atan2(tf[1, 0], tf[0, 0])


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


def reads_truth(model: Model, data: Data, w: int, tick: int, wanted) -> bool:
    """Whether world ``w`` makes a ground_truth at ``tick`` for the readers ``wanted`` (as
    :func:`sense` takes them): the only message of a robot's body velocities."""
    if wanted is None:
        return "ground_truth" in model.due(tick)[1]
    return "ground_truth" in _read_plan(model, outgoing(model, data, w), tick, wanted)[1]


class Settled(dict):
    """robot -> ``wanted(topic)`` whose answers hold for as long as this object lives (the
    plant's: :class:`plant.outbox.Reads`, a new object whenever a reader may have come or
    gone). :func:`sense` works out what it reads at each phase of the sensors' periods
    once for such an object, not every tick. ``bare``: (robot, topic) -> whether that
    message (a LaserScan, a camera's Image or CameraInfo) is read only as values
    (:mod:`plant.handover`, :mod:`plant.camera_handover`: by members composed into the
    host), so its bytes are not made (:data:`UNENCODED` in their place); None: every
    message read is encoded."""
    __slots__ = ("bare",)

    def __init__(self, wanted=(), bare: Callable[[str], bool] | None = None) -> None:
        super().__init__(wanted)
        self.bare = bare


class _Unencoded(bytes):
    """The type of :data:`UNENCODED`."""
    __slots__ = ()


#: a message read only as values: its bytes were not made (compare with ``is``)
UNENCODED = _Unencoded()


def _scans(model: Model, cfg, group, rows, ranges, t_ns: int, wanted) -> list:
    """The LaserScans of ``rows`` (of lidar ``group``) with ``ranges``: their bytes,
    :data:`UNENCODED` for a robot whose scan only a values reader reads (:class:`Settled`'s
    ``bare``); ``wanted`` False: the messages (:mod:`bus.codec`'s), not their bytes."""
    if wanted is False:
        return [codec.laser_scan(t_ns, cfg.angle_min, cfg.angle_max, cfg.angle_increment,
                                 1.0 / cfg.rate_hz, cfg.min_range_m, cfg.max_range_m, r,
                                 frame_id=model.frames["laser"][i])
                for i, r in zip(rows.tolist(), ranges)]
    at = np.searchsorted(group, rows)
    bare = getattr(wanted, "bare", None)
    if bare is None:
        return model.scan_rows[cfg].pack(t_ns, {"ranges": ranges}, at)
    names = model.robots
    need = np.array([not bare(names[i], "scan") for i in rows.tolist()], bool)
    msgs = [UNENCODED] * len(rows)
    if need.any():
        made = model.scan_rows[cfg].pack(t_ns, {"ranges": ranges[need]}, at[need])
        for k, m in zip(np.flatnonzero(need).tolist(), made):
            msgs[k] = m
    return msgs


def _read_plan(model: Model, out: Outgoing, tick: int, wanted) -> tuple:
    """(:func:`wanted_masks`' masks and topics read, the robots' due topics, the (R, 3)
    per-tick messages read (:attr:`Outgoing.read`), their places in the layout's order) at
    ``tick``; kept for a :class:`Settled` ``wanted`` and the tick's phases (the
    :meth:`Model.due` entry, held with the plan: the same object is the same phases)."""
    due = model.due(tick)
    plans = None
    if type(wanted) is Settled:
        if out.plans[0] is not wanted:
            out.plans = (wanted, {})
        plans = out.plans[1]
        plan = plans.get(id(due))
        if plan is not None and plan[0] is due:
            return plan[1]
    masks, some = wanted_masks(model, tick, wanted)
    reads = out.read if plans is None else out.read.copy()
    for k, topic in enumerate(EVERY_TICK):
        reads[:, k] = masks[topic]
    if plans is None:                      # (the places asked for when needed)
        return masks, some, due[1], reads, None
    plan = (masks, some, due[1], reads, np.flatnonzero(reads.ravel()).tolist())
    if len(plans) >= 1024:
        plans.clear()
    plans[id(due)] = (due, plan)
    return plan


def sense_read(model: Model, data: Data, w: int, t_ns: int, shapes: Callable, wanted,
               cast: tuple | None = None) -> tuple[int, list[tuple[int, str, str, bytes]]]:
    """:func:`sense`'s encoded messages that someone reads (``wanted``), without a place for
    each one nobody reads: (how many were due, [(its place among the due ones, robot,
    topic, CDR bytes)]). A host that numbers every due message (the plant's sequence
    numbers count them, read or not) numbers these by their place."""
    return sense(model, data, w, t_ns, shapes, wanted, True, cast, read_only=True)


def sense(model: Model, data: Data, w: int, t_ns: int, shapes: Callable, wanted=None,
          encoded: bool = True, cast: tuple | None = None, read_only: bool = False):
    """(robot, topic, CDR bytes) of every sensor due at ``t_ns`` in world ``w``, in the
    plant's order (robot by robot, each robot's topics in its order), ``None`` for a due
    topic nobody reads (``wanted``: not built, no noise drawn). ``data``
    holds the world's state (:func:`observe`); ``shapes()`` gives its solids or their
    Scene (called only when a lidar or a camera is due and read). ``encoded`` False: the
    messages (:mod:`bus.codec`'s) of the same values instead of their bytes. ``cast``:
    (scene, {robot index: noise-free ranges}) of the tick's lidars, cast already
    (:func:`plant.tick.messages_of`, several worlds' at once). ``read_only``: what
    :func:`sense_read` returns."""
    tick = t_ns // model.tick_ns
    out = outgoing(model, data, w)
    read = out.read
    if wanted is None:
        masks, due = model.due(tick)
        some = due.keys()
        if not read.all():
            read[:] = 1
        places = range(read.size)
    else:
        masks, some, due, reads, places = _read_plan(model, out, tick, wanted)
        if reads is not read:
            read[:] = reads
    out.sense(tick, t_ns)                  # every per-tick message in one call
    raw = out.buffer.tobytes()
    order = out.layout.order
    if read_only and len(due) == len(EVERY_TICK):     # (the per-tick ones alone: their places)
        if places is None:
            places = np.flatnonzero(read.ravel()).tolist()
        return len(order), [(k, order[k][0], order[k][1], raw[order[k][2]:order[k][3]])
                            for k in places]
    if not encoded:
        made = _objects(model, data, w, out, raw, t_ns)
    elif wanted is None:
        made = [raw[a:b] for _, _, a, b in order]
    else:
        made = [raw[a:b] if r else None for (_, _, a, b), r in zip(order, read.ravel().tolist())]
    if len(due) == len(EVERY_TICK):        # (no lidar nor camera due anywhere)
        return [(name, topic, m) for (name, topic, _, _), m in zip(order, made)]
    R = len(model.robots)
    got: dict[str, list] = {t: [None] * R for t in model.periods}
    for (name, topic, _, _), m in zip(order, made):
        got[topic][model.index[name]] = m
    scene, exact = cast if cast is not None else (None, None)
    if cast is None and ("scan" in some or "camera/image_raw" in some):
        scene = Scene.from_shapes(shapes())
    tfs = data.tf[w]
    kept = []                                  # (the tick's ranges: data.ranges)
    for cfg, group in (model.lidar_groups.items() if "scan" in some else ()):
        rows = group[masks["scan"][group]]
        if not len(rows):
            continue
        if exact is None:
            cast_rows = lid.scan_many(cfg, tfs[rows], scene, [model.robots[i] for i in rows])
        else:
            cast_rows = np.array([exact[i] for i in rows.tolist()], float)
        keys, laws = data.keys["lidar"][w], model.noise["lidar"]
        if len(rows) < R:                      # (every robot's: the arrays as they are)
            keys, laws = keys[rows], laws[rows]
        ranges = kernels.lidar_noise(np.ascontiguousarray(cast_rows, float), keys, laws, tick,
                                     cfg.min_range_m, cfg.max_range_m, cfg.resolution_m)
        kept.append((cfg, rows, ranges))
        msgs = _scans(model, cfg, group, rows, ranges, t_ns, wanted if encoded else False)
        for i, m in zip(rows.tolist(), msgs):
            got["scan"][i] = m
    data.ranges[w] = (tick, kept)
    pictures: dict[int, np.ndarray] = {}       # (the tick's pictures: data.images)
    data.images[w] = (tick, pictures)
    bare = getattr(wanted, "bare", None) if encoded else None
    for i in due.get("camera/image_raw", ()):
        _camera(model, data.streams[w][model.robots[i]].camera_noise, i, t_ns, tick, tfs[i],
                scene, bool(masks["camera/image_raw"][i]), bool(masks["camera/camera_info"][i]),
                got, encoded, pictures, bare)
    made = [(name, topic, got[topic][i]) for i, name, topic, p in model.order if tick % p == 0]
    if read_only:
        return len(made), [(k, *m) for k, m in enumerate(made) if m[2] is not None]
    return made


_D2, _D3, _D7, _D6 = (struct.Struct(f"<{n}d") for n in (2, 3, 7, 6))


def _objects(model: Model, data: Data, w: int, out, raw: bytes, t_ns: int) -> list:
    """The per-tick messages (:mod:`bus.codec`'s, as the per-message path builds them) of
    the values the kernel wrote into ``raw`` (``None`` where unread), in ``out``'s order."""
    made = []
    yaw = data.yaw[w].tolist()
    base = model.frames["base_link"]
    for i, (r, at) in enumerate(zip(out.read.tolist(), out.layout.places)):
        made.append(codec.joint_state(t_ns, JOINTS, _D2.unpack_from(raw, at[1]),
                                      _D2.unpack_from(raw, at[2])) if r[0] else None)
        made.append(codec.point_stamped(t_ns, *_D3.unpack_from(raw, at[4])) if r[1] else None)
        if r[2]:
            x, y, z, *q = _D7.unpack_from(raw, at[6])
            twist = _D6.unpack_from(raw, at[7])
            made.append(codec.odometry(t_ns, x, y, yaw[i], twist[0], twist[5],
                                       frame_id=WORLD_FRAME, child_frame_id=base[i], z=z,
                                       quaternion=q))
        else:
            made.append(None)
    return made


def _camera(model: Model, image_noise, i: int, t_ns: int, tick: int, tf: np.ndarray, scene,
            image: bool, info: bool, out: dict, encoded: bool, pictures: dict,
            bare: Callable[[str, str], bool] | None = None) -> None:
    """Robot ``i``'s camera messages (render, ``image_noise`` at ``tick``, encode where
    ``encoded``), as RobotSensors makes them; its picture into ``pictures`` (what
    :mod:`plant.camera_handover` hands composed members). A message ``bare`` says only
    values readers read is :data:`UNENCODED`: the picture is drawn, its bytes not made."""
    enc = codec.encode if encoded else _same
    c = model.cameras[i]
    robot = model.robots[i]
    optical = model.frames["camera_optical"][i]
    if image:
        # render(camera_pose(tf)) then image_noise.apply(tick): the same bytes, one call
        rgb = pictures[i] = cam.frame(c, tf, scene, robot, image_noise, tick)
        if bare is not None and bare(robot, "camera/image_raw"):
            out["camera/image_raw"][i] = UNENCODED
        else:
            out["camera/image_raw"][i] = enc(codec.image(t_ns, rgb, optical))
    if info and bare is not None and bare(robot, "camera/camera_info"):
        out["camera/camera_info"][i] = UNENCODED
    elif info:
        fields = model.camera_info[i]
        out["camera/camera_info"][i] = _info_bytes(fields, optical, t_ns) if encoded else \
            codec.camera_info(t_ns, **fields, frame_id=optical)


def _same(msg):
    return msg


_STAMP = struct.Struct("<iI")        # a Header's stamp (sec, nanosec), after the CDR header
_INFO: dict[tuple[int, str], tuple] = {}


def _info_bytes(fields: dict, frame_id: str, t_ns: int) -> bytes:
    """``codec.encode(codec.camera_info(t_ns, **fields, frame_id=frame_id))``: a camera's
    CameraInfo changes only in its stamp (bytes 4-11), so the rest is encoded once."""
    got = _INFO.get((id(fields), frame_id))
    if got is None:                    # (an entry holds its fields: their id stays theirs)
        if len(_INFO) > 64:
            _INFO.clear()
        data = codec.encode(codec.camera_info(0, **fields, frame_id=frame_id))
        got = _INFO[(id(fields), frame_id)] = (fields, data[:4], data[12:])
    sec, nanosec = divmod(t_ns, 1_000_000_000)
    return b"".join((got[1], _STAMP.pack(sec, nanosec), got[2]))
