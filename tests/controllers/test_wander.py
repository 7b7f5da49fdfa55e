"""The leader's route (controllers/wander.py): the nearest route point it steers from."""
from __future__ import annotations

import numpy as np

from controllers.wander import Wander


def test_nearest_point_is_the_first_of_the_closest_as_by_the_full_formula():
    """Wander.point against the plain (N, 2) formula, on points anywhere in and around the
    room, on the route's own points and at its centre (where two are nearly equally close)."""
    w = Wander()
    rng = np.random.default_rng(5)
    probes = np.vstack([rng.uniform(-3.0, 3.0, (3000, 2)), w.points[::7],
                        w.points[::11] + rng.normal(0.0, 1e-9, (len(w.points[::11]), 2)),
                        [(w.cx, w.cy), (w.cx + w.a, w.cy), (w.cx, w.cy + w.b)]])
    for x, y in probes.tolist():
        assert w.point(x, y) == int(np.argmin(np.sum((w.points - (x, y)) ** 2, axis=1))), (x, y)


def _full(w: Wander, x: float, y: float) -> int:
    return int(np.argmin(np.sum((w.points - (x, y)) ** 2, axis=1)))


def test_search_from_the_last_point_gives_the_full_search_answer_along_the_leaders_drive():
    """The leader driven by its own commands (a unicycle, 20 ms ticks, from its start in the
    follow world and from off the route): every nearest point the local search gives is
    the full search's, and the whole route is searched only on the first tick."""
    for start in ((-0.1, -1.25, 0.0), (0.4, 0.3, 0.0), (-0.1, 1.3, 3.0)):
        w = Wander()
        x, y, yaw = start
        for _ in range(1500):             # 30 s: past the start-up turn, round the bends
            i = w.point(x, y)
            assert i == _full(w, x, y), (x, y)
            tw = w.step({"ground_truth": _pose(x, y, yaw)})
            x += 0.02 * tw.linear * np.cos(yaw)
            y += 0.02 * tw.linear * np.sin(yaw)
            yaw += 0.02 * tw.angular
        assert w.full_searches == 1, (start, w.full_searches)


def test_search_from_the_last_point_gives_the_full_search_answer_anywhere():
    """Points in a walk of random steps round the room, jumps anywhere, points in and around
    the ellipse, on its evolute (an astroid) and just outside and inside it, the route's
    points and midway between two (where two are often equally near: the first is the
    answer), taken forwards and backwards round the route and across its first point, for
    a wide, a round and a tall ellipse."""
    rng = np.random.default_rng(7)
    for axes in ((1.5, 1.1), (1.0, 1.0), (0.8, 1.6)):
        w = Wander(semi_axes=axes)
        c = np.array([w.cx, w.cy])
        walk = np.cumsum(rng.normal(0.0, 0.01, (1500, 2)), axis=0) + c + (axes[0], 0.0)
        t = rng.uniform(0.0, 2 * np.pi, 300)
        ring = np.stack([np.cos(t), np.sin(t)], axis=1)
        near = c + axes * ring * rng.uniform(0.3, 1.3, (300, 1))
        cusp = abs(axes[0] ** 2 - axes[1] ** 2)
        astroid = c + cusp / np.array(axes) * ring ** 3 * rng.uniform(0.97, 1.05, (300, 1))
        mids = (w.points + np.roll(w.points, -1, axis=0))[::4] / 2
        wrap = [w.points[-3], (w.points[-1] + w.points[0]) / 2]    # (the last and first tie)
        probes = np.vstack([walk, rng.uniform(-3.0, 3.0, (300, 2)), near, astroid,
                            w.points[::9], mids, mids[::-1], wrap, [c, c + (1e-12, 0.0)]])
        for x, y in probes.tolist():
            assert w.point(x, y) == _full(w, x, y), (axes, x, y)
        assert w.full_searches < len(probes)


def _pose(x: float, y: float, yaw: float):
    from bus import codec
    return codec.odometry(0, x, y, yaw, 0.0, 0.0)
