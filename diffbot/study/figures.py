"""``diffbot figures --out DIR``: the study's twelve figures, from real runs, with a report.

Every figure comes from a run of this project's own commands, each started as a
``diffbot`` subprocess into ``DIR/runs/<job>/`` (its stdout and stderr in
``DIR/runs/<job>.log``); independent jobs run in parallel (``--jobs``, longest first),
through :mod:`diffbot.runner`: on this machine, or as Ray tasks (``--engine ray``,
``--address``; the runs' folders come back to ``DIR`` from another machine).
A figure is copied from its run's output or re-plotted from its CSV/PNG; nothing here
re-implements an experiment. Then ``DIR`` holds::

    fig01_robot.png ... fig12_tracking_distance.png, follow.gif
    index.html    every figure with its number, caption, parameters and measured numbers
    REPORT.md     the same in Markdown
    figures.json  all the numbers, the parameters and each job's command, exit code and times

Ctrl-C (or SIGTERM) cancels the queued jobs and stops the running ones (each by PID:
SIGINT, a grace period, SIGKILL to its process tree); the report is still written for
what finished. Exit codes: 0 all figures
written, 1 a job or a figure failed (the others are still written), 2 bad arguments,
130 interrupted.
"""
from __future__ import annotations

import math
import os
import shutil
import sys
from dataclasses import dataclass, field
from typing import Callable


from .. import runner
from ..runner import read_json

EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130



# ------------------------------------------------------------------ the jobs
@dataclass(frozen=True)
class JobSpec:
    name: str
    args: tuple[str, ...]        # after `diffbot` (or a module run with -m, see `module`)
    est_s: float                 # measured wall time alone on the 2-core machine: run longest first
    what: str
    module: str = ""             # run `python -m module` instead of `diffbot`
    cpus: float = 1.0            # CPUs its processes keep busy (pipelined lockstep: 2)


JOBS = {j.name: j for j in (
    JobSpec("follow", ("run", "follow"), 48.0, "follow scenario: leader + camera follower, 60 s",
            cpus=2.0),
    JobSpec("motion-noise", ("experiment", "motion-noise"), 45.0,
            "100 noisy open-loop 0.3 m runs in one plant"),
    JobSpec("square", ("run", "square"), 18.0, "1.5 m square on odometry vs GPS"),
    JobSpec("noisy-odometry", ("experiment", "noisy-odometry"), 18.0,
            "the square with encoder noise 0.2 rad"),
    JobSpec("lidar", ("experiment", "lidar"), 4.5, "one noiseless lidar scan"),
    JobSpec("camera", ("experiment", "camera"), 5.5, "camera image, noiseless and noisy"),
    JobSpec("drive-test", ("run", "drive-test"), 5.5, "wheel speeds 1,1 then 1,-1 rad/s"),
    JobSpec("noisy-lidar", ("experiment", "noisy-lidar"), 5.0, "lidar scan with noise 0.2"),
    JobSpec("render", (), 3.5, "third-person renders of robot1 and the living room",
            module="diffbot.study.figures_render"),
)}


def job_argv(spec: JobSpec, out: str, seed: int) -> list[str]:
    if spec.module:
        return [sys.executable, "-m", spec.module, "--out", out]
    return [sys.executable, "-m", "diffbot.cli", *spec.args, "--out", out, "--seed", str(seed)]


# ------------------------------------------------------------------ the figures
@dataclass
class Made:
    """What a figure builder reports: caption text, parameters used, numbers measured."""
    caption: str
    parameters: dict
    numbers: dict
    extra_files: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class FigureSpec:
    number: int
    file: str
    study_caption: str
    jobs: tuple[str, ...]
    build: Callable[["Context", str], Made]


class FigureError(Exception):
    pass


@dataclass
class Context:
    out: str
    jobs: dict[str, runner.Run]

    def run_dir(self, job: str) -> str:
        return self.jobs[job].out

    def summary(self, job: str) -> dict:
        s = self.jobs[job].summary or read_json(os.path.join(self.run_dir(job), "summary.json"))
        if not s:
            raise FigureError(f"{job}: no summary.json in {self.run_dir(job)}")
        return s

    def file(self, job: str, name: str) -> str:
        path = os.path.join(self.run_dir(job), name)
        if not os.path.isfile(path):
            raise FigureError(f"{job} wrote no {name} (looked in {self.run_dir(job)})")
        return path

    def copy(self, job: str, name: str, dest: str) -> str:
        shutil.copyfile(self.file(job, name), dest)
        return dest

    def plotted(self, job: str, name: str, dest: str) -> tuple[dict, dict]:
        """A figure made by one job: its plot ``name`` copied to ``dest``; the job's
        summary and the parameters in it."""
        s = self.summary(job)
        self.copy(job, name, dest)
        return s, s.get("parameters", {})


def _scenario_params(s: dict) -> dict:
    return {k: s.get(k) for k in ("scenario", "world", "mode", "seed") if k in s}


def _run_numbers(s: dict) -> dict:
    return {"real_time_factor": s.get("real_time_factor"), "sim_time_s": s.get("sim_time_s"),
            "run_wall_time_s": s.get("wall_time_s")}


def fig_robot(ctx: Context, dest: str) -> Made:
    s = ctx.summary("render")
    ctx.copy("render", "robot.png", dest)
    views = ", ".join(v["label"] for v in s.get("robot_views", []))
    return Made(
        f"{s['robot']} as the plant builds it: a box chassis, two driven wheels (radius "
        f"{s['wheel_radius_m']:g} m, {s['wheel_separation_m']:g} m apart) and a rear ball "
        f"caster, ray-cast from the same shapes the camera and lidar see ({views}).",
        {"world": s["world"], "robot": s["robot"], "robot_pose": s["robot_pose"],
         "image_size_px": s["robot_view_size_px"], "hfov_rad": s["robot_view_hfov_rad"],
         "eye_points": s["robot_views"], "settle_s": s["settle_s"]},
        {"wheel_radius_m": s["wheel_radius_m"], "wheel_separation_m": s["wheel_separation_m"],
         "robot_colour_pixel_fraction": s.get("robot_colour_fraction")})


def _schedule(spec) -> list[tuple[float, float, float]]:
    """(duration s, left, right rad/s) of the drive-test's wheel_schedule controller."""
    for p in spec.processes:
        cmd = list(p.command)
        if "--schedule" in cmd:
            out = []
            for seg in cmd[cmd.index("--schedule") + 1].split(";"):
                dur, wheels = seg.split(":")
                left, right = wheels.split(",")
                out.append((float(dur), float(left), float(right)))
            return out
    raise FigureError("drive-test: no --schedule in the scenario")


def _drive_test(ctx: Context) -> tuple[dict, list, float, float, "object"]:
    from plant.world import load_world

    from ..launch.scenario import load_scenario
    s = ctx.summary("drive-test")
    spec = load_scenario("drive-test")
    drive = load_world(spec.world).robot(spec.robot).drive
    import numpy as np
    a = np.loadtxt(ctx.file("drive-test", "velocity.csv"), delimiter=",", skiprows=1, ndmin=2)
    if a.size == 0:
        raise FigureError("drive-test: velocity.csv is empty")
    return s, _schedule(spec), drive.wheel_radius_m, drive.wheel_separation_m, a


def _velocity_plot(a, col: int, sched, expected: list[float], key: int, measured: float,
                   window, ylabel: str, title: str, formula: str, unit: str, color: str,
                   dest: str) -> None:
    """One velocity against time, the schedule's phases shaded and labelled, the expected
    value of each phase dashed (phase ``key``'s value and formula written out)."""
    from ..analysis.plots import plt, save
    fig, ax = plt.subplots(figsize=(8, 4.4))
    t0 = 0.0
    for i, (dur, left, right) in enumerate(sched):
        ax.axvspan(t0, t0 + dur, color="0.5" if i % 2 else "0.8", alpha=0.12, lw=0)
        ax.text(t0 + dur / 2, 1.01, f"left {left:+g}, right {right:+g} rad/s", ha="center",
                va="bottom", transform=ax.get_xaxis_transform(), fontsize=8.5)
        t0 += dur
    ax.plot(a[:, 0], a[:, col], color=color, lw=2.2, label="measured (ground truth)")
    ax.axvspan(*window, color=color, alpha=0.13, lw=0,
               label=f"mean over {window[0]:g}-{window[1]:g} s = {measured:.4f} {unit}")
    t0 = 0.0
    for i, ((dur, _, _), exp) in enumerate(zip(sched, expected)):
        ax.plot([t0, t0 + dur], [exp, exp], ls=(0, (4, 3)), color="k", lw=1.3, zorder=5,
                label=f"expected: {formula}" if i == key else None)
        if i == key:
            ax.annotate(f"expected {exp:.3f} {unit}", (t0 + dur / 2, exp),
                        xytext=(0, 10 if exp >= 0 else -16), textcoords="offset points",
                        ha="center", fontsize=10, fontweight="bold")
        t0 += dur
    lo = min(0.0, *expected, float(a[:, col].min()))
    hi = max(0.0, *expected, float(a[:, col].max()))
    pad = 0.12 * max(hi - lo, 1e-6)
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_xlabel("simulated time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title, pad=18)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="center right", fontsize=8.5)
    save(fig, dest)


def fig_linear(ctx: Context, dest: str) -> Made:
    s, sched, r, d, a = _drive_test(ctx)
    m = s.get("metrics", {})
    v = m.get("steady_linear_velocity_mps", math.nan)
    expected = [r * (left + right) / 2 for _, left, right in sched]
    left, right = sched[0][1], sched[0][2]
    _velocity_plot(a, 1, sched, expected, 0, v, (3.0, 5.0), "linear velocity v [m/s]",
                   "Linear velocity of the robot",
                   f"v = r (ωL + ωR) / 2 = {r:g} x ({left:g} + {right:g}) / 2", "m/s",
                   "tab:blue", dest)
    return Made(
        f"Both wheels at {sched[0][1]:g} rad/s for {sched[0][0]:g} s (the study's \"1 m/s\" is "
        f"1 rad/s): v = r ω = {expected[0]:.3f} m/s expected, {v:.4f} m/s measured (mean of "
        "the plant's ground-truth body velocity over 3-5 s). Then the wheels turn opposite "
        "ways and v returns to 0.",
        {**_scenario_params(s), "wheel_schedule_s_radps": sched, "wheel_radius_m": r},
        {"steady_linear_velocity_mps": v, "expected_linear_velocity_mps": expected[0],
         "linear_velocity_error_mps": v - expected[0], **_run_numbers(s)})


def fig_angular(ctx: Context, dest: str) -> Made:
    s, sched, r, d, a = _drive_test(ctx)
    m = s.get("metrics", {})
    w = m.get("steady_angular_velocity_radps", math.nan)
    expected = [r * (right - left) / d for _, left, right in sched]
    t_end = sum(seg[0] for seg in sched)
    left, right = sched[-1][1], sched[-1][2]
    _velocity_plot(a, 2, sched, expected, len(sched) - 1, w, (t_end - 2.0, t_end),
                   "angular velocity ω [rad/s]",
                   "Angular velocity of the robot (counter-clockwise positive)",
                   f"ω = r (ωR - ωL) / d = {r:g} x ({right:g} - {left:g}) / {d:g}", "rad/s",
                   "tab:red", dest)
    return Made(
        f"Left wheel {sched[-1][1]:+g} rad/s, right {sched[-1][2]:+g} rad/s: the robot spins "
        f"on the spot, clockwise. ω = r(ωR - ωL)/d = {expected[-1]:.3f} rad/s expected "
        f"(counter-clockwise positive; the study's \"0.12/0.18 = 0.66 m/s\" is this rate in "
        f"rad/s, counted clockwise-positive), {w:.4f} rad/s measured (mean over the last 2 s).",
        {**_scenario_params(s), "wheel_schedule_s_radps": sched, "wheel_radius_m": r,
         "wheel_separation_m": d, "sign_convention": "counter-clockwise positive (REP 103)"},
        {"steady_angular_velocity_radps": w, "expected_angular_velocity_radps": expected[-1],
         "angular_velocity_error_radps": w - expected[-1], **_run_numbers(s)})


def fig_motion_noise(ctx: Context, dest: str) -> Made:
    s, p = ctx.plotted("motion-noise", "motion_noise.png", dest)
    std = s.get("endpoint_std_m", [math.nan, math.nan])
    return Made(
        f"{p.get('runs')} open-loop straight runs of {p.get('distance_m')} m at "
        f"{p.get('wheel_speed_radps')} rad/s, with Gaussian noise of "
        f"{p.get('command_noise_std_radps')} rad/s on each wheel command every tick and "
        f"wheel/floor friction {p.get('wheel_floor_friction')}; GPS end positions with their "
        f"mean and 1σ/2σ covariance ellipses. Spread {1000 * std[0]:.2f} mm along the path, "
        f"{1000 * std[1]:.2f} mm across; slip leaves the robot "
        f"{1000 * s.get('mean_shortfall_m', math.nan):.1f} mm short on average. One plant "
        "process, reset between runs.",
        {k: p[k] for k in ("runs", "world", "start_pose", "distance_m", "wheel_speed_radps",
                           "drive_time_s", "command_noise_std_radps", "wheel_floor_friction",
                           "contact_solver", "seeds") if k in p},
        {"endpoint_mean_m": s.get("endpoint_mean_m"), "endpoint_std_m": std,
         "ideal_end_m": s.get("ideal_end_m"), "mean_shortfall_m": s.get("mean_shortfall_m"),
         "mean_slip_gap_m": s.get("mean_slip_gap_m"), "runs_done": s.get("runs_done"),
         "wall_time_per_run_s": s.get("wall_time_per_run_s")})


def fig_lidar(ctx: Context, dest: str) -> Made:
    s, p = ctx.plotted("lidar", "lidar.png", dest)
    return Made(
        f"(a) The living room from above with the {p.get('num_rays')} rays of one scan and "
        f"where they hit; (b) the same scan as a polar plot (bearing 0 = ahead, + = left). "
        f"{p.get('num_rays')} rays over {math.degrees(p.get('fov_rad', math.nan)):.0f}° "
        f"including both ends, max range {p.get('max_range_m')} m, no noise.",
        {k: p[k] for k in ("world", "robot", "robot_pose", "num_rays", "fov_rad",
                           "angle_increment_rad", "max_range_m", "scan_plane_z_m") if k in p},
        {k: s.get(k) for k in ("finite_rays", "range_min_m", "range_max_m", "range_mean_m")})


def fig_map(ctx: Context, dest: str) -> Made:
    s = ctx.summary("render")
    ctx.copy("render", "room.png", dest)
    return Made(
        f"The {s['world']} world: a {s['floor_size_m'][0]:g} m x {s['floor_size_m'][1]:g} m "
        f"room with {s['objects']} furniture solids (boxes, cylinders, spheres) from "
        f"plant/worlds/{s['world']}.toml, rendered by the plant's ray caster from above a "
        "corner; robot1 at its start pose.",
        {"world": s["world"], "eye_m": s["room_eye_m"], "target_m": s["room_target_m"],
         "hfov_rad": s["room_hfov_rad"], "image_size_px": s["room_size_px"]},
        {"floor_size_m": s["floor_size_m"], "wall_height_m": s["wall_height_m"],
         "objects": s["objects"], "render_wall_time_s": s.get("wall_time_s")})


def _square_numbers(m: dict) -> dict:
    return {k: m.get(k) for k in ("final_odom_error_m", "max_odom_error_m", "path_length_m",
                                  "path_closure_m", "duration_s")}


def fig_odometry(ctx: Context, dest: str) -> Made:
    s = ctx.summary("square")
    ctx.copy("square", "odometry_vs_gps.png", dest)
    m = s.get("metrics", {})
    robot = next((k for k, v in m.items() if isinstance(v, dict)), "robot1")
    mr = m.get(robot, m)
    return Made(
        f"{robot} drives a 1.5 m square closed-loop on its own odometry (the C odometry FMU on "
        f"the bus integrating the wheel encoders); odometry '*' against GPS 'o'. Without noise "
        f"they end {1000 * mr.get('final_odom_error_m', math.nan):.1f} mm apart after "
        f"{mr.get('path_length_m', math.nan):.2f} m.",
        {**_scenario_params(s), "side_m": 1.5, "odometry": "fmus/build/odometry_fmi2.fmu"},
        {**_square_numbers(mr), **_run_numbers(s)})


def _camera_plot(ctx: Context, name: str, dest: str, title: str) -> None:
    from ..analysis.plots import plt, save
    img = plt.imread(ctx.file("camera", name))
    h, w = img.shape[:2]
    fig, ax = plt.subplots(figsize=(8, 8 * h / w + 0.6))
    ax.imshow(img, interpolation="nearest")
    ax.set_title(title, fontsize=10.5)
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    save(fig, dest)


def fig_camera(ctx: Context, dest: str) -> Made:
    s = ctx.summary("camera")
    p = s.get("parameters", {})
    pose = p.get("pose", [0, 0, 0])
    _camera_plot(ctx, "camera.png", dest,
                 f"{p.get('robot')}'s camera, {p.get('width')}x{p.get('height')} rgb8 from the bus "
                 f"(no noise), robot at ({pose[0]:g}, {pose[1]:g}) m, yaw {pose[2]:g} rad")
    return Made(
        f"One frame of {p.get('robot')}'s camera topic ({p.get('width')}x{p.get('height')}, "
        f"horizontal field of view {p.get('hfov_rad')} rad), decoded from the bus and "
        "enlarged pixel for pixel: the dining corner with table, chairs and bookshelf.",
        {k: p[k] for k in ("world", "robot", "pose", "width", "height", "hfov_rad") if k in p},
        {})


def fig_noisy_lidar(ctx: Context, dest: str) -> Made:
    s, p = ctx.plotted("noisy-lidar", "noisy_lidar.png", dest)
    return Made(
        f"The scan of Figure 5 without (blue) and with (orange) Webots lidar noise "
        f"{p.get('lidar_noise_webots')}: a standard deviation relative to the max range, "
        f"{p.get('lidar_noise_std_m')} m for the SICK LMS 291's {p.get('max_range_m')} m, on "
        "ranges of 1-5 m, so the room disappears in the noise (left: full range; right: "
        f"zoomed to the room). Noisy values are clipped to the sensor's range: "
        f"{100 * (s.get('fraction_clipped_to_min_range') or 0):.0f} % read the minimum.",
        {k: p[k] for k in ("world", "robot", "lidar_noise_webots", "lidar_noise_std_m",
                           "max_range_m", "min_range_m", "num_rays") if k in p},
        {k: s.get(k) for k in ("measured_residual_std_m", "expected_residual_std_with_clipping_m",
                               "measured_residual_mean_m", "fraction_clipped_to_min_range")})


def fig_noisy_odometry(ctx: Context, dest: str) -> Made:
    s, p = ctx.plotted("noisy-odometry", "odometry_vs_gps.png", dest)
    run = s.get("run", {})
    return Made(
        f"The square of Figure 7 with Webots PositionSensor noise {p.get('encoder_noise_webots')} "
        f"(a Gaussian of {p.get('encoder_noise_std_rad')} rad std on every encoder reading). The "
        f"controller closes the square on the noisy odometry (blue '*'); GPS (orange 'o') shows "
        f"where the robot really went: up to {100 * s.get('max_odom_error_m', math.nan):.0f} cm "
        "apart.",
        {k: p[k] for k in ("world", "robot", "side_m", "encoder_noise_webots",
                           "encoder_noise_std_rad", "odometry", "controller") if k in p}
        | {"seed": s.get("seed")},
        {**{k: s.get(k) for k in ("final_odom_error_m", "max_odom_error_m", "mean_odom_error_m",
                                  "path_length_m", "path_closure_m")}, **_run_numbers(run)})


def fig_noisy_camera(ctx: Context, dest: str) -> Made:
    s = ctx.summary("camera")
    p = s.get("parameters", {})
    _camera_plot(ctx, "camera_noisy.png", dest,
                 f"the same frame with Webots camera noise {p.get('camera_noise_webots')} "
                 f"(std {p.get('camera_noise_std_levels'):g} of 255 levels per channel)")
    return Made(
        f"The frame of Figure 8 with Webots camera noise {p.get('camera_noise_webots')}: a "
        f"Gaussian of {p.get('camera_noise_std_levels'):g} levels (0.2 x 255) per channel and "
        "pixel, rounded and clipped to 0-255 (clipping makes the measured spread a little "
        "smaller than 51).",
        {k: p[k] for k in ("world", "robot", "pose", "width", "height", "camera_noise_webots",
                           "camera_noise_std_levels") if k in p},
        {k: s.get(k) for k in ("measured_residual_std_levels",
                               "expected_residual_std_with_clipping_levels",
                               "measured_residual_std_midtones_levels",
                               "pixels_clipped_fraction")})


def fig_tracking(ctx: Context, dest: str) -> Made:
    s = ctx.summary("follow")
    ctx.copy("follow", "tracking_distance.png", dest)
    extra = []
    try:
        ctx.copy("follow", "follow.gif", os.path.join(ctx.out, "follow.gif"))
        extra.append("follow.gif")
    except FigureError:
        pass
    m = s.get("metrics", {})
    return Made(
        "The follower keeps its camera 0.65 m from the leader's green ball: it finds the ball "
        "with OpenCV, steers it to the image centre and sets its speed from the ball's "
        "apparent radius (orange: that estimate); blue: the true distance from ground truth. "
        f"After {m.get('settle_s', 5):g} s the distance stays within "
        f"{m.get('distance_min_m', math.nan):.3f}-{m.get('distance_max_m', math.nan):.3f} m "
        "(the study: 0.6-0.7 m).",
        {**_scenario_params(s), "target_distance_m": 0.65, "band_m": [0.60, 0.70],
         "settle_s": m.get("settle_s")},
        {**{k: m.get(k) for k in ("distance_min_m", "distance_max_m", "distance_rms_error_m",
                                  "distance_in_band", "ball_lost_frames", "frames")},
         **_run_numbers(s)}, extra)


FIGURES = {f.number: f for f in (
    FigureSpec(1, "fig01_robot.png", "3D model of the differential drive robot.", ("render",),
               fig_robot),
    FigureSpec(2, "fig02_linear_velocity.png", "Linear velocity of the robot.", ("drive-test",),
               fig_linear),
    FigureSpec(3, "fig03_angular_velocity.png", "Angular velocity of the robot.",
               ("drive-test",), fig_angular),
    FigureSpec(4, "fig04_motion_noise.png", "Motion noise.", ("motion-noise",), fig_motion_noise),
    FigureSpec(5, "fig05_lidar.png", "Lidar sensor data: (a) the simulation environment, "
               "(b) polar plot of the distance sensor data.", ("lidar",), fig_lidar),
    FigureSpec(6, "fig06_map.png", "Map environment.", ("render",), fig_map),
    FigureSpec(7, "fig07_odometry_vs_gps.png", "Odometry and GPS data.", ("square",),
               fig_odometry),
    FigureSpec(8, "fig08_camera.png", "Camera image.", ("camera",), fig_camera),
    FigureSpec(9, "fig09_noisy_lidar.png", "Noisy lidar data compared to noiseless data.",
               ("noisy-lidar",), fig_noisy_lidar),
    FigureSpec(10, "fig10_noisy_odometry.png",
               "Noisy odometry data compared to ground truth GPS data.", ("noisy-odometry",),
               fig_noisy_odometry),
    FigureSpec(11, "fig11_noisy_camera.png", "Noisy camera image.", ("camera",),
               fig_noisy_camera),
    FigureSpec(12, "fig12_tracking_distance.png", "Tracking distance vs time.", ("follow",),
               fig_tracking),
)}
