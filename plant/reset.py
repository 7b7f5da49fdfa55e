"""The ``sim/reset`` request (docs/PROTOCOL.md section 6), checked in full before anything
changes, so a bad request leaves the world as it was."""
from __future__ import annotations

import math

from .world import WorldSpec


def parse_reset(req, spec: WorldSpec,
                robots) -> tuple[int | None, dict[str, tuple[float, float, float]]]:
    """(seed or None, new poses by robot) of a reset request; ValueError if any part is bad.
    ``robots`` are the names of the world's robots."""
    if not isinstance(req, dict):
        raise ValueError("request must be a JSON object")
    unknown = set(req) - {"seed", "poses"}
    if unknown:
        raise ValueError(f"unknown request keys: {', '.join(sorted(map(str, unknown)))}")
    seed = req.get("seed")
    if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool)
                             or not 0 <= seed < 2**63):
        raise ValueError("seed must be an integer in [0, 2**63)")
    poses = req.get("poses") or {}
    if not isinstance(poses, dict):
        raise ValueError('poses must be an object {"robot": [x, y, yaw]}')
    half = [s / 2 for s in spec.floor_size_m]
    out = {}
    for name, pose in poses.items():
        if name not in robots:
            raise ValueError(f"unknown robot {name!r}")
        if (not isinstance(pose, list) or len(pose) != 3 or
                not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                        and math.isfinite(v) for v in pose)):
            raise ValueError(f"pose of {name} must be [x, y, yaw] (finite numbers)")
        x, y, yaw = (float(v) for v in pose)
        if abs(x) > half[0] or abs(y) > half[1] or abs(yaw) > 1e3:
            raise ValueError(f"pose of {name} {pose} is off the {2 * half[0]:g} x "
                             f"{2 * half[1]:g} m floor (or yaw beyond 1000 rad)")
        out[name] = (x, y, yaw)
    return seed, out
