"""One world's per-tick messages as one buffer, written by one kernel call a tick.

Every robot's joint_states, gps and ground_truth lie one after the other in a byte buffer
(robot by robot, in that order), each a copy of its template (:class:`bus.packed.Rows`:
the frame ids and joint names fixed, so a message's length and its values' places are
known once). A tick's call of plant/kernels/sense.c (:func:`plant.kernels.sense_call`)
draws the encoders' and GPS's noise and writes the stamps and values of the messages
someone reads; each message is then a slice of the buffer's bytes. A kinematic world's
state comes into the core's arrays by one call too (:meth:`Outgoing.observe_kinematic`).
:class:`Poses` writes every robot's true pose at a tick into one tf2_msgs/msg/TFMessage
(``sim/poses``, docs/PROTOCOL.md section 2) from the same arrays.
"""
from __future__ import annotations

import numpy as np

from bus.keys import WORLD_FRAME
from bus.packed import _CDR_LE, _STAMP, _U32, _Stamp, _header, _pad, _split, _string

from .. import kernels
from .data import Data
from .model import EVERY_TICK, Model


class Layout:
    """Where each robot's per-tick messages lie in the buffer (the same for every world of
    a model): the buffer with the templates written in, each message's (start, end) and
    its values' places (int64 (R, 8): joint_states start, position, velocity; gps start,
    point; ground_truth start, pose, twist)."""

    def __init__(self, model: Model) -> None:
        rows = (model.joint_rows, model.gps_rows, model.odom_rows)
        fields = (("position", "velocity"), ("point",), ("pose", "twist"))
        parts, at, spans = [], [], []
        n = 0
        for i in range(len(model.robots)):
            places = []
            for r, names in zip(rows, fields):
                t = r.templates[i]
                places.append(n)
                places += [n + r._at[f][i] for f in names]
                spans.append((n, n + len(t)))
                parts.append(t)
                n += len(t)
            at.append(places)
        self.buffer = np.frombuffer(b"".join(parts), np.uint8).copy()
        self.at = np.array(at, np.int64).reshape(len(model.robots), 8)
        self.places = self.at.tolist()
        self.spans = spans
        #: (robot, topic, start, end) of every per-tick message, in the plant's order
        self.order = [(name, topic, a, b) for (name, topic), (a, b) in zip(
            ((n, t) for n in model.robots for t in EVERY_TICK), spans)]


class Outgoing:
    """World ``w``'s buffer and its kernel calls, the arrays' addresses taken once (the
    arrays are :class:`Data`'s and :class:`Model`'s, changed in place)."""

    def __init__(self, model: Model, data: Data, w: int, layout: Layout) -> None:
        R = len(model.robots)
        self.layout = layout
        self.buffer = layout.buffer.copy()
        #: whether each robot's joint_states, gps, ground_truth is made this tick
        self.read = np.ones((R, 3), np.uint8)
        #: (the Settled wanted, {its plans at each phase}) (plant.core.step._read_plan)
        self.plans: tuple = (None, {})
        #: the arrays of world w that a kinematic world's state goes into (views: no
        #: reference back to ``data``, which holds this object)
        self._state = (data.tf[w], data.yaw[w], data.quaternion[w], data.v[w], data.w[w],
                       data.enc_pos[w], data.enc_vel[w])
        self._keep = (data.tf[w], data.quaternion[w], data.v[w], data.w[w], data.enc_pos[w],
                      data.enc_vel[w], data.keys["encoders"][w], model.noise["encoders"],
                      data.keys["gps"][w], model.noise["gps"])
        for a in self._keep:
            assert a.flags.c_contiguous
        self.sense = kernels.sense_call(R, tuple(a.ctypes.data for a in self._keep),
                                        layout.at, self.read, self.buffer)
        self._kin: tuple | None = None         # (the kinematic arrays, their call)
        #: a dynamic world's orientations as quaternions (from ``tf``), in one call
        self.quaternions = kernels.quaternions_call(data.tf[w], data.quaternion[w])
        #: a dynamic world's state rows, copied in each tick, and their call into the
        #: arrays (:meth:`observe_rows`)
        self._rows = np.zeros((R, 26))
        self._observe_rows = kernels.observe_rows_call(
            self._rows, (data.tf[w], data.quaternion[w], data.v[w], data.w[w],
                         data.enc_pos[w], data.enc_vel[w]))

    def observe_rows(self, rows: np.ndarray) -> None:
        """A dynamic world's state ``rows`` (R, 26) (:meth:`plant.sim.Simulation.read_state`)
        into the core's arrays in one call: the pose, forward speed, yaw rate, wheel angles
        and speeds copied, the orientations as quaternions (the yaw is the caller's)."""
        self._rows[:] = rows
        self._observe_rows()

    def observe_kinematic(self, kin) -> None:
        """The true state of a kinematic world's robots (``kin``:
        :class:`plant.kinematic.Kinematics`) into the core's arrays, in one call (the
        arithmetic of :meth:`plant.sim.Simulation.kin_state`)."""
        arrays = (kin.pose, kin.vel, kin.wheels, kin.speeds, kin.radius)
        got = self._kin
        if got is None or any(a is not b for a, b in zip(arrays, got[0])):
            call = kernels.observe_kinematic_call(len(kin.pose), arrays, self._state)
            got = self._kin = (arrays, call)     # (the arrays kept alive with their call)
        got[1]()


class Poses:
    """Every robot's true pose at a tick as one tf2_msgs/msg/TFMessage: a TransformStamped
    per robot in the model's robot order, ``world`` -> ``<robot>/base_link``, each stamped
    with the tick. The message's template (frame ids fixed, so every field's place is known
    once) is filled by one kernel call a tick (plant/kernels/sense.c's plant_poses): each
    robot's stamp, then its translation and rotation x, y, z, qx, qy, qz, qw (:class:`Data`'s
    ``tf`` position and ``quaternion``, the very doubles of its ``ground_truth`` pose)."""

    def __init__(self, model: Model) -> None:
        buf = bytearray(_CDR_LE)
        buf += _U32.pack(len(model.robots))
        places = []
        for child in model.frames["base_link"]:
            _pad(buf, 4)                       # (header.stamp: two 4-byte integers)
            stamp = len(buf)
            _header(buf, _Stamp(WORLD_FRAME))
            _string(buf, child)
            _pad(buf, 8)                       # transform: translation, rotation (7 <f8)
            places.append((stamp, len(buf)))
            buf += bytes(7 * 8)
        self.template = np.frombuffer(bytes(buf), np.uint8)
        self._at = np.array(places, np.int64).reshape(len(places), 2)
        self._buffer = self.template.copy()
        self._calls: dict = {}                 # world -> its kernel call (plant_poses)

    def encode(self, data: Data, w: int, t_ns: int) -> bytes:
        """World ``w``'s message at ``t_ns`` of the state in ``data`` (observed already:
        :func:`plant.core.step.observe`)."""
        call = self._calls.get(w)
        if call is None:
            call = self._calls[w] = kernels.poses_call(data.tf[w], data.quaternion[w],
                                                       self._at, self._buffer)
        sec, nanosec = _split(t_ns)
        _STAMP.pack(sec, nanosec)              # (the stamp's range checked as the wire's)
        call(sec, nanosec)
        return self._buffer.tobytes()
