"""Differential-drive kinematics and command limits (pure Python, no physics).

Convention: x forward, y left, yaw counter-clockwise. With wheel radius r and
wheel separation d (between the wheels' contact points)::

    v = r (w_right + w_left) / 2          w = r (w_right - w_left) / d
    w_left = (v - w d / 2) / r           w_right = (v + w d / 2) / r
"""
from __future__ import annotations

import math

from .world import DriveSpec


def inverse(v_mps: float, w_radps: float, r: float, d: float) -> tuple[float, float]:
    """Wheel speeds (left, right) in rad/s for a body velocity."""
    return (v_mps - w_radps * d / 2.0) / r, (v_mps + w_radps * d / 2.0) / r


def forward(wl: float, wr: float, r: float, d: float) -> tuple[float, float]:
    """Body velocity (v m/s, w rad/s) for wheel speeds in rad/s."""
    return r * (wr + wl) / 2.0, r * (wr - wl) / d


def _clamp(x: float, lim: float) -> float:
    return max(-lim, min(lim, x))


def _ramp(target: float, current: float, max_delta: float) -> float:
    return current + _clamp(target - current, max_delta)


class DriveLimiter:
    """Turns commands into wheel-speed set-points within the world file's limits.

    ``cmd_vel`` is clamped to the body speed limits and ramped by the body
    acceleration limits; wheel commands are clamped and ramped per wheel. Either
    way the result is clamped to ``max_wheel_speed_radps``. Non-finite inputs
    never reach here (the plant rejects them first).

    The hosts' ticks run every robot's limiter at once as arrays
    (:mod:`plant.core.drive`, a C kernel); this class is its reference, robot by robot,
    which the tests compare it with to the bit.
    """

    def __init__(self, spec: DriveSpec) -> None:
        self.spec = spec
        self.v = 0.0
        self.w = 0.0
        self.wheels = (0.0, 0.0)

    def reset(self) -> None:
        self.v = self.w = 0.0
        self.wheels = (0.0, 0.0)

    def from_twist(self, v_target: float, w_target: float, dt: float) -> tuple[float, float]:
        s = self.spec
        v_target = _clamp(v_target, s.max_linear_mps)
        w_target = _clamp(w_target, s.max_angular_radps)
        self.v = _ramp(v_target, self.v, s.max_linear_accel_mps2 * dt)
        self.w = _ramp(w_target, self.w, s.max_angular_accel_radps2 * dt)
        wl, wr = inverse(self.v, self.w, s.wheel_radius_m, s.wheel_separation_m)
        return self._wheel_limits(wl, wr, dt)

    def from_wheels(self, wl: float, wr: float, dt: float) -> tuple[float, float]:
        out = self._wheel_limits(wl, wr, dt)
        self.v, self.w = forward(*out, self.spec.wheel_radius_m, self.spec.wheel_separation_m)
        return out

    def _wheel_limits(self, wl: float, wr: float, dt: float) -> tuple[float, float]:
        s = self.spec
        m = s.max_wheel_speed_radps
        # Scale both wheels together so the path's curvature is kept.
        peak = max(abs(wl), abs(wr))
        if peak > m:
            wl, wr = wl * m / peak, wr * m / peak
        a = s.max_wheel_accel_radps2 * dt
        self.wheels = (_ramp(wl, self.wheels[0], a), _ramp(wr, self.wheels[1], a))
        return self.wheels


def finite(*xs: float) -> bool:
    return all(math.isfinite(x) for x in xs)
