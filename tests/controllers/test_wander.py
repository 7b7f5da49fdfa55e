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
