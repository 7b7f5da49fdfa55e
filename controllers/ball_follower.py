"""Follow a leader by tracking the green ball on its back bumper with the camera.

Reads only its own camera (``camera/image_raw``, ``camera/camera_info``). Each new frame:
HSV threshold for green, the largest contour, ``cv2.minEnclosingCircle``; the
distance from the apparent radius through the pinhole model (ball radius given,
focal length and principal point from CameraInfo); proportional steering that
keeps the ball centred; PI speed control that holds the target distance; speed
and turn limits. When the ball is lost it stops and turns toward where it was
last seen. Its estimate goes out on ``follower/debug`` so a user can see what it sees.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import cv2
import numpy as np

from bus import codec
from bus.cliargs import nonneg_float, positive_float
from bus.controller import Twist
from bus.node import node_arg_parser, run_controller

#: The ball's edge beyond minEnclosingCircle's radius of the pixel contour, px.
EDGE_OFFSET_PX = 0.2

#: Layout of the ``follower/debug`` message (std_msgs/Float64MultiArray).
DEBUG_FIELDS = ("found", "u_px", "v_px", "radius_px", "distance_m", "bearing_rad")


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


def detect_ball(rgb: np.ndarray, p: DetectorParams = DetectorParams()) -> Detection | None:
    """The largest vivid-green blob of an RGB image as a circle, or None."""
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    mask = cv2.inRange(hsv, (p.hue_range[0], p.min_saturation, p.min_value),
                       (p.hue_range[1], 255, 255))
    if p.open_kernel > 1:
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN,
                                np.ones((p.open_kernel, p.open_kernel), np.uint8))
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return None
    c = max(contours, key=cv2.contourArea)
    (u, v), r = cv2.minEnclosingCircle(c)
    if r < p.min_radius_px:
        return None
    # The contour runs through the centres of the boundary pixels, inside the ball's
    # edge; measured on rendered frames (4-13 px radius) the edge is 0.2 px further out.
    return Detection(float(u), float(v), float(r) + EDGE_OFFSET_PX)


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
        return r / np.linalg.norm(r)
    r1 = ray(det.u - det.radius * eu, det.v - det.radius * ev)
    r2 = ray(det.u + det.radius * eu, det.v + det.radius * ev)
    half = 0.5 * math.acos(max(-1.0, min(1.0, float(r1 @ r2))))
    centre = r1 + r2
    distance = ball_radius_m / math.sin(max(half, 1e-9))
    return distance, -math.atan2(centre[0], centre[2])


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
        self.integral = 0.0
        self.last_t: float | None = None
        self.last_frame: int | None = None
        self.last_bearing = 0.0
        self.command = Twist()
        self.lost_frames = 0
        self.frames = 0

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
        det = detect_ball(rgb, self.detector)
        if det is None:
            self.lost_frames += 1
            self.integral = 0.0
            self.command = Twist(0.0, math.copysign(self.search, self.last_bearing or 1.0))
            debug = (0.0, math.nan, math.nan, math.nan, math.nan, math.nan)
        else:
            dist, bearing = locate_ball(det, fx, fy, cx, cy, self.ball_radius)
            err = dist - self.target
            self.integral = max(-0.5, min(0.5, self.integral + err * dt))
            v = self.kp * err + self.ki * self.integral
            v = max(-0.5 * self.v_max, min(self.v_max, v))
            w = max(-self.w_max, min(self.w_max, self.k_turn * bearing))
            self.last_bearing = bearing
            self.command = Twist(v, w)
            debug = (1.0, det.u, det.v, det.radius, dist, bearing)
        return {"cmd": self.command, "follower/debug": debug_message(debug)}


def debug_message(values) -> object:
    T = codec.T
    layout = T["std_msgs/msg/MultiArrayLayout"](
        dim=[T["std_msgs/msg/MultiArrayDimension"](label=",".join(DEBUG_FIELDS),
                                                    size=len(DEBUG_FIELDS), stride=len(DEBUG_FIELDS))],
        data_offset=0)
    return T["std_msgs/msg/Float64MultiArray"](layout=layout,
                                               data=np.asarray(values, dtype=np.float64))


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
