"""The follow scenario's outputs: tracking distance (the study's Figure 12), CSV, animation.

The true distance is measured from ground truth: the follower's camera centre (its
mount on the follower) to the centre of the leader's green ball (its part pose on
the leader), both placed with the robots' full 3-D poses. Contacts between the two
robots are judged on ground truth with the swarm's footprints
(:mod:`diffbot.analysis.swarm`). Stretches of frames in which the follower believed no
ball (its ``follower/debug``) are reported with how far it drove during them once it had
stopped for them.
"""
from __future__ import annotations

import csv
import math
import os

import cv2
import numpy as np

from bus import codec
from bus.keys import TOPICS, Keys
from controllers.ball_follower import LOST_AFTER_FRAMES
from plant.footprint import footprint_centres

from .bands import BAND_M, FOLLOWER, LEADER, SETTLE_S, TARGET_M, ball_offset, pose_matrix_of
from .swarm import footprint_gap, robot_contacts

ANIMATION_PERIOD_S = 0.4          # one animation frame per 0.4 s of simulated time (played 2x)
BALL_RGB = (25, 215, 40)          # the ball in the animation's top-down view


class FollowAnalysis:
    draws = True

    @staticmethod
    def keys(keys: Keys, spec, world) -> dict[str, str]:
        return {keys.topic(LEADER, "ground_truth"): TOPICS["ground_truth"].msgtype,
                keys.topic(FOLLOWER, "ground_truth"): TOPICS["ground_truth"].msgtype,
                keys.topic(FOLLOWER, "follower/debug"): TOPICS["follower/debug"].msgtype,
                keys.topic(FOLLOWER, "camera/image_raw"): TOPICS["camera/image_raw"].msgtype}

    @staticmethod
    def drawing_keys(keys: Keys) -> set[str]:
        """The keys of :meth:`keys` read only for the figures (the animation's camera
        frames): a run without figures does not subscribe to them, so the camera's 57 kB
        images are not sent to the launcher, nor kept there (all of a 600 s run's: 0.9 GB)."""
        return {keys.topic(FOLLOWER, "camera/image_raw")}

    @staticmethod
    def analyse(observer, keys, spec, world, out, plots: bool = True) -> dict:
        lead = {codec.msg_stamp_ns(m): m for m in observer.messages(keys.topic(LEADER, "ground_truth"))}
        fol = {codec.msg_stamp_ns(m): m for m in observer.messages(keys.topic(FOLLOWER, "ground_truth"))}
        debug = dict(observer.stamped(keys.topic(FOLLOWER, "follower/debug")))
        cam_mount = world.robot(FOLLOWER).sensors.camera.mount_pose()
        ball = ball_offset(world)
        rows = []
        for t in sorted(set(lead) & set(fol)):
            lt, ft = pose_matrix_of(lead[t]), pose_matrix_of(fol[t])
            d = float(np.linalg.norm((lt @ ball)[:3] - (ft @ cam_mount)[:3, 3]))
            dbg = debug.get(t)
            found, est = (dbg.data[0], dbg.data[4]) if dbg is not None else (math.nan, math.nan)
            rows.append((t * 1e-9, d, est, found, lt[0, 3], lt[1, 3], ft[0, 3], ft[1, 3],
                         math.atan2(lt[1, 0], lt[0, 0]), math.atan2(ft[1, 0], ft[0, 0])))
        with open(os.path.join(out, "tracking.csv"), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["t_s", "distance_m", "estimated_distance_m", "ball_found",
                        "leader_x_m", "leader_y_m", "follower_x_m", "follower_y_m"])
            for r in rows:
                w.writerow([f"{v:.9f}" if isinstance(v, float) else v for v in r[:8]])
        if not rows:
            return {"rows": 0}
        a = np.array(rows)
        settled = a[a[:, 0] - a[0, 0] >= SETTLE_S]
        lost = sum(1 for m in debug.values() if m.data[0] == 0.0)
        # (ticks, [leader, follower], x y yaw)
        poses = np.stack([a[:, [4, 5, 8]], a[:, [6, 7, 9]]], axis=1)
        gap = footprint_gap(footprint_centres(poses[..., 0], poses[..., 1], poses[..., 2]), 0, 1)
        frames = 0                      # the animation's frames (none without the figures)
        if plots:
            plot_tracking(a, os.path.join(out, "tracking_distance.png"))
            frames = write_animation(observer, keys, world, a, os.path.join(out, "follow.gif"))
        in_band = settled[:, 1] if len(settled) else a[:, 1]
        return {
            "distance_min_m": float(in_band.min()), "distance_max_m": float(in_band.max()),
            "distance_rms_error_m": float(np.sqrt(np.mean((in_band - TARGET_M) ** 2))),
            "distance_in_band": bool(in_band.min() >= BAND_M[0] and in_band.max() <= BAND_M[1]),
            "settle_s": SETTLE_S, "ball_lost_frames": lost, "frames": len(debug),
            "ball_lost": lost_stretches(debug, a),
            # the robots' footprints as the swarm's collisions judge them: the closest they
            # came (negative: overlapping) and the times they touched
            "robot_contacts": {"count": robot_contacts(gap), "min_gap_m": float(gap.min())},
            "animation_frames": frames, "duration_s": float(a[-1, 0] - a[0, 0]),
        }


def lost_stretches(debug: dict, a: np.ndarray) -> dict:
    """The stretches of at least ``LOST_AFTER_FRAMES`` frames without a believed ball (the
    follower stops for them): how many, the longest (s), whether the run ended in one, and
    how far the follower's base moved in them after the stretch's first
    ``LOST_AFTER_FRAMES`` frames (it should stand or turn on the spot: ~0 m)."""
    stamps = sorted(debug)
    found = [debug[t].data[0] != 0.0 for t in stamps]
    where = {round(r[0] * 1e9): k for k, r in enumerate(a)}
    stretches, start = [], None
    for k, f in enumerate(found + [True]):
        if not f and start is None:
            start = k
        elif f and start is not None:
            if k - start >= LOST_AFTER_FRAMES:
                stretches.append((start, k - 1))
            start = None
    moved = 0.0
    for s, e in stretches:
        rows = [where[t] for t in stamps[s + LOST_AFTER_FRAMES - 1:e + 1] if t in where]
        if len(rows) > 1:
            xy = a[rows[0]:rows[-1] + 1, 6:8]
            moved += float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
    return {"stretches": len(stretches),
            "longest_s": max(((stamps[e] - stamps[s]) * 1e-9 for s, e in stretches), default=0.0),
            "at_end": bool(stretches) and stretches[-1][1] == len(stamps) - 1,
            "moved_while_lost_m": moved}


def plot_tracking(a: np.ndarray, path: str) -> str:
    """Distance against time with the 0.60-0.70 m band shaded (the study's Figure 12)."""
    from .plots import plt, save
    fig, ax = plt.subplots(figsize=(8, 4))
    t = a[:, 0] - a[0, 0]
    ax.axhspan(*BAND_M, color="tab:green", alpha=0.15, label="0.60-0.70 m band")
    ax.axhline(TARGET_M, color="tab:green", lw=0.8, ls="--", label="target 0.65 m")
    ax.axvline(SETTLE_S, color="0.5", lw=0.8, ls=":", label=f"settled after {SETTLE_S:.0f} s")
    ax.plot(t, a[:, 1], color="tab:blue", lw=1.2, label="true distance (ground truth)")
    est = a[:, 2]
    ok = np.isfinite(est)
    ax.plot(t[ok], est[ok], ".", color="tab:orange", ms=2, alpha=0.6,
            label="follower's estimate (ball radius)")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("camera to ball distance [m]")
    ax.set_title("Tracking distance vs time")
    ax.set_ylim(min(0.5, float(np.nanmin(a[:, 1])) - 0.02), max(0.8, float(np.nanmax(a[:, 1])) + 0.02))
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    return save(fig, path)


class TopDown:
    """A fast top-down raster of the room for animation frames (OpenCV, no matplotlib)."""

    def __init__(self, world, size_px: int = 240) -> None:
        lx, ly = world.floor_size_m
        self.scale = size_px / max(lx, ly)
        self.w, self.h = int(lx * self.scale), int(ly * self.scale)
        self.lx, self.ly = lx, ly
        img = np.full((self.h, self.w, 3), 235, np.uint8)
        for o in world.objects:
            color = tuple(int(255 * c) for c in o.color)
            if o.shape == "box":
                self.box(img, o.pose[0], o.pose[1], o.pose[3], o.size[0], o.size[1], color)
            else:
                cv2.circle(img, self.px(o.pose[0], o.pose[1]), max(1, int(o.size[0] * self.scale)),
                           color, -1, cv2.LINE_AA)
        self.background = img

    def px(self, x: float, y: float) -> tuple[int, int]:
        return (int((x + self.lx / 2) * self.scale), int((self.ly / 2 - y) * self.scale))

    def box(self, img, x, y, yaw, sx, sy, color, fill=True) -> None:
        c, s = math.cos(yaw), math.sin(yaw)
        pts = [(x + c * dx - s * dy, y + s * dx + c * dy)
               for dx, dy in ((sx / 2, sy / 2), (-sx / 2, sy / 2), (-sx / 2, -sy / 2), (sx / 2, -sy / 2))]
        poly = np.array([self.px(*p) for p in pts], np.int32)
        if fill:
            cv2.fillConvexPoly(img, poly, color, cv2.LINE_AA)
        else:
            cv2.polylines(img, [poly], True, color, 1, cv2.LINE_AA)

    def frame(self, robots: list[tuple[float, float, float, tuple]], ball_xy=None) -> np.ndarray:
        img = self.background.copy()
        for x, y, yaw, color in robots:
            self.box(img, x - 0.05 * math.cos(yaw), y - 0.05 * math.sin(yaw), yaw, 0.40, 0.36, color)
            tip = (x + 0.3 * math.cos(yaw), y + 0.3 * math.sin(yaw))
            cv2.line(img, self.px(x, y), self.px(*tip), (20, 20, 20), 1, cv2.LINE_AA)
        if ball_xy is not None:
            cv2.circle(img, self.px(*ball_xy), 3, BALL_RGB, -1, cv2.LINE_AA)
        return img


def write_animation(observer, keys, world, a: np.ndarray, path: str) -> int:
    """The follower's camera view beside a top-down view of both robots, as a GIF."""
    from PIL import Image
    images = observer.messages(keys.topic(FOLLOWER, "camera/image_raw"))
    if not images:
        return 0
    td = TopDown(world)
    colors = {LEADER: tuple(int(255 * c) for c in world.robot(LEADER).color),
              FOLLOWER: tuple(int(255 * c) for c in world.robot(FOLLOWER).color)}
    poses = {round(r[0], 6): r for r in a}
    lead = {codec.msg_stamp_ns(m): m for m in observer.messages(keys.topic(LEADER, "ground_truth"))}
    fol = {codec.msg_stamp_ns(m): m for m in observer.messages(keys.topic(FOLLOWER, "ground_truth"))}
    ball = ball_offset(world)
    frames, next_t = [], None
    for img in images:
        t = codec.msg_stamp_ns(img)
        if next_t is not None and t < next_t or t not in lead or t not in fol:
            continue
        next_t = t + int(ANIMATION_PERIOD_S * 1e9)
        lt, ft = pose_matrix_of(lead[t]), pose_matrix_of(fol[t])
        cam = cv2.resize(codec.image_to_array(img), (td.h * 4 // 3, td.h),
                         interpolation=cv2.INTER_NEAREST)
        top = td.frame([(lt[0, 3], lt[1, 3], math.atan2(lt[1, 0], lt[0, 0]), colors[LEADER]),
                        (ft[0, 3], ft[1, 3], math.atan2(ft[1, 0], ft[0, 0]), colors[FOLLOWER])],
                       tuple((lt @ ball)[:2]))
        row = poses.get(round(t * 1e-9, 6))
        label = f"t={t * 1e-9:5.1f} s  d={row[1]:.3f} m" if row is not None else f"t={t * 1e-9:5.1f} s"
        frame = np.hstack([cam, np.full((td.h, 4, 3), 255, np.uint8), top])
        cv2.putText(frame, label, (4, td.h - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1,
                    cv2.LINE_AA)
        frames.append(Image.fromarray(frame).quantize(colors=64, method=Image.Quantize.FASTOCTREE))
    if frames:
        frames[0].save(path, save_all=True, append_images=frames[1:],
                       duration=int(ANIMATION_PERIOD_S * 1000 / 2), loop=0, optimize=False)
    return len(frames)
