"""One world's per-tick messages as one buffer, written by one kernel call a tick.

Every robot's joint_states, gps and ground_truth lie one after the other in a byte buffer
(robot by robot, in that order), each a copy of its template (:class:`bus.packed.Rows`:
the frame ids and joint names fixed, so a message's length and its values' places are
known once). A tick's call of plant/kernels/sense.c (:func:`plant.kernels.sense_call`)
draws the encoders' and GPS's noise and writes the stamps and values of the messages
someone reads; each message is then a slice of the buffer's bytes. A kinematic world's
state comes into the core's arrays by one call too (:meth:`Outgoing.observe_kinematic`).
"""
from __future__ import annotations

import numpy as np

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
