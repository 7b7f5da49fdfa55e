"""The swarm scenario's analysis: paths, distance covered, collisions, a top-down PNG.

Collisions are judged on ground truth with a conservative footprint: each robot is the
circle of radius ``FOOTPRINT_RADIUS_M`` round its chassis box's centre (it holds the
whole 0.40 x 0.26 m box). A *collision* is an event: a robot's footprint coming within
``CONTACT_MARGIN_M`` of another robot's footprint, an obstacle or a wall, counted once
per contact episode (it ends when they are ``CONTACT_MARGIN_M`` apart again).
"""
from __future__ import annotations

import math
import os

import numpy as np

from bus.keys import Keys
from plant.footprint import CONTACT_MARGIN_M, FOOTPRINT_RADIUS_M, footprint_centres

from .paths import ground_truth_tracks, plot_paths, write_csv
from .paths import keys as paths_keys


def clearance_to_object(p: np.ndarray, obj) -> np.ndarray:
    """Distance (m) from points ``p`` (..., 2) to a static object's footprint."""
    x, y, _, yaw = obj.pose
    d = p - (x, y)
    if obj.shape == "box":
        c, s = math.cos(yaw), math.sin(yaw)
        lx, ly = d[..., 0] * c + d[..., 1] * s, -d[..., 0] * s + d[..., 1] * c
        qx = np.maximum(np.abs(lx) - obj.size[0] / 2, 0.0)
        qy = np.maximum(np.abs(ly) - obj.size[1] / 2, 0.0)
        return np.hypot(qx, qy)
    return np.maximum(np.hypot(d[..., 0], d[..., 1]) - obj.size[0], 0.0)


def count_episodes(touching: np.ndarray) -> int:
    """Rising edges of a boolean series (the first sample counts if it starts touching)."""
    t = np.asarray(touching, dtype=bool)
    return int(t[0]) + int(np.sum(t[1:] & ~t[:-1])) if len(t) else 0


def footprint_gap(c: np.ndarray, i: int, j: int) -> np.ndarray:
    """Per tick, the gap (m) between robots ``i``'s and ``j``'s footprints (negative: they
    overlap), from footprint centres ``c`` (ticks, robots, 2)."""
    return np.hypot(*(c[:, i] - c[:, j]).T) - 2 * FOOTPRINT_RADIUS_M


def robot_contacts(gap: np.ndarray) -> int:
    """Contact episodes of two robots from their footprint gap per tick."""
    return count_episodes(gap < CONTACT_MARGIN_M)


def collisions(c: np.ndarray, world) -> dict:
    """Collision events from footprint centres ``c`` (ticks, robots, 2)."""
    n = c.shape[1]
    half = np.asarray(world.floor_size_m) / 2
    robot_robot = 0
    pairs = []
    for i in range(n):
        for j in range(i + 1, n):
            k = robot_contacts(footprint_gap(c, i, j))
            if k:
                pairs.append([i, j, k])
            robot_robot += k
    obstacles = walls = 0
    for obj in world.objects:
        k = sum(count_episodes(clearance_to_object(c[:, i], obj)
                               < FOOTPRINT_RADIUS_M + CONTACT_MARGIN_M) for i in range(n))
        obstacles += k
    for i in range(n):
        gap = np.min(half - np.abs(c[:, i]), axis=1)
        walls += count_episodes(gap < FOOTPRINT_RADIUS_M + CONTACT_MARGIN_M)
    return {"robot_robot": robot_robot, "robot_obstacle": obstacles, "robot_wall": walls,
            "total": robot_robot + obstacles + walls, "robot_pairs": pairs}


class SwarmAnalysis:
    draws = True
    draws_paths = True      # its paths.png says the collisions too (diffbot.analysis.paths)

    @staticmethod
    def keys(keys: Keys, spec, world) -> dict[str, str]:
        return paths_keys(keys, world)

    @staticmethod
    def analyse(observer, keys, spec, world, out, plots: bool = True) -> dict:
        names = [r.name for r in world.robots]
        tracks = ground_truth_tracks(observer, keys, names)
        stamps = sorted(set.intersection(*(set(t) for t in tracks.values()))) if tracks else []
        if not stamps:
            return {"robots": len(names), "samples": 0}
        a = np.array([[tracks[r][t] for r in names] for t in stamps])   # ticks, robots, 3
        write_csv(os.path.join(out, "paths.csv"),
                  {r: {t: tracks[r][t] for t in stamps} for r in names})
        dist = np.sum(np.hypot(np.diff(a[:, :, 0], axis=0), np.diff(a[:, :, 1], axis=0)), axis=0)
        col = collisions(footprint_centres(a[:, :, 0], a[:, :, 1], a[:, :, 2]), world)
        if plots:
            plot_paths({r: a[:, i, :2] for i, r in enumerate(names)}, world,
                       os.path.join(out, "paths.png"),
                       f"swarm: {len(names)} robots, {(stamps[-1] - stamps[0]) * 1e-9:.0f} s, "
                       f"{col['total']} collisions")
        return {"robots": len(names), "samples": len(stamps),
                "duration_s": (stamps[-1] - stamps[0]) * 1e-9,
                "distance_m": {r: float(d) for r, d in zip(names, dist)},
                "distance_total_m": float(dist.sum()), "distance_min_m": float(dist.min()),
                "collisions": col,
                "controller_processes": spec.controller_processes}
