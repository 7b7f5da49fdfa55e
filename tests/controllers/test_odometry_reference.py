"""The reference odometry reproduces closed-form arcs exactly (and the sign convention)."""
import math

import numpy as np
import pytest

from controllers.odometry import Odometry, arc_step, integrate

R, D = 0.12, 0.36


def closed_form(v, w, t, pose0=(0.0, 0.0, 0.0)):
    x0, y0, th0 = pose0
    if w == 0:
        return x0 + v * t * math.cos(th0), y0 + v * t * math.sin(th0), th0
    th = th0 + w * t
    return (x0 + v / w * (math.sin(th) - math.sin(th0)),
            y0 - v / w * (math.cos(th) - math.cos(th0)), th)


@pytest.mark.parametrize("wl,wr", [(1, 1), (1, -1), (2, 1), (0.5, 3), (-1, -2), (0, 0), (1, 1 + 1e-6)])
@pytest.mark.parametrize("h", [0.001, 0.02, 0.5])
def test_exact_arc_for_constant_wheel_speeds(wl, wr, h):
    n = int(round(10 / h))
    t = np.arange(n + 1) * h
    poses = integrate(wl * t, wr * t, R, D, (0.3, -0.2, 0.4))
    v, w = R * (wr + wl) / 2, R * (wr - wl) / D
    x, y, th = closed_form(v, w, t[-1], (0.3, -0.2, 0.4))
    assert np.allclose(poses[-1], [x, y, th], atol=1e-9, rtol=0)


def test_sign_convention_right_wheel_faster_turns_left():
    x, y, th = arc_step(0, 0, 0, dl=1.0, dr=2.0, r=R, d=D)
    assert th > 0 and y > 0 and x > 0
    x, y, th = arc_step(0, 0, 0, dl=1.0, dr=-1.0, r=R, d=D)   # spin in place, clockwise
    assert math.isclose(th, -2 * R / D) and abs(x) < 1e-15 and abs(y) < 1e-15


def test_incremental_matches_batch():
    rng = np.random.default_rng(1)
    el = np.cumsum(rng.normal(0.1, 0.05, 500))
    er = np.cumsum(rng.normal(0.1, 0.05, 500))
    batch = integrate(el, er, R, D)
    o = Odometry(R, D)
    inc = np.array([o.update(a, b, i * 0.02) for i, (a, b) in enumerate(zip(el, er))])
    assert np.array_equal(batch, inc)


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError):
        integrate(np.zeros(3), np.zeros(4))
