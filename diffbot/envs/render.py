"""``render_mode="rgb_array"``: a top-down view of the room, drawn with OpenCV.

North up (+y up, +x right, the world frame as seen from above), ``PX_PER_M`` pixels per
metre (the view fits ``MAX_SIDE_PX``): the floor, the static objects in their colours (the
ones the robot passes under, table tops, paler), each robot's footprint circle (the
contact test's, :mod:`diffbot.envs.geometry`) with a heading line, each goal as a ring of
the goal radius with a dot at its centre, and each robot's latest lidar rays. Ground truth
throughout: what the reward is judged on, not what the policy sees.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from plant.footprint import FOOTPRINT_RADIUS_M, ROBOT_TOP_M, bottom

from .geometry import Footprints

MAX_SIDE_PX = 480
FLOOR = (235, 235, 228)
WALL = (60, 60, 60)
RAY = (255, 170, 170)
HIT = (220, 40, 40)
#: robots in turn: blue, orange, purple, teal ... (RGB)
ROBOT_COLOURS = [(30, 90, 220), (240, 130, 20), (150, 60, 190), (20, 160, 160),
                 (200, 50, 120), (110, 110, 30)]
GOAL = (20, 170, 60)


class TopDown:
    """The static room drawn once; :meth:`frame` draws robots, goals and rays on a copy."""

    def __init__(self, spec, max_side_px: int = MAX_SIDE_PX) -> None:
        fx, fy = (float(v) for v in spec.floor_size_m)
        self.scale = max_side_px / max(fx, fy)              # px per m
        self.w, self.h = int(round(fx * self.scale)), int(round(fy * self.scale))
        self.half = (fx / 2, fy / 2)
        self.lidar = {r.name: r.sensors.lidar for r in spec.robots}
        img = np.empty((self.h, self.w, 3), np.uint8)
        img[:] = FLOOR
        for o in spec.objects:
            if not o.static:
                continue
            colour = np.array(o.color[:3], float) * 255
            if bottom(o) >= ROBOT_TOP_M:                    # passed under: pale
                colour = 0.35 * colour + 0.65 * np.array(FLOOR)
            colour = tuple(int(c) for c in colour)
            x, y, yaw = o.pose[0], o.pose[1], o.pose[3] if len(o.pose) > 3 else 0.0
            if o.shape == "box":
                hx, hy = o.size[0] / 2, o.size[1] / 2
                c, s = math.cos(yaw), math.sin(yaw)
                corners = [(x + c * a - s * b, y + s * a + c * b)
                           for a, b in ((hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy))]
                cv2.fillPoly(img, [self.px_array(corners)], colour, cv2.LINE_AA)
            else:
                cv2.circle(img, self.px(x, y), self.length(o.size[0]), colour, -1, cv2.LINE_AA)
        cv2.rectangle(img, (0, 0), (self.w - 1, self.h - 1), WALL, 3)
        self.background = img

    # ---------------------------------------------------------------- coordinates
    def px(self, x: float, y: float) -> tuple[int, int]:
        """The pixel (column, row) of world point (x, y)."""
        return (int(round((x + self.half[0]) * self.scale)),
                int(round((self.half[1] - y) * self.scale)))

    def px_array(self, pts) -> np.ndarray:
        return np.array([self.px(x, y) for x, y in pts], np.int32)

    def length(self, m: float) -> int:
        return max(1, int(round(m * self.scale)))

    # ---------------------------------------------------------------- frame
    def frame(self, poses: dict, goals: dict | None = None, scans: dict | None = None,
              goal_radius_m: float = 0.3) -> np.ndarray:
        """``poses``: robot -> true (x, y, yaw); ``goals``: robot -> (x, y); ``scans``:
        robot -> its latest LaserScan message (rays drawn from the robot's true pose)."""
        img = self.background.copy()
        names = list(poses)
        for name, scan in (scans or {}).items():
            if scan is not None and name in poses and self.lidar.get(name) is not None:
                self._rays(img, self.lidar[name], poses[name], scan)
        for i, name in enumerate(names):
            g = (goals or {}).get(name)
            if g is not None:
                colour = GOAL if len(names) == 1 else ROBOT_COLOURS[i % len(ROBOT_COLOURS)]
                cv2.circle(img, self.px(*g), self.length(goal_radius_m), colour, 2, cv2.LINE_AA)
                cv2.circle(img, self.px(*g), 4, colour, -1, cv2.LINE_AA)
        for i, name in enumerate(names):
            x, y, yaw = poses[name]
            colour = ROBOT_COLOURS[i % len(ROBOT_COLOURS)]
            centre = Footprints.centre(x, y, yaw)
            cv2.circle(img, self.px(*centre), self.length(FOOTPRINT_RADIUS_M), colour, -1,
                       cv2.LINE_AA)
            tip = (x + 1.2 * FOOTPRINT_RADIUS_M * math.cos(yaw),
                   y + 1.2 * FOOTPRINT_RADIUS_M * math.sin(yaw))
            cv2.line(img, self.px(x, y), self.px(*tip), (255, 255, 255), 2, cv2.LINE_AA)
        return img

    def _rays(self, img: np.ndarray, lidar, pose, scan) -> None:
        x, y, yaw = pose
        c, s = math.cos(yaw), math.sin(yaw)
        ox, oy = x + c * lidar.mount_x_m - s * lidar.mount_y_m, y + s * lidar.mount_x_m + c * lidar.mount_y_m
        r = np.asarray(scan.ranges, float)
        hit = np.isfinite(r) & (r < scan.range_max)
        r = np.where(np.isfinite(r), np.minimum(r, scan.range_max), scan.range_max)
        a = yaw + lidar.mount_yaw_rad + scan.angle_min + scan.angle_increment * np.arange(len(r))
        ends = np.stack([ox + r * np.cos(a), oy + r * np.sin(a)], 1)
        o = self.px(ox, oy)
        for (ex, ey), h in zip(ends, hit):
            p = self.px(ex, ey)
            cv2.line(img, o, p, RAY, 1)
            if h:
                cv2.circle(img, p, 2, HIT, -1)


def beside(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """``right`` scaled (whole factors, nearest pixel) to about ``left``'s height and put to
    its right, on a white strip if shorter."""
    k = max(1, left.shape[0] // right.shape[0])
    big = np.repeat(np.repeat(right, k, 0), k, 1)
    h = max(left.shape[0], big.shape[0])
    out = np.full((h, left.shape[1] + big.shape[1], 3), 255, np.uint8)
    out[:left.shape[0], :left.shape[1]] = left
    out[:big.shape[0], left.shape[1]:] = big
    return out
