"""The study's sensor experiments (``diffbot experiment lidar|noisy-lidar|camera``): one
scan or frame through the bus, without and with the study's noise (Figs. 5, 8, 9, 11)."""
from __future__ import annotations

import math
import os
import sys

import numpy as np

from bus import codec
from plant.world import WorldError, load_world

from .experiment_bus import (ExperimentError, capture)

from .experiments import (_fmt, _pose_set, _write_csv,
                          expected_clipped_std)


# ------------------------------------------------------------------ lidar (Fig. 5)
def _scan_arrays(msg) -> tuple[np.ndarray, np.ndarray]:
    ranges = np.asarray(msg.ranges, dtype=float)
    n = len(ranges)
    angles = np.linspace(float(msg.angle_min), float(msg.angle_max), n) if n > 1 else \
        np.array([float(msg.angle_min)])
    return angles, ranges


def _robot_pose(gt) -> tuple[float, float, float, float]:
    p = gt.pose.pose
    return p.position.x, p.position.y, p.position.z, codec.quaternion_to_yaw(p.orientation)


def _sensor(args, sets: list[str], kind: str):
    """The config of the robot's ``kind`` sensor (lidar, camera) in the world with ``sets``;
    WorldError if it has none."""
    cfg = getattr(load_world(args.world, sets).robot(args.robot).sensors, kind)
    if cfg is None:
        raise WorldError(f"{args.world}: {args.robot} has no {kind}")
    return cfg


def _without_and_with_noise(args, base: list[str], kind: str, noise: str, topic: str):
    """Two captures of ``topic`` from the same pose and seed (plant_noiseless, plant_noisy):
    the ``kind`` sensor (lidar, camera) without noise, then with the ``noise`` table; the
    other sensor off."""
    other = "camera" if kind == "lidar" else "lidar"
    return [capture(args.out, f"plant_{name}", [topic], args.world,
                    [*base, f"robots.{args.robot}.{kind}.noise={table}"], args.seed,
                    disable=(other,), robot=args.robot)
            for name, table in (("noiseless", "{std = 0.0}"), ("noisy", noise))]


def lidar(args) -> dict:
    robot = args.robot
    sets = [f"robots.{robot}.lidar.noise={{std = 0.0}}", *_pose_set(robot, args.pose)]
    cfg = _sensor(args, sets, "lidar")
    print(f"lidar: one scan of {robot} in {args.world} from the bus", file=sys.stderr)
    cap = capture(args.out, "plant", ["scan", "ground_truth"], args.world, sets, args.seed,
                  disable=("camera",), robot=robot)
    angles, ranges = _scan_arrays(cap.obs["scan"])
    _write_csv(os.path.join(args.out, "scan.csv"), ["angle_rad", "range_m"],
               [[_fmt(a), _fmt(r, 6)] for a, r in zip(angles, ranges)])
    x, y, z, yaw = _robot_pose(cap.obs["ground_truth"])
    c, s = math.cos(yaw), math.sin(yaw)
    sx, sy = x + c * cfg.mount_x_m - s * cfg.mount_y_m, y + s * cfg.mount_x_m + c * cfg.mount_y_m
    plane_z = z + cfg.mount_z_m
    from .experiment_plots import plot_lidar
    plot_lidar(cap.info, (x, y, yaw + cfg.mount_yaw_rad), (sx, sy), plane_z, angles, ranges,
               os.path.join(args.out, "lidar.png"),
               f"Lidar ({cfg.num_rays} rays over {math.degrees(cfg.fov_rad):.0f}°, max range "
               f"{cfg.max_range_m:g} m, noiseless) — {robot} at ({x:.2f}, {y:.2f}) m, "
               f"yaw {math.degrees(yaw):.0f}°")
    fin = np.isfinite(ranges)
    return {
        "parameters": {"world": args.world, "robot": robot, "robot_pose": [x, y, yaw],
                       "num_rays": cfg.num_rays, "fov_rad": cfg.fov_rad,
                       "angle_increment_rad": cfg.angle_increment,
                       "max_range_m": cfg.max_range_m, "min_range_m": cfg.min_range_m,
                       "sensor_xy_m": [sx, sy], "scan_plane_z_m": plane_z,
                       "noise": "none (std 0 m)"},
        "rays": int(len(ranges)), "finite_rays": int(fin.sum()),
        "range_min_m": float(np.min(ranges[fin])) if fin.any() else None,
        "range_max_m": float(np.max(ranges[fin])) if fin.any() else None,
        "range_mean_m": float(np.mean(ranges[fin])) if fin.any() else None,
        "scan_stamp_s": cap.obs.t,
    }


# ------------------------------------------------------------------ noisy-lidar (Fig. 9)
def noisy_lidar(args) -> dict:
    robot = args.robot
    base = _pose_set(robot, args.pose)
    cfg = _sensor(args, base, "lidar")
    if args.lidar_noise_std is not None:
        noise_tbl, std = f"{{std = {args.lidar_noise_std!r}}}", args.lidar_noise_std
        form = f"std {std:g} m (given in metres)"
    else:
        noise_tbl = f"{{webots_noise = {args.lidar_noise!r}}}"
        std = args.lidar_noise * cfg.max_range_m
        form = f"Webots noise {args.lidar_noise:g} x maxRange {cfg.max_range_m:g} m = std {std:g} m"
    print(f"noisy-lidar: {form}; two plants (noiseless, noisy), same pose and seed",
          file=sys.stderr)
    clean_cap, noisy_cap = _without_and_with_noise(args, base, "lidar", noise_tbl, "scan")
    angles, clean = _scan_arrays(clean_cap.obs["scan"])
    _, noisy = _scan_arrays(noisy_cap.obs["scan"])
    _write_csv(os.path.join(args.out, "scan_noisy.csv"),
               ["angle_rad", "range_noiseless_m", "range_noisy_m"],
               [[_fmt(a), _fmt(c, 6), _fmt(n, 6)] for a, c, n in zip(angles, clean, noisy)])
    from .experiment_plots import plot_noisy_lidar
    plot_noisy_lidar(angles, clean, noisy, os.path.join(args.out, "noisy_lidar.png"),
                     f"Lidar without (blue) and with (orange) noise: {form}")
    both = np.isfinite(clean) & np.isfinite(noisy)
    resid = (noisy - clean)[both]
    at_min = np.isclose(noisy[both], cfg.min_range_m, atol=1e-6)
    at_max = np.isclose(noisy[both], cfg.max_range_m, atol=1e-4)
    expected = expected_clipped_std(clean[both], std, cfg.min_range_m, cfg.max_range_m) \
        if std > 0 and both.any() else 0.0
    return {
        "parameters": {"world": args.world, "robot": robot,
                       "lidar_noise_webots": None if args.lidar_noise_std is not None
                       else args.lidar_noise,
                       "lidar_noise_std_m": std, "max_range_m": cfg.max_range_m,
                       "min_range_m": cfg.min_range_m, "num_rays": cfg.num_rays},
        "noise_meaning": noise_meaning(form, std, args.lidar_noise_std is not None, cfg, clean,
                                       float(at_min.mean()) if both.any() else 0.0,
                                       float(at_max.mean()) if both.any() else 0.0),
        "rays": int(len(clean)),
        "measured_residual_std_m": float(resid.std()) if resid.size else None,
        "expected_residual_std_with_clipping_m": expected,
        "measured_residual_mean_m": float(resid.mean()) if resid.size else None,
        "fraction_clipped_to_min_range": float(at_min.mean()) if both.any() else 0.0,
        "fraction_clipped_to_max_range": float(at_max.mean()) if both.any() else 0.0,
    }


def noise_meaning(form: str, std: float, in_metres: bool, cfg, clean: np.ndarray,
                  at_min: float, at_max: float) -> str:
    """What the noise the options gave means: a std given in metres is one absolute std on
    every ray; a Webots value is relative to the max range. Then what clipping did."""
    fin = clean[np.isfinite(clean)]
    ranges = f"{fin.min():.1f}-{fin.max():.1f} m" if fin.size else "no finite ranges"
    if in_metres:
        text = (f"{form}: the same Gaussian std on every ray, whatever its range (in Webots' "
                f"terms, relative to the max range {cfg.max_range_m:g} m, "
                f"{std / cfg.max_range_m:.3g}); the ranges in this room are {ranges}")
    else:
        text = (f"{form}. Webots' lidar noise is a Gaussian std relative to maxRange (SICK "
                f"LMS 291: {cfg.max_range_m:g} m): here a std of {std:g} m on ranges that are "
                f"{ranges} in this room")
    clipped = [f"{100 * frac:.0f} % of the rays read the {lim:g} m {what}"
               for frac, lim, what in ((at_min, cfg.min_range_m, "minimum"),
                                       (at_max, cfg.max_range_m, "maximum")) if frac > 0]
    return text + ("; noisy values are clipped to [min, max] range, so "
                   + " and ".join(clipped) if clipped else "; no ray was clipped") + "."


# ------------------------------------------------------------------ camera (Fig. 8/11)
def _save_rgb_png(path: str, rgb: np.ndarray) -> str:
    import cv2
    if not cv2.imwrite(path, cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)):
        raise ExperimentError(f"cannot write {path}")
    return path


def camera(args) -> dict:
    robot = args.robot
    pose = args.pose if args.pose is not None else (0.0, 0.0, -0.6)
    base = _pose_set(robot, pose)
    cfg = _sensor(args, base, "camera")
    if args.camera_noise_std is not None:
        tbl, std = f"{{std = {args.camera_noise_std!r}}}", args.camera_noise_std
        form = f"std {std:g} levels (of 0-255)"
    else:
        tbl, std = f"{{webots_noise = {args.camera_noise!r}}}", args.camera_noise * 255.0
        form = f"Webots noise {args.camera_noise:g} x 255 = std {std:g} levels"
    print(f"camera: {cfg.width}x{cfg.height} from ({pose[0]:g}, {pose[1]:g}, yaw {pose[2]:g}); "
          f"{form}", file=sys.stderr)
    clean_cap, noisy_cap = _without_and_with_noise(args, base, "camera", tbl,
                                                   "camera/image_raw")
    clean = codec.image_to_array(clean_cap.obs["camera/image_raw"])
    noisy = codec.image_to_array(noisy_cap.obs["camera/image_raw"])
    _save_rgb_png(os.path.join(args.out, "camera.png"), clean)
    _save_rgb_png(os.path.join(args.out, "camera_noisy.png"), noisy)
    from .experiment_plots import plot_camera_compare
    plot_camera_compare(clean, noisy, os.path.join(args.out, "camera_compare.png"),
                        f"Camera {cfg.width}x{cfg.height} rgb8 from the bus "
                        f"({robot} at ({pose[0]:g}, {pose[1]:g}) m, yaw {pose[2]:g} rad)",
                        labels=("noiseless (Figure 8)", f"noisy: {form} (Figure 11)"))
    resid = noisy.astype(float) - clean.astype(float)
    mid = (clean >= 96) & (clean <= 160)
    expected = expected_clipped_std(clean.reshape(-1), std, 0.0, 255.0) if std > 0 else 0.0
    return {
        "parameters": {"world": args.world, "robot": robot, "pose": list(pose),
                       "width": cfg.width, "height": cfg.height, "hfov_rad": cfg.hfov_rad,
                       "camera_noise_webots": None if args.camera_noise_std is not None
                       else args.camera_noise,
                       "camera_noise_std_levels": std,
                       "noise_meaning": "Webots camera noise: per-channel Gaussian std, "
                                        "1.0 = 255 levels; the result is rounded and clipped "
                                        "to 0..255"},
        "measured_residual_std_levels": float(resid.std()),
        "expected_residual_std_with_clipping_levels": expected,
        "measured_residual_std_midtones_levels": float(resid[mid].std()) if mid.any() else None,
        "pixels_clipped_fraction": float(np.mean((noisy == 0) | (noisy == 255))),
        "images": ["camera.png", "camera_noisy.png", "camera_compare.png"],
    }
