"""The swarm scenario's analysis: paths, distance covered, collisions, a top-down PNG.

Collisions are judged on ground truth with a conservative footprint: each robot is the
circle of radius ``FOOTPRINT_RADIUS_M`` round its chassis box's centre (it holds the
whole 0.40 x 0.26 m box). A *collision* is an event: a robot's footprint coming within
``CONTACT_MARGIN_M`` of another robot's footprint, an obstacle or a wall, counted once
per contact episode (it ends when they are ``CONTACT_MARGIN_M`` apart again).
"""
from __future__ import annotations

import csv
import math
import os

import numpy as np

from bus import codec
from bus.keys import TOPICS, Keys
from plant.footprint import CONTACT_MARGIN_M, FOOTPRINT_RADIUS_M, footprint_centres


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

    @staticmethod
    def keys(keys: Keys, spec, world) -> dict[str, str]:
        return {keys.topic(r.name, "ground_truth"): TOPICS["ground_truth"].msgtype
                for r in world.robots}

    @staticmethod
    def analyse(observer, keys, spec, world, out) -> dict:
        names = [r.name for r in world.robots]
        tracks = {}
        for r in names:
            rows = {}
            for m in observer.messages(keys.topic(r, "ground_truth")):
                p = m.pose.pose
                rows[codec.msg_stamp_ns(m)] = (p.position.x, p.position.y,
                                               codec.quaternion_to_yaw(p.orientation))
            tracks[r] = rows
        stamps = sorted(set.intersection(*(set(t) for t in tracks.values()))) if tracks else []
        if not stamps:
            return {"robots": len(names), "samples": 0}
        a = np.array([[tracks[r][t] for r in names] for t in stamps])   # ticks, robots, 3
        with open(os.path.join(out, "paths.csv"), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["t_s", "robot", "x_m", "y_m", "yaw_rad"])
            for k, t in enumerate(stamps):
                for i, r in enumerate(names):
                    w.writerow([f"{t * 1e-9:.9f}", r, *(f"{v:.9f}" for v in a[k, i])])
        dist = np.sum(np.hypot(np.diff(a[:, :, 0], axis=0), np.diff(a[:, :, 1], axis=0)), axis=0)
        col = collisions(footprint_centres(a[:, :, 0], a[:, :, 1], a[:, :, 2]), world)
        plot_paths(a, names, world, os.path.join(out, "paths.png"),
                   f"swarm: {len(names)} robots, {(stamps[-1] - stamps[0]) * 1e-9:.0f} s, "
                   f"{col['total']} collisions")
        return {"robots": len(names), "samples": len(stamps),
                "duration_s": (stamps[-1] - stamps[0]) * 1e-9,
                "distance_m": {r: float(d) for r, d in zip(names, dist)},
                "distance_total_m": float(dist.sum()), "distance_min_m": float(dist.min()),
                "collisions": col,
                "controller_processes": spec.controller_processes}


def plot_paths(a: np.ndarray, names: list[str], world, path: str, title: str) -> str:
    from matplotlib.patches import Circle, Rectangle
    from matplotlib.transforms import Affine2D

    from .plots import plt, save
    fig, ax = plt.subplots(figsize=(7, 7))
    hx, hy = np.asarray(world.floor_size_m) / 2
    ax.add_patch(Rectangle((-hx, -hy), 2 * hx, 2 * hy, fill=False, lw=2, color="k"))
    for o in world.objects:
        if o.name == "floor" or o.name.startswith("wall_"):
            continue
        x, y, _, yaw = o.pose
        if o.shape == "box":
            r = Rectangle((-o.size[0] / 2, -o.size[1] / 2), o.size[0], o.size[1],
                          color="0.55")
            r.set_transform(Affine2D().rotate(yaw).translate(x, y) + ax.transData)
            ax.add_patch(r)
        else:
            ax.add_patch(Circle((x, y), o.size[0], color="0.55"))
    colors = {r.name: r.color for r in world.robots}
    for i, n in enumerate(names):
        ax.plot(a[:, i, 0], a[:, i, 1], lw=1, color=colors[n])
        ax.plot(a[0, i, 0], a[0, i, 1], "o", ms=4, color=colors[n])
        ax.plot(a[-1, i, 0], a[-1, i, 1], "s", ms=4, color=colors[n])
    ax.set_xlim(-hx - 0.2, hx + 0.2)
    ax.set_ylim(-hy - 0.2, hy + 0.2)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title + "  (o start, \u25a1 end)")
    return save(fig, path)
