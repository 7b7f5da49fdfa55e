"""Figures of the sensor experiments (the study's Figures 4, 5, 9, 10 and 11).

Plain functions: data in, PNG path out. Units on every axis; frames as everywhere in
the project (x forward, y left, angles counter-clockwise, rad in data, degrees only
on polar tick labels).
"""
from __future__ import annotations

import math

import numpy as np

from ..analysis.plots import plt, save


def save_with_suptitle(fig, path: str, title: str) -> str:
    """Like :func:`diffbot.analysis.plots.save`, leaving room at the top for a figure title."""
    fig.suptitle(title, fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# ------------------------------------------------------------------ Figure 4
def covariance_ellipse(ax, mean, cov, k: float, **kw) -> None:
    """The k-sigma ellipse of a 2-D Gaussian with covariance ``cov`` around ``mean``."""
    from matplotlib.patches import Ellipse
    vals, vecs = np.linalg.eigh(np.asarray(cov, dtype=float))
    vals = np.clip(vals, 0.0, None)
    if vals.max() <= 0.0:
        return
    angle = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))      # major axis
    ax.add_patch(Ellipse(mean, 2 * k * math.sqrt(vals[1]), 2 * k * math.sqrt(vals[0]),
                         angle=angle, fill=False, **kw))


def plot_endpoints(ends: np.ndarray, start: tuple[float, float, float], ideal: tuple[float, float],
                   path: str, title: str) -> str:
    """End positions of repeated straight runs (GPS), their mean and 1σ/2σ ellipses."""
    fig, ax = plt.subplots(figsize=(7, 6))
    mean = ends.mean(axis=0)
    cov = np.cov(ends.T) if len(ends) > 1 else np.zeros((2, 2))
    ax.plot(ends[:, 0], ends[:, 1], "o", ms=4, color="tab:blue", alpha=0.7,
            label=f"end positions (GPS), n={len(ends)}")
    ax.plot(*mean, "+", ms=14, mew=2.5, color="tab:red", label="mean")
    covariance_ellipse(ax, mean, cov, 1.0, color="tab:red", lw=1.5)
    covariance_ellipse(ax, mean, cov, 2.0, color="tab:red", lw=1.2, ls="--")
    ax.plot([], [], "-", color="tab:red", label="1σ ellipse")
    ax.plot([], [], "--", color="tab:red", label="2σ ellipse")
    ax.plot(*ideal, "x", ms=10, mew=2, color="black", label="ideal end (no noise, no slip)")
    ax.set_xlabel("x [m] (world, start heading = +x)")
    ax.set_ylabel("y [m] (world)")
    ax.set_title(title, fontsize=10)
    ax.ticklabel_format(useOffset=False)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    std = np.sqrt(np.diag(cov))
    ax.text(0.02, 0.02, f"mean = ({mean[0]:.4f}, {mean[1]:.4f}) m\n"
                        f"std  = ({std[0] * 1e3:.2f}, {std[1] * 1e3:.2f}) mm\n"
                        f"start = ({start[0]:.2f}, {start[1]:.2f}) m",
            transform=ax.transAxes, fontsize=8, family="monospace", va="bottom",
            bbox=dict(facecolor="white", alpha=0.8, edgecolor="0.8"))
    return save(fig, path)


# ------------------------------------------------------------------ Figure 5
def _footprint(ax, obj: dict, in_plane: bool) -> None:
    from matplotlib.patches import Circle, Polygon
    x, y, _, yaw = obj["pose"]
    color = obj.get("color", (0.6, 0.6, 0.6))
    style = dict(facecolor=color, edgecolor="black", lw=0.6, alpha=0.85) if in_plane else \
        dict(facecolor=color, edgecolor="0.3", lw=0.6, alpha=0.25, ls="--")
    if obj["shape"] == "box":
        lx, ly = obj["size"][0] / 2, obj["size"][1] / 2
        c, s = math.cos(yaw), math.sin(yaw)
        pts = [(x + c * px - s * py, y + s * px + c * py)
               for px, py in ((lx, ly), (-lx, ly), (-lx, -ly), (lx, -ly))]
        ax.add_patch(Polygon(pts, closed=True, **style))
    else:
        ax.add_patch(Circle((x, y), obj["size"][0], **style))


def z_extent(obj: dict) -> tuple[float, float]:
    """Lowest and highest z of an object from ``sim/info`` (m)."""
    z = obj["pose"][2]
    h = obj["size"][2] / 2 if obj["shape"] == "box" else \
        obj["size"][1] / 2 if obj["shape"] == "cylinder" else obj["size"][0]
    return z - h, z + h


def draw_room(ax, info: dict, plane_z: float | None = None) -> None:
    """The world from above: floor, walls and furniture footprints (objects that cross
    the scan plane solid, the others faded and dashed)."""
    from matplotlib.patches import Rectangle
    lx, ly = info["floor_size_m"]
    ax.add_patch(Rectangle((-lx / 2, -ly / 2), lx, ly, facecolor="0.97", edgecolor="0.5", lw=1))
    labelled: list[tuple[float, float]] = []
    for obj in sorted(info["objects"], key=lambda o: -_area(o)):
        if obj["name"] == "floor":
            continue
        lo, hi = z_extent(obj)
        in_plane = plane_z is None or lo <= plane_z <= hi
        _footprint(ax, obj, in_plane)
        x, y = obj["pose"][0], obj["pose"][1]
        # one label per piece of furniture: skip parts centred near a labelled one
        if obj["name"].startswith("wall") or not in_plane or _area(obj) < 0.05 or \
                any(math.hypot(x - px, y - py) < 0.5 for px, py in labelled):
            continue
        labelled.append((x, y))
        ax.annotate(obj["name"].replace("_", " "), (x, y), fontsize=6, ha="center",
                    va="center", color="0.1",
                    bbox=dict(facecolor="white", alpha=0.65, edgecolor="none", pad=0.8))


def _area(obj: dict) -> float:
    if obj["shape"] == "box":
        return obj["size"][0] * obj["size"][1]
    return math.pi * obj["size"][0] ** 2


def draw_robot(ax, x: float, y: float, yaw: float, color="tab:blue") -> None:
    from matplotlib.patches import Polygon
    c, s = math.cos(yaw), math.sin(yaw)
    # chassis 0.40 x 0.26 m, centre 5 cm behind the axle (plant/robot.py)
    pts = [(x + c * px - s * py, y + s * px + c * py)
           for px, py in ((0.15, 0.13), (-0.25, 0.13), (-0.25, -0.13), (0.15, -0.13))]
    ax.add_patch(Polygon(pts, closed=True, facecolor=color, edgecolor="black", lw=0.8,
                         alpha=0.9, zorder=5))
    ax.annotate("", (x + 0.35 * c, y + 0.35 * s), (x, y), zorder=6,
                arrowprops=dict(arrowstyle="->", color="black", lw=1.5))


def polar_scan(ax, angles, series, rmax: float | None = None, title: str = "") -> None:
    """Half-disc polar plot of scans: 0 rad = straight ahead (right), counter-clockwise
    positive (left), as in the top view. ``series``: (ranges, style dict) pairs."""
    for ranges, style in series:
        r = np.where(np.isfinite(ranges), ranges, np.nan)
        ax.plot(angles, r, **style)
    ax.set_thetamin(-90)
    ax.set_thetamax(90)
    if rmax is not None:
        ax.set_rmax(rmax)
    ax.set_rlabel_position(-80)
    ax.grid(True, alpha=0.4)
    ax.set_title(f"{title}\nbearing 0° = ahead, + = left; radius = range [m]", fontsize=9,
                 pad=14)


def plot_lidar(info: dict, robot_xy_yaw, sensor_xy, plane_z: float, angles, ranges,
               path: str, title: str) -> str:
    """Figure 5: the room from above with the rays and their hits, beside the polar scan."""
    x, y, yaw = robot_xy_yaw
    fig = plt.figure(figsize=(13, 6))
    gs = fig.add_gridspec(1, 2, width_ratios=[1.3, 1])
    ax = fig.add_subplot(gs[0])
    draw_room(ax, info, plane_z)
    sx, sy = sensor_xy
    world_a = yaw + np.asarray(angles)
    r = np.asarray(ranges)
    ok = np.isfinite(r)
    hx, hy = sx + r[ok] * np.cos(world_a[ok]), sy + r[ok] * np.sin(world_a[ok])
    for px, py in zip(hx, hy):
        ax.plot([sx, px], [sy, py], "-", color="tab:orange", lw=0.3, alpha=0.5)
    ax.plot(hx, hy, ".", color="tab:red", ms=3, label="lidar hits", zorder=7)
    draw_robot(ax, x, y, yaw)
    ax.plot([], [], "-", color="tab:orange", label="rays")
    ax.plot([], [], "s", color="tab:blue", label="robot (arrow = heading)")
    ax.plot([], [], "s", color="0.6", alpha=0.3, label="above/below scan plane")
    lx, ly = info["floor_size_m"]
    ax.set_xlim(-lx / 2 - 0.2, lx / 2 + 0.2)
    ax.set_ylim(-ly / 2 - 0.2, ly / 2 + 0.2)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{info.get('world', 'world')} from above; scan plane z = {plane_z:.2f} m",
                 fontsize=10)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.09), ncol=4,
              framealpha=0.9)
    ax2 = fig.add_subplot(gs[1], projection="polar")
    polar_scan(ax2, angles, [(r, dict(color="tab:blue", lw=1.5, label="range"))],
               title="scan (polar)")
    return save_with_suptitle(fig, path, title)


# ------------------------------------------------------------------ Figure 9
def plot_noisy_lidar(angles, clean, noisy, path: str, title: str) -> str:
    """Figure 9: noiseless (blue) and noisy (orange) scans on one polar plot; a second
    panel zooms to the room's scale."""
    fig = plt.figure(figsize=(10, 6))
    fin = np.isfinite(clean)
    room = float(np.max(clean[fin])) * 1.15 if fin.any() else None
    for i, (rmax, sub) in enumerate(((None, "full range"),
                                     (room, f"zoom: 0-{room:.1f} m (room scale)"))):
        ax = fig.add_subplot(1, 2, i + 1, projection="polar")
        polar_scan(ax, angles, [(noisy, dict(color="tab:orange", lw=0.9, label="noisy")),
                                (clean, dict(color="tab:blue", lw=1.8, label="noiseless"))],
                   rmax=rmax, title=sub)
        ax.legend(loc="upper left", fontsize=8, bbox_to_anchor=(0.62, 1.0))
    return save_with_suptitle(fig, path, title)


# ------------------------------------------------------------------ Figure 11
def plot_camera_compare(clean: np.ndarray, noisy: np.ndarray, path: str, title: str,
                        labels=("noiseless", "noisy")) -> str:
    """Figure 8 / 11 side by side, pixels upscaled (nearest neighbour)."""
    h, w = clean.shape[:2]
    fig, axes = plt.subplots(1, 2, figsize=(12, 12 * h / w / 2 + 1.0))
    for ax, img, lab in zip(axes, (clean, noisy), labels):
        ax.imshow(img, interpolation="nearest")
        ax.set_title(lab, fontsize=10)
        ax.set_xlabel("u [px]")
        ax.set_ylabel("v [px]")
    return save_with_suptitle(fig, path, title)
