"""Reference dead reckoning: exact arc integration of wheel-encoder increments.

Sign convention (the usual one; the study's equation (2) has it the other way round):
x forward, y left, yaw counter-clockwise. For encoder increments dl, dr (rad) of
wheels of radius r whose contact points are d apart::

    ds     = r (dr + dl) / 2          distance travelled by the axle midpoint
    dtheta = r (dr - dl) / d          positive = turned left

With the wheel speeds held over the interval the midpoint moves on a circular arc,
whose chord has length ``ds * sinc(dtheta/2)`` and heading ``theta + dtheta/2``:
that update is exact for any step, straight lines and spins in place included.
The FMU in ``fmus/odometry`` implements the same formula in C.
"""
from __future__ import annotations

import math

import numpy as np


def _sinc_half(half: float) -> float:
    """sin(h)/h, with its series near 0 (exact to double precision)."""
    return 1.0 - half * half / 6.0 if abs(half) < 1e-9 else math.sin(half) / half


def arc_step(x: float, y: float, theta: float, dl: float, dr: float, r: float, d: float
             ) -> tuple[float, float, float]:
    """Pose after encoder increments (dl, dr) in rad."""
    ds = r * (dr + dl) / 2.0
    dtheta = r * (dr - dl) / d
    half = dtheta / 2.0
    chord = ds * _sinc_half(half)
    return (x + chord * math.cos(theta + half), y + chord * math.sin(theta + half), theta + dtheta)


def integrate(enc_left: np.ndarray, enc_right: np.ndarray, r: float = 0.12, d: float = 0.36,
              pose0: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Poses (N, 3) [x, y, theta] for encoder angle series (N,) in rad; row 0 is ``pose0``.

    theta is not wrapped (it counts whole turns), as the encoders do.
    """
    enc_left = np.asarray(enc_left, dtype=float)
    enc_right = np.asarray(enc_right, dtype=float)
    if enc_left.shape != enc_right.shape or enc_left.ndim != 1:
        raise ValueError("enc_left and enc_right must be 1-D arrays of the same length")
    out = np.empty((len(enc_left), 3))
    if len(enc_left) == 0:
        return out
    x, y, th = pose0
    out[0] = pose0
    dl = np.diff(enc_left)
    dr = np.diff(enc_right)
    for i in range(len(dl)):
        x, y, th = arc_step(x, y, th, dl[i], dr[i], r, d)
        out[i + 1] = (x, y, th)
    return out


class Odometry:
    """Incremental form of :func:`integrate` for a stream of encoder readings."""

    def __init__(self, r: float = 0.12, d: float = 0.36,
                 pose0: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        self.r, self.d = r, d
        self.x, self.y, self.theta = pose0
        self.v = self.w = 0.0
        self._last: tuple[float, float] | None = None
        self._last_t: float | None = None

    def update(self, left: float, right: float, t: float | None = None) -> tuple[float, float, float]:
        """Feed absolute encoder angles (rad) at time t (s); returns the pose."""
        if self._last is not None:
            dl, dr = left - self._last[0], right - self._last[1]
            self.x, self.y, self.theta = arc_step(self.x, self.y, self.theta, dl, dr, self.r, self.d)
            if t is not None and self._last_t is not None and t > self._last_t:
                h = t - self._last_t
                self.v = self.r * (dr + dl) / 2.0 / h
                self.w = self.r * (dr - dl) / self.d / h
        self._last = (left, right)
        self._last_t = t
        return self.x, self.y, self.theta
