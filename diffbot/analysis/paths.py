"""Every run's robot paths on the room's map: ``paths.csv`` and ``paths.png``.

Whatever a scenario's own analysis does (a user's own scenario, with ``exec`` processes,
has none), the run keeps every robot's true pose (the plant's ``sim/poses``: one
tf2_msgs/TFMessage a tick, a transform per robot in the world frame, the poses of the
robots' ``<robot>/ground_truth``, which it reads instead where the analysis keeps them
already) and afterwards writes:

* ``paths.csv``: ``t_s, robot, x_m, y_m, yaw_rad`` for every tick every robot reported;
* ``paths.png``: the room from its world file (the floor's edge or its walls, each piece of
  furniture's footprint, the ones a robot passes under drawn hollow), each robot's path in
  its own colour, its start (circle) and end (square).

An analysis that draws the paths itself (the swarm's) says so with ``draws_paths = True``.
"""
from __future__ import annotations

import csv
import os

import numpy as np

from bus import codec
from bus.keys import POSES_TYPE, Keys, frame
from plant.footprint import ROBOT_TOP_M, bottom


def keys(keys: Keys, world, kept: dict[str, str] | None = None) -> dict[str, str]:
    """The observer's keys for the paths: none more where the run keeps every robot's
    ``ground_truth`` already (``kept``: the analysis's keys; one robot's square, the follow),
    else every robot's pose in one message a tick, ``sim/poses`` (the plant then builds no
    robot's ``ground_truth`` for the paths alone, and puts one message a tick, not one a
    robot). Either gives the same poses, to the bit."""
    if kept is not None and all(_truth(keys, r.name) in kept for r in world.robots):
        return {}
    return {keys.poses: POSES_TYPE}


def _truth(keys: Keys, robot: str) -> str:
    return keys.topic(robot, "ground_truth")


def ground_truth_tracks(observer, keys: Keys, names: list[str]) -> dict[str, dict[int, tuple]]:
    """robot -> {stamp ns: (x, y, yaw)} from the observed ``sim/poses`` (each transform's
    child frame says its robot: ``<robot>/base_link``), or from every robot's
    ``ground_truth`` where the observer keeps those instead (:func:`keys`)."""
    tracks: dict[str, dict[int, tuple]] = {r: {} for r in names}
    if keys.poses not in observer.keep:
        for r in names:
            rows = tracks[r]
            for m in observer.messages(_truth(keys, r)):
                p = m.pose.pose
                rows[codec.msg_stamp_ns(m)] = (p.position.x, p.position.y,
                                               codec.quaternion_to_yaw(p.orientation))
        return tracks
    robot_of = {frame(r, "base_link"): tracks[r] for r in names}
    for m in observer.messages(keys.poses):
        for tf in m.transforms:
            rows = robot_of.get(tf.child_frame_id)
            if rows is not None:
                p, q = tf.transform.translation, tf.transform.rotation
                rows[codec.stamp_ns(tf.header.stamp)] = (p.x, p.y, codec.quaternion_to_yaw(q))
    return tracks


def write_csv(path: str, tracks: dict[str, dict[int, tuple]]) -> str:
    """``paths.csv``: one row per tick per robot, by time, then in the world's robot order."""
    stamps = sorted(set().union(*(set(t) for t in tracks.values()))) if tracks else []
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t_s", "robot", "x_m", "y_m", "yaw_rad"])
        for t in stamps:
            for r, rows in tracks.items():
                if t in rows:
                    w.writerow([f"{t * 1e-9:.9f}", r, *(f"{v:.9f}" for v in rows[t])])
    return path


def write_paths(observer, keys: Keys, spec, world, out: str, plots: bool = True) -> dict:
    """``paths.csv`` and (with ``plots``) ``paths.png`` of a run; what the summary says of
    them."""
    names = [r.name for r in world.robots]
    tracks = {r: rows for r, rows in ground_truth_tracks(observer, keys, names).items() if rows}
    if not tracks:
        return {"robots": 0}
    write_csv(os.path.join(out, "paths.csv"), tracks)
    paths = {r: np.array([rows[t] for t in sorted(rows)]) for r, rows in tracks.items()}
    length = {r: float(np.sum(np.hypot(*np.diff(p[:, :2], axis=0).T))) for r, p in paths.items()}
    t0 = min(min(rows) for rows in tracks.values())
    t1 = max(max(rows) for rows in tracks.values())
    if plots:
        plot_paths(paths, world, os.path.join(out, "paths.png"),
                   f"{spec.name}: {len(paths)} robot{'s' * (len(paths) > 1)}, "
                   f"{(t1 - t0) * 1e-9:.1f} s")
    return {"robots": len(paths), "duration_s": (t1 - t0) * 1e-9, "distance_m": length,
            "files": ["paths.csv", "paths.png"] if plots else ["paths.csv"]}


def plot_paths(paths: dict[str, np.ndarray], world, path: str, title: str) -> str:
    """The room (floor edge or walls, furniture footprints) and each robot's path
    (``paths``: robot -> (ticks, >=2) array of x, y), start o, end square."""
    from matplotlib.patches import Circle, Rectangle
    from matplotlib.transforms import Affine2D

    from .plots import plt, save
    fig, ax = plt.subplots(figsize=(7, 7))
    hx, hy = np.asarray(world.floor_size_m) / 2
    if world.wall_height_m > 0:
        t = world.wall_thickness_m
        ax.add_patch(Rectangle((-hx - t, -hy - t), 2 * (hx + t), 2 * (hy + t), fill=False,
                               lw=4, color="0.3"))
    ax.add_patch(Rectangle((-hx, -hy), 2 * hx, 2 * hy, fill=False, lw=1, color="k"))
    for o in world.objects:
        if o.name == "floor" or o.name.startswith("wall_"):
            continue
        x, y, _, yaw = o.pose
        # what a robot passes under (table tops, the TV) hollow, what stops it filled
        under = bottom(o) >= ROBOT_TOP_M
        style = dict(fill=not under, lw=1, ec="0.45", fc="0.7" if not under else "none")
        if o.shape == "box":
            r = Rectangle((-o.size[0] / 2, -o.size[1] / 2), o.size[0], o.size[1], **style)
            r.set_transform(Affine2D().rotate(yaw).translate(x, y) + ax.transData)
            ax.add_patch(r)
        else:
            ax.add_patch(Circle((x, y), o.size[0], **style))
    colors = {r.name: r.color for r in world.robots}
    for n, p in paths.items():
        ax.plot(p[:, 0], p[:, 1], lw=1, color=colors.get(n, "k"),
                label=n if len(paths) <= 12 else None)
        ax.plot(p[0, 0], p[0, 1], "o", ms=5, color=colors.get(n, "k"))
        ax.plot(p[-1, 0], p[-1, 1], "s", ms=5, color=colors.get(n, "k"))
    m = 0.2 + (world.wall_thickness_m if world.wall_height_m > 0 else 0.0)
    ax.set_xlim(-hx - m, hx + m)
    ax.set_ylim(-hy - m, hy + m)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title + "  (o start, \u25a1 end)")
    handles = [Rectangle((0, 0), 1, 1, fc="0.7", ec="0.45", label="furniture"),
               Rectangle((0, 0), 1, 1, fill=False, ec="0.45",
                         label=f"above {ROBOT_TOP_M:.2f} m (passed under)")]
    ax.legend(handles=ax.get_legend_handles_labels()[0][:13] + handles, loc="upper right",
              fontsize=7, framealpha=0.8)
    return save(fig, path)
