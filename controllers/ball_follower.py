"""Follow a leader by tracking the green ball on its back bumper with the camera.

Reads only its own camera (``camera/image_raw``, ``camera/camera_info``). Each new frame:
the image noise is estimated from the frame itself and, when it is strong, the frame is
smoothed before the HSV threshold for green (a noisy pixel's hue and saturation are
meaningless, its neighbourhood's average is not); the largest round blob (its contour
fills most of its ``cv2.minEnclosingCircle``) is the ball, sized by that circle, or on a
smoothed frame by a least-squares ellipse through its contour; the distance follows from
its apparent radius through the pinhole model (ball radius given,
focal length and principal point from CameraInfo). The distance is filtered over time
(an alpha-beta filter: distance and its rate) and a measurement far from the prediction
is not believed. Proportional steering keeps the ball centred; PI speed control holds the
target distance, within a speed limit that shrinks with the share of recent frames that
gave no believable ball (it slows down when unsure). When no believable ball has come for
``LOST_AFTER_FRAMES`` frames it stops, says so in its log, and turns toward where it was
last seen; after ``SEARCH_S`` more it stands still until the ball is back. Its estimate
goes out on ``follower/debug`` so a user can see what it sees.
"""
from __future__ import annotations

import ctypes
import logging
import math
import sys
from collections import deque
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from bus import codec
from bus.cliargs import nonneg_float, positive_float
from bus.controller import Twist
from bus.node import node_arg_parser, run_controller
from controllers.kernels import function

#: The ball's edge beyond minEnclosingCircle's radius of the pixel contour, px.
EDGE_OFFSET_PX = 0.2

#: Layout of the ``follower/debug`` message (std_msgs/Float64MultiArray). ``found`` is 1
#: for a frame whose ball was believed; ``distance_m`` is the filtered distance.
DEBUG_FIELDS = ("found", "u_px", "v_px", "radius_px", "distance_m", "bearing_rad")

#: frames without a believable ball after which the follower stops and searches
LOST_AFTER_FRAMES = 5
#: how long it turns toward the ball's last bearing before it stands still, s
SEARCH_S = 3.0
#: frames the confidence (the share of believable ones) is judged over
CONFIDENCE_FRAMES = 12

log = logging.getLogger("ball_follower")


@dataclass
class Detection:
    u: float          # centre, px (x to the right)
    v: float          # centre, px (y down)
    radius: float     # apparent radius, px


@dataclass
class DetectorParams:
    hue_range: tuple[int, int] = (45, 75)      # OpenCV hue 0..180; pure green is 60
    min_saturation: int = 150                  # 0..255: only vivid green
    min_value: int = 60
    min_radius_px: float = 1.5
    open_kernel: int = 3                       # morphological opening against speckle noise
    #: estimated noise std (0..255) from which the frame is smoothed before the threshold
    #: by a Gaussian of 3 px, and from which by one of 5 px (below: as the camera gives it)
    smooth_from_std: tuple[float, float] = (15.0, 35.0)
    #: a blob's contour area over its enclosing circle's: a ball fills 0.84-1 of it;
    #: noise blobs and other shapes less (a blob cut by the image's border is let through)
    min_fill: float = 0.6


def image_noise_std(rgb: np.ndarray) -> float:
    """The std of per-pixel noise in an image (0..255), estimated from the frame alone.

    The median absolute difference of horizontally neighbouring pixels: a rendered
    frame's neighbours are mostly equal, so the median is the noise's (for Gaussian noise
    of std s the difference has std s*sqrt(2), its median absolute value 0.674 of that).
    """
    # every 4th row of one channel: ~4,800 differences, 2 % precision
    g = rgb[::4, :, 1]
    if rgb.dtype != np.uint8 or g.shape[1] < 2 or g.shape[0] == 0:
        d = np.abs(np.diff(g.astype(np.int16), axis=1))
        return float(np.median(d)) / (0.6745 * math.sqrt(2.0))
    # a uint8 frame's differences are 0..255: their median (np.median's value: the middle
    # one, or the mean of the two middle ones) from their histogram, in C (vision.c)
    out = (ctypes.c_int64 * 2)()
    h, w = rgb.shape[:2]
    _vision("controller_diff_median", 7)(_address(rgb) + rgb.strides[2], h, w, rgb.strides[0],
                                         rgb.strides[1], 4, ctypes.addressof(out))
    return out[0] / 2 / (0.6745 * math.sqrt(2.0))


def _vision(name: str, nargs: int):
    """controllers/kernels/vision.c's ``name``."""
    return function(name, ("controller_vision_abi", 1), nargs)


def _address(a: np.ndarray) -> int:
    return a.__array_interface__["data"][0]


@lru_cache(maxsize=8)
def _square(k: int) -> np.ndarray:
    """The k x k structuring element of the detector's opening (made once)."""
    return np.ones((k, k), np.uint8)


def detect_ball(rgb: np.ndarray, p: DetectorParams = DetectorParams(),
                noise_std: float | None = None) -> Detection | None:
    """The largest round vivid-green blob of an RGB image as a circle, or None.
    ``noise_std``: the image's noise if known (else estimated, :func:`image_noise_std`)."""
    if noise_std is None:
        noise_std = image_noise_std(rgb)
    smooth = noise_std >= p.smooth_from_std[0]
    if smooth:
        k = 3 if noise_std < p.smooth_from_std[1] else 5
        rgb = cv2.GaussianBlur(rgb, (k, k), 0)
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    mask = cv2.inRange(hsv, (p.hue_range[0], p.min_saturation, p.min_value),
                       (p.hue_range[1], 255, 255))
    h, w = mask.shape
    # Only the rectangle round the mask's pixels is opened and searched, with a margin of
    # the opening's size: outside it the mask is empty and stays so (an opening only takes
    # pixels away), and within the margin the result is the whole frame's (the opening
    # sees only empty pixels beyond the rectangle either way, findContours a border of
    # them). The contours come back in the frame's coordinates and order.
    x0, y0, bw, bh = cv2.boundingRect(mask)
    if bw == 0:
        return None
    m = max(p.open_kernel, 1)
    x0, y0, x1, y1 = max(x0 - m, 0), max(y0 - m, 0), min(x0 + bw + m, w), min(y0 + bh + m, h)
    if (x0, y0, x1, y1) != (0, 0, w, h):
        mask = np.ascontiguousarray(mask[y0:y1, x0:x1])
    if p.open_kernel > 1:
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, _square(p.open_kernel))
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE,
                                   offset=(x0, y0))
    for c in sorted(contours, key=cv2.contourArea, reverse=True)[:3]:
        (u, v), r = cv2.minEnclosingCircle(c)
        if r < p.min_radius_px:
            return None                 # (the rest are smaller still)
        x, y, bw, bh = cv2.boundingRect(c)
        cut = x <= 0 or y <= 0 or x + bw >= w or y + bh >= h
        # (the contour runs through the boundary pixels' centres: half a pixel inside)
        if not cut and cv2.contourArea(c) < p.min_fill * math.pi * max(r - 0.5, 0.5) ** 2:
            continue
        if smooth and not cut and len(c) >= 5:
            # A smoothed frame's contour is ragged: the least-squares ellipse through all
            # of it (its major axis, as the enclosing circle's) rather than the circle
            # round its farthest points. On the follow scenario's frames with noise std
            # 51 its distance is off by +0.013 m on average (0.031 m std); the enclosing
            # circle's by -0.032 m.
            (u, v), axes, _ = cv2.fitEllipse(c)
            r = max(axes) / 2
        # The contour runs through the centres of the boundary pixels, inside the ball's
        # edge; measured on rendered frames (4-13 px radius) the edge is 0.2 px further out.
        return Detection(float(u), float(v), float(r) + EDGE_OFFSET_PX)
    return None


def distance_from_radius(radius_px: float, focal_px: float, ball_radius_m: float) -> float:
    """Centre distance of a sphere seen on the optical axis with an image radius of
    ``radius_px`` (pinhole model: the silhouette's half-angle is asin(R/d), imaged at f*tan)."""
    return ball_radius_m / math.sin(math.atan(radius_px / focal_px))


def locate_ball(det: Detection, fx: float, fy: float, cx: float, cy: float,
                ball_radius_m: float) -> tuple[float, float]:
    """(distance m, bearing rad, left positive) of the ball's centre from a detection.

    Off the optical axis a sphere images as an ellipse stretched along the line from
    the principal point; ``minEnclosingCircle`` returns that ellipse's major axis. The
    rays through the two ends of the major axis are the silhouette cone's edges, so the
    angle between them is exactly twice the half-angle asin(R/d), and their bisector
    points at the centre — no small-angle or on-axis approximation.
    """
    du, dv = det.u - cx, det.v - cy
    n = math.hypot(du, dv)
    eu, ev = (du / n, dv / n) if n > 1e-9 else (1.0, 0.0)

    def ray(u: float, v: float) -> np.ndarray:
        r = np.array([(u - cx) / fx, (v - cy) / fy, 1.0])
        return r / math.sqrt(r.dot(r))        # (np.linalg.norm(r), without its checks)
    r1 = ray(det.u - det.radius * eu, det.v - det.radius * ev)
    r2 = ray(det.u + det.radius * eu, det.v + det.radius * ev)
    half = 0.5 * math.acos(max(-1.0, min(1.0, float(r1 @ r2))))
    centre = r1 + r2
    distance = ball_radius_m / math.sin(max(half, 1e-9))
    return distance, -math.atan2(centre[0], centre[2])


class DistanceFilter:
    """An alpha-beta filter of the ball's distance (m) and its rate (m/s) over frames.

    A measurement more than ``gate_m`` from the prediction is not believed (a blob
    of noise, a mis-sized ball), unless ``reset_after`` such come in a row: then the
    ball did move, and the filter starts again from the measurement."""

    def __init__(self, alpha: float = 0.4, beta: float = 0.05, gate_m: float = 0.15,
                 reset_after: int = 4) -> None:
        self.alpha, self.beta, self.gate, self.reset_after = alpha, beta, gate_m, reset_after
        self.d: float | None = None
        self.rate = 0.0
        self.doubted = 0
        self.rejected = 0

    def predict(self, dt: float) -> float | None:
        return None if self.d is None else self.d + self.rate * dt

    def update(self, measured: float, dt: float) -> bool:
        """Take a measurement ``dt`` s after the last; whether it was believed."""
        pred = self.predict(dt)
        e = 0.0 if pred is None else measured - pred
        if pred is None or abs(e) > self.gate and self.doubted + 1 >= self.reset_after:
            self.d, self.rate, self.doubted = measured, 0.0, 0
            return True
        if abs(e) > self.gate:
            self.doubted += 1
            self.rejected += 1
            return False
        self.doubted = 0
        self.d = pred + self.alpha * e
        if dt > 0:
            self.rate = max(-1.0, min(1.0, self.rate + self.beta * e / dt))
        return True

    def coast(self, dt: float) -> None:
        """A frame without a measurement: the prediction stands, the rate decays."""
        if self.d is not None:
            self.d += self.rate * dt
            self.rate *= 0.8


class BallFollower:
    name = "ball_follower"
    inputs = ["camera/image_raw", "camera/camera_info"]

    def __init__(self, target_m: float = 0.65, ball_radius_m: float = 0.06,
                 k_distance: float = 1.5, ki_distance: float = 0.4, k_turn: float = 2.5,
                 max_speed_mps: float = 0.4, max_turn_radps: float = 1.5,
                 search_turn_radps: float = 0.6, detector: DetectorParams | None = None) -> None:
        if min(target_m, ball_radius_m, max_speed_mps, max_turn_radps) <= 0:
            raise ValueError("target distance, ball radius and limits must be positive")
        self.target = target_m
        self.ball_radius = ball_radius_m
        self.kp, self.ki, self.k_turn = k_distance, ki_distance, k_turn
        self.v_max, self.w_max = max_speed_mps, max_turn_radps
        self.search = search_turn_radps
        self.detector = detector or DetectorParams()
        self.filter = DistanceFilter()
        self.integral = 0.0
        self.last_t: float | None = None
        self.last_frame: int | None = None
        self.last_bearing = 0.0
        self.command = Twist()
        self.lost_frames = 0            # frames without a believable ball, in all
        self.lost_run = 0               # ... in a row
        self.lost_episodes = 0          # times it stopped because the ball was gone
        self.lost_since: float | None = None
        self.recent: deque[int] = deque(maxlen=CONFIDENCE_FRAMES)
        self.noise_std: float | None = None   # the camera's noise, estimated (0..255)
        self.frames = 0

    def stats(self) -> dict:
        return {"ball_lost_frames": self.lost_frames, "ball_lost_episodes": self.lost_episodes,
                "ball_doubted_frames": self.filter.rejected,
                "camera_noise_std_estimate": self.noise_std}

    def confidence(self) -> float:
        """The share of recent frames that gave a believable ball (1 before any)."""
        return sum(self.recent) / len(self.recent) if self.recent else 1.0

    def step(self, obs):
        img, info = obs["camera/image_raw"], obs["camera/camera_info"]
        if img is None or info is None:
            return Twist()
        stamp = codec.msg_stamp_ns(img)
        if stamp == self.last_frame:           # no new frame this tick: hold the command
            return self.command
        self.last_frame = stamp
        dt = 0.0 if self.last_t is None else max(0.0, obs.t - self.last_t)
        self.last_t = obs.t
        self.frames += 1
        try:
            rgb = codec.image_to_array(img)
        except ValueError:
            return self.command
        fx, fy, cx, cy = float(info.k[0]), float(info.k[4]), float(info.k[2]), float(info.k[5])
        # the camera's noise changes slowly if at all: a running estimate, not each frame's
        est = image_noise_std(rgb)
        self.noise_std = est if self.noise_std is None else 0.9 * self.noise_std + 0.1 * est
        det = detect_ball(rgb, self.detector, self.noise_std)
        believed = False
        if det is not None:
            dist, bearing = locate_ball(det, fx, fy, cx, cy, self.ball_radius)
            believed = self.filter.update(dist, dt)
        else:
            self.filter.coast(dt)
        self.recent.append(int(believed))
        if believed:
            if self.lost_run >= LOST_AFTER_FRAMES:
                log.info("ball found again at t=%.2f s after %.2f s", obs.t,
                         obs.t - (self.lost_since or obs.t))
            self.lost_run = 0
            self.lost_since = None
            dist = self.filter.d
            err = dist - self.target
            self.integral = max(-0.5, min(0.5, self.integral + err * dt))
            # slower the fewer of the recent frames were believable
            v_lim = self.v_max * self.confidence()
            v = self.kp * err + self.ki * self.integral
            v = max(-0.5 * v_lim, min(v_lim, v))
            w = max(-self.w_max, min(self.w_max, self.k_turn * bearing))
            self.last_bearing = bearing
            self.command = Twist(v, w)
            debug = (1.0, det.u, det.v, det.radius, dist, bearing)
        else:
            self.lost_frames += 1
            self.lost_run += 1
            if self.lost_since is None:
                self.lost_since = obs.t
            if self.lost_run < LOST_AFTER_FRAMES:
                # a frame or two without the ball: on, at the speed confidence allows
                c = self.confidence()
                self.command = Twist(self.command.linear * c, self.command.angular)
            else:
                if self.lost_run == LOST_AFTER_FRAMES:
                    self.lost_episodes += 1
                    log.warning("ball lost at t=%.2f s (no believable ball in %d frames): "
                                "stopped, turning toward where it was last seen",
                                self.lost_since, self.lost_run)
                self.integral = 0.0
                searching = obs.t - self.lost_since < SEARCH_S
                if not searching and self.command.angular != 0.0:
                    log.warning("no ball for %.1f s: standing still until it is back", SEARCH_S)
                self.command = Twist(0.0, math.copysign(self.search, self.last_bearing or 1.0)
                                     if searching else 0.0)
            u, v, r = (det.u, det.v, det.radius) if det is not None else (math.nan,) * 3
            debug = (0.0, u, v, r, math.nan, math.nan)
        return {"cmd": self.command, "follower/debug": debug_message(debug)}


def debug_message(values) -> object:
    """The ``follower/debug`` message of ``values`` (``DEBUG_FIELDS``' order)."""
    return codec.T["std_msgs/msg/Float64MultiArray"](layout=_debug_layout(),
                                                     data=np.asarray(values, dtype=np.float64))


@lru_cache(maxsize=1)
def _debug_layout() -> object:
    """The ``follower/debug`` layout, the same in every message: made once."""
    T = codec.T
    return T["std_msgs/msg/MultiArrayLayout"](
        dim=[T["std_msgs/msg/MultiArrayDimension"](label=",".join(DEBUG_FIELDS),
                                                    size=len(DEBUG_FIELDS), stride=len(DEBUG_FIELDS))],
        data_offset=0)


def main(argv=None) -> int:
    p = node_arg_parser("Follow the leader's green ball with the camera.")
    p.set_defaults(robot="follower")
    p.add_argument("--target", type=positive_float, default=0.65, help="distance to hold, m (0.65)")
    p.add_argument("--ball-radius", type=positive_float, default=0.06, help="m (0.06)")
    p.add_argument("--k-distance", type=nonneg_float, default=1.5, help="P gain, (m/s)/m")
    p.add_argument("--ki-distance", type=nonneg_float, default=0.4, help="I gain, (m/s)/(m s)")
    p.add_argument("--k-turn", type=nonneg_float, default=2.5, help="steering gain, (rad/s)/rad")
    p.add_argument("--max-speed", type=positive_float, default=0.4, help="m/s")
    p.add_argument("--max-turn", type=positive_float, default=1.5, help="rad/s")
    args = p.parse_args(argv)
    return run_controller(lambda: BallFollower(args.target, args.ball_radius, args.k_distance,
                                               args.ki_distance, args.k_turn, args.max_speed,
                                               args.max_turn), args, "ball_follower")


if __name__ == "__main__":
    sys.exit(main())
