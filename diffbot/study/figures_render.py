"""Third-person pictures of a world for ``diffbot figures``: the study's Figures 1 and 6.

Both are ray-cast by :func:`plant.camera.third_person` from the shapes the sensors see
(:meth:`plant.sim.Simulation.shapes`) after the robots have stood on the floor for
:data:`SETTLE_S` of simulated time; no bus and no other process is involved.

    robot_views    Figure 1: a robot close up from the eye points of ROBOT_VIEWS
    room_overview  Figure 6: the room from a high corner, with labels for the objects
"""
from __future__ import annotations

import math

import numpy as np

from plant.camera import look_at, third_person
from plant.sim import Simulation
from plant.world import load_world

SETTLE_S = 0.3            # simulated time before the picture: the caster settles on the floor
VIEW_W, VIEW_H = 640, 480


def settled_world(world: str = "living_room") -> Simulation:
    spec = load_world(world)
    sim = Simulation(spec)
    for _ in range(max(1, int(round(SETTLE_S / spec.control_tick_s)))):
        sim.step_tick()
    return sim


def robot_xy_yaw(sim: Simulation, robot: str) -> tuple[float, float, float]:
    st = sim.state(robot)
    return float(st.tf[0, 3]), float(st.tf[1, 3]), float(st.yaw)


#: (label, eye azimuth from the robot's forward axis (rad, CCW), distance m, height m)
ROBOT_VIEWS = (
    ("front left", math.radians(40), 0.95, 0.55),
    ("rear right", math.radians(-140), 0.95, 0.55),
    ("right side, wheel height", math.radians(-90), 0.85, 0.14),
    ("from above, front up", math.radians(180), 0.02, 1.25),
)
ROBOT_HFOV_RAD = 0.9


def robot_views(sim: Simulation, robot: str = "robot1") -> list[tuple[str, np.ndarray]]:
    """``(label, rgb8 VIEW_H x VIEW_W image)`` of ``robot`` seen from each ROBOT_VIEWS eye."""
    x, y, yaw = robot_xy_yaw(sim, robot)
    shapes = sim.shapes()
    out = []
    for label, az, dist, height in ROBOT_VIEWS:
        a = yaw + az
        eye = (x + dist * math.cos(a), y + dist * math.sin(a), height)
        target = (x, y, 0.10)
        up = (math.cos(yaw), math.sin(yaw), 0.0) if height > 1.0 else (0.0, 0.0, 1.0)
        out.append((label, third_person(eye, target, shapes, VIEW_W, VIEW_H, ROBOT_HFOV_RAD,
                                        up=up)))
    return out


#: Figure 6: the eye is above and outside the room's front-left corner (+x, +y; the walls
#: are 0.8 m high), where nothing hides anything
ROOM_EYE = (4.4, 3.7, 3.7)
ROOM_TARGET = (-0.5, -0.35, -0.3)
ROOM_HFOV_RAD = 1.12
ROOM_W, ROOM_H = 1200, 860

#: objects labelled in Figure 6: label -> the object whose top centre the label marks
ROOM_LABELS = {
    "sofa": "sofa_back", "TV": "tv", "coffee table": "coffee_table_top",
    "dining table": "dining_table_top", "chairs": "chair_1_back", "bookshelf": "bookshelf",
    "low shelf": "low_shelf", "plant": "plant_foliage", "lamp": "lamp_shade",
    "footstool": "footstool",
}


def project(eye, target, hfov: float, width: int, height: int, point) -> tuple[float, float] | None:
    """Pixel ``(u, v)`` where :func:`third_person` draws the world ``point`` (None: behind)."""
    m = look_at(eye, target)
    p = m[:3, :3].T @ (np.asarray(point, dtype=float) - m[:3, 3])
    if p[0] <= 1e-6:
        return None
    f = (width / 2) / math.tan(hfov / 2)
    return (width - 1) / 2 - f * p[1] / p[0], (height - 1) / 2 - f * p[2] / p[0]


def room_overview(sim: Simulation) -> tuple[np.ndarray, list[tuple[str, float, float]]]:
    """The room seen from ROOM_EYE (rgb8) and ``(label, u, v)`` for the objects of
    ROOM_LABELS and each robot, at the top centre of each."""
    shapes = sim.shapes()
    img = third_person(ROOM_EYE, ROOM_TARGET, shapes, ROOM_W, ROOM_H, ROOM_HFOV_RAD)
    tops = {}
    for s in shapes:
        half = {"box": lambda sz: sz[2] / 2, "cylinder": lambda sz: sz[1] / 2,
                "sphere": lambda sz: sz[0]}[s.kind](s.size)
        tops[s.name] = (s.pose[0, 3], s.pose[1, 3], s.pose[2, 3] + half)
    points = [(label, tops[name]) for label, name in ROOM_LABELS.items() if name in tops]
    for name in sim.robots:
        x, y, _ = robot_xy_yaw(sim, name)
        points.append((name, (x, y, 0.2)))
    labels = []
    for label, p in points:
        uv = project(ROOM_EYE, ROOM_TARGET, ROOM_HFOV_RAD, ROOM_W, ROOM_H, p)
        if uv is not None and 0 <= uv[0] < ROOM_W and 0 <= uv[1] < ROOM_H:
            labels.append((label, *uv))
    return img, labels


def colour_fraction(img: np.ndarray, rgb01, tol: float = 0.08) -> float:
    """Fraction of pixels that are a lit or shaded version of the colour ``rgb01``: the
    pixel's chromaticity (RGB / sum) within ``tol`` of the colour's."""
    c = np.asarray(rgb01, dtype=float)
    c = c / c.sum()
    px = img.reshape(-1, 3).astype(float)
    s = px.sum(axis=1)
    lit = s > 30
    chroma = px[lit] / s[lit, None]
    return float(np.sum(np.abs(chroma - c).max(axis=1) <= tol)) / len(px)


# ------------------------------------------------------------------ the figure files
def robot_figure(views: list[tuple[str, np.ndarray]], path: str, title: str) -> str:
    """Figure 1: the views of :func:`robot_views` as a 2 x 2 sheet."""
    from ..analysis.plots import plt, save
    n = len(views)
    cols = 2 if n > 1 else 1
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(6.4 * cols * 0.8, 4.8 * rows * 0.8 + 0.5),
                             squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, (label, img) in zip(axes.flat, views):
        ax.imshow(img)
        ax.set_title(label, fontsize=10)
    fig.suptitle(title, fontsize=11)
    return save(fig, path)


def room_figure(img: np.ndarray, labels: list[tuple[str, float, float]], path: str,
                title: str, robots: tuple[str, ...] = ()) -> str:
    """Figure 6: the overview with a label on each object (robots' labels in bold)."""
    from ..analysis.plots import plt, save
    h, w = img.shape[:2]
    fig, ax = plt.subplots(figsize=(w / 100, h / 100 + 0.4))
    ax.imshow(img)
    ax.axis("off")
    for label, u, v in labels:
        bold = label in robots
        ax.annotate(label, (u, v), xytext=(0, 26 if bold else 16), textcoords="offset points",
                    ha="center", fontsize=11 if bold else 9,
                    fontweight="bold" if bold else "normal",
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="0.4", alpha=0.85),
                    arrowprops=dict(arrowstyle="-", color="0.2", lw=0.8))
    ax.set_title(title, fontsize=12)
    return save(fig, path)


def main(argv: list[str] | None = None) -> int:
    """``python -m diffbot.study.figures_render --out DIR``: Figures 1 and 6 and a summary.json."""
    import argparse
    import os
    import sys
    import time

    from bus.jsonio import write_json
    from plant.world import WorldError

    p = argparse.ArgumentParser(prog="python -m diffbot.study.figures_render",
                                description="Third-person renders: the robot close up "
                                            "(Figure 1) and the room (Figure 6).")
    p.add_argument("--out", required=True)
    p.add_argument("--world", default="living_room")
    p.add_argument("--robot", default="robot1")
    args = p.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    t0 = time.monotonic()
    try:
        sim = settled_world(args.world)
        rs = sim.spec.robot(args.robot)
    except (WorldError, KeyError, ValueError) as exc:
        print(f"figures_render: {exc}", file=sys.stderr)
        return 2
    x, y, yaw = robot_xy_yaw(sim, args.robot)
    views = robot_views(sim, args.robot)
    chassis = " x ".join(f"{s:g}" for s in _chassis(sim, args.robot))
    robot_png = robot_figure(
        views, os.path.join(args.out, "robot.png"),
        f"{args.robot} in {args.world}: chassis {chassis} m, "
        f"wheel radius {rs.drive.wheel_radius_m:g} m, wheel separation "
        f"{rs.drive.wheel_separation_m:g} m, rear caster")
    img, labels = room_overview(sim)
    room_png = room_figure(img, labels, os.path.join(args.out, "room.png"),
                           f"{args.world}: {sim.spec.floor_size_m[0]:g} m x "
                           f"{sim.spec.floor_size_m[1]:g} m, walls {sim.spec.wall_height_m:g} m "
                           f"high, seen from above its front-left corner "
                           f"(x toward the TV, y to the left)",
                           robots=tuple(sim.robots))
    robot_px = [colour_fraction(v, rs.color) for _, v in views]
    summary = {
        "world": args.world, "robot": args.robot,
        "robot_pose": [round(x, 6), round(y, 6), round(yaw, 6) + 0.0],
        "robot_color": list(rs.color), "settle_s": SETTLE_S,
        "robot_views": [{"label": lab, "azimuth_rad": az, "distance_m": d, "eye_height_m": hgt}
                        for lab, az, d, hgt in ROBOT_VIEWS],
        "robot_view_size_px": [VIEW_W, VIEW_H], "robot_view_hfov_rad": ROBOT_HFOV_RAD,
        "robot_colour_fraction": robot_px,
        "room_eye_m": list(ROOM_EYE), "room_target_m": list(ROOM_TARGET),
        "room_hfov_rad": ROOM_HFOV_RAD, "room_size_px": [ROOM_W, ROOM_H],
        "floor_size_m": list(sim.spec.floor_size_m), "wall_height_m": sim.spec.wall_height_m,
        "objects": len(sim.spec.objects), "shapes": len(sim.shapes()),
        "wheel_radius_m": rs.drive.wheel_radius_m,
        "wheel_separation_m": rs.drive.wheel_separation_m,
        "files": [os.path.basename(robot_png), os.path.basename(room_png)],
        "wall_time_s": time.monotonic() - t0,
    }
    write_json(os.path.join(args.out, "summary.json"), summary)
    print(f"figures_render: robot.png, room.png in {args.out} "
          f"({summary['wall_time_s']:.1f} s)", file=sys.stderr)
    return 0


def _chassis(sim: Simulation, robot: str) -> tuple[float, ...]:
    for s in sim.shapes():
        if s.owner == robot and s.kind == "box":
            return tuple(s.size)
    return ()


if __name__ == "__main__":
    import sys
    sys.exit(main())
