"""``diffbot experiment NAME --out DIR``: the study's sensor experiments, through the bus.

Every experiment starts its own plant process (lockstep, on a private unix socket),
reads what it needs from the real topics, and writes PNG + CSV + ``summary.json``
(experiment, parameters — noise both in the study's Webots form and as the resulting
SI standard deviation —, seed, results) into DIR.

    motion-noise    Fig. 4: N straight 0.3 m runs with command noise and wheel slip
                    (friction 0.4), in ONE plant reset between runs (``sim/reset``, new
                    seed per run); GPS end positions, mean, 1σ/2σ covariance ellipses
    lidar           Fig. 5: one scan in the living room; the room from above + polar plot
    noisy-lidar     Fig. 9: the same scan noiseless and with Webots noise 0.2
                    (std = 0.2 x maxRange 80 m = 16 m) on one polar plot
    noisy-odometry  Fig. 10: the 1.5 m square with encoder noise 0.2 rad: odometry vs GPS
    camera          Fig. 8/11: camera image without and with Webots noise 0.2 (std 51/255)

The motion-noise drive is OPEN LOOP: both wheels at ``--wheel-speed`` for the time
that covers ``--distance`` without noise or slip (distance / (r w), rounded to whole
control ticks; the drive limiter's ramps up and down are symmetric, so they cancel),
then zero for ``--settle`` seconds, then the GPS position is recorded.
"""
from __future__ import annotations

import csv
import json
import math
import os
import sys
import time

import numpy as np

from bus import codec, jsonio
from bus.controller import WheelSpeeds
from plant.world import load_world

from .experiment_bus import (ExperimentError, PlantProcess, forget_inputs,
                             run_controller)

EXIT_FAILED = 1
EXIT_BAD_INPUT = 2


# ------------------------------------------------------------------ helpers
class Progress:
    """A progress bar on stderr (one line per 10 % when stderr is not a terminal)."""

    def __init__(self, total: int, what: str, width: int = 30) -> None:
        self.total, self.what, self.width = max(total, 1), what, width
        self.t0 = time.monotonic()
        self.tty = sys.stderr.isatty()
        self._last_decile = -1

    def update(self, done: int) -> None:
        frac = done / self.total
        el = time.monotonic() - self.t0
        eta = el / frac - el if frac > 0 else 0.0
        bar = "#" * int(round(frac * self.width))
        line = (f"  [{bar:<{self.width}}] {done}/{self.total} {self.what}  "
                f"{el:5.1f} s elapsed, {eta:4.1f} s left")
        if self.tty:
            print("\r" + line, end="" if done < self.total else "\n", file=sys.stderr, flush=True)
        elif int(frac * 10) != self._last_decile or done == self.total:
            self._last_decile = int(frac * 10)
            print(line, file=sys.stderr, flush=True)


def _fmt(x: float, digits: int = 9) -> str:
    return f"{x:.{digits}f}" if math.isfinite(x) else ("inf" if x > 0 else "nan")


def _write_csv(path: str, header: list[str], rows) -> str:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for row in rows:
            w.writerow(row)
    return path


def _parse_pose(text: str | None) -> tuple[float, float, float] | None:
    if text is None:
        return None
    try:
        pose = tuple(float(v) for v in text.split(","))
    except ValueError:
        pose = ()
    if len(pose) != 3 or not all(math.isfinite(v) for v in pose):
        raise ValueError(f"--pose must be X,Y,YAW (m, m, rad), got {text!r}")
    return pose  # type: ignore[return-value]


def _pose_set(robot: str, pose) -> list[str]:
    return [] if pose is None else [f"robots.{robot}.pose=[{pose[0]!r}, {pose[1]!r}, {pose[2]!r}]"]


def clipped_normal_moments(v, sigma: float, lo: float, hi: float):
    """Mean and mean square of ``clip(v + N(0, sigma), lo, hi) - v`` (elementwise in v).

    Sensors clip their noisy readings (camera to 0..255, lidar to [min, max] range), so a
    Webots-sized std (51 levels, 16 m) is only reached far from the limits; this is what
    the measured spread should be instead."""
    from math import erf, exp, pi, sqrt
    v = np.atleast_1d(np.asarray(v, dtype=float))
    a, b = (lo - v) / sigma, (hi - v) / sigma
    Phi = np.vectorize(lambda z: 0.5 * (1.0 + erf(z / sqrt(2.0))))
    phi = np.vectorize(lambda z: exp(-0.5 * z * z) / sqrt(2.0 * pi))
    Pa, Pb, pa, pb = Phi(a), Phi(b), phi(a), phi(b)
    m1 = a * Pa + (pa - pb) + b * (1.0 - Pb)
    m2 = a * a * Pa + (Pb - Pa) + a * pa - b * pb + b * b * (1.0 - Pb)
    return sigma * m1, sigma * sigma * m2


def expected_clipped_std(values, sigma: float, lo: float, hi: float) -> float:
    """Std of the residuals (noisy - true) over a set of true values, with clipping."""
    m1, m2 = clipped_normal_moments(values, sigma, lo, hi)
    return float(math.sqrt(max(np.mean(m2) - np.mean(m1) ** 2, 0.0)))


# ------------------------------------------------------------------ motion-noise (Fig. 4)
class StraightRuns:
    """Lockstep driver: open-loop straight runs, GPS end position, ``sim/reset``, repeat.

    The plant answers ``sim/reset`` while it waits for this node's ack, so the reset is
    sent from inside ``step``. A run is: tick 0 no command (the robot stands), ticks
    1..D both wheels at ``wheel_speed``, then S ticks of zero, then the reading. The
    step that resets publishes no command (a command stamped with the old world's time
    would be refused by the new world's clock); the plant does not step the new world
    for that tick but publishes its tick 0, which stands still exactly as the first
    world's did: every run sees the same command sequence.
    After the reset the node runner forgets its inputs: the new world's clock starts
    again at 0, and stamps it already acted on would otherwise be ignored."""

    name = "motion_noise"
    inputs = ["gps", "ground_truth", "joint_states"]

    def __init__(self, runs: int, seed0: int, wheel_speed: float, drive_ticks: int,
                 settle_ticks: int, robot: str, pose, wheel_radius: float,
                 progress: Progress | None = None) -> None:
        self.runs, self.seed0 = runs, seed0
        self.w = wheel_speed
        self.drive_ticks, self.settle_ticks = drive_ticks, settle_ticks
        self.robot, self.pose, self.r = robot, tuple(pose), wheel_radius
        self.progress = progress
        self.run = 0
        self.k = 0
        self.rows: list[tuple] = []
        self.done = False
        self.session = self.keys = self.runner = None

    def step(self, obs):
        k = self.k
        self.k += 1
        if k == 0:
            return None
        if k <= self.drive_ticks:
            return WheelSpeeds(self.w, self.w)
        if k <= self.drive_ticks + self.settle_ticks:
            return WheelSpeeds(0.0, 0.0)
        g, gt, js = obs["gps"].point, obs["ground_truth"].pose.pose, obs["joint_states"]
        enc = self.r * float(np.mean(js.position))
        true = math.hypot(gt.position.x - self.pose[0], gt.position.y - self.pose[1])
        self.rows.append((self.run, self.seed0 + self.run, g.x, g.y,
                          codec.quaternion_to_yaw(gt.orientation), enc, true, obs.t))
        if self.progress:
            self.progress.update(self.run + 1)
        if self.run + 1 >= self.runs:
            self.done = True
            return WheelSpeeds(0.0, 0.0)
        self.run += 1
        self.reset(self.seed0 + self.run)
        self.k = 0                       # the plant publishes the new world's tick 0 next
        return None

    def stop_command(self):
        return WheelSpeeds(0.0, 0.0)

    def reset(self, seed: int) -> None:
        req = jsonio.dumps({"seed": seed, "poses": {self.robot: list(self.pose)}})
        for reply in self.session.get(self.keys.reset, payload=req, timeout=10.0):
            if reply.ok is None:
                raise ExperimentError(
                    f"sim/reset refused: {reply.err.payload.to_bytes().decode()}")
            forget_inputs(self.runner)
            return
        raise ExperimentError("no reply to sim/reset within 10 s")


def motion_noise(args) -> dict:
    robot = args.robot
    sets = [f"materials.rubber.friction={args.friction!r}",
            f"materials.floor.friction={max(args.friction, 1.0)!r}",
            f"robots.{robot}.motion.command_noise_std_radps={args.command_noise!r}",
            *_pose_set(robot, args.pose)]
    spec = load_world(args.world, sets)
    rs = spec.robot(robot)
    r = rs.drive.wheel_radius_m
    tick = spec.control_tick_s
    drive_ticks = max(1, int(round(args.distance / (r * args.wheel_speed) / tick)))
    settle_ticks = max(1, int(round(args.settle / tick)))
    x0, y0, yaw0 = rs.pose
    ideal_dist = r * args.wheel_speed * drive_ticks * tick
    ideal = (x0 + ideal_dist * math.cos(yaw0), y0 + ideal_dist * math.sin(yaw0))
    print(f"motion-noise: {args.runs} runs of {drive_ticks * tick:.2f} s at {args.wheel_speed:g} "
          f"rad/s (open loop, {ideal_dist:.3f} m without noise/slip), command noise "
          f"{args.command_noise:g} rad/s per tick, wheel/floor friction {args.friction:g}; "
          "one plant, reset between runs", file=sys.stderr)
    prog = Progress(args.runs, "runs")
    driver = StraightRuns(args.runs, args.seed, args.wheel_speed, drive_ticks, settle_ticks,
                          robot, rs.pose, r, prog)
    t0 = time.monotonic()
    with PlantProcess(args.out, "plant", driver.name, args.world, sets, args.seed,
                      disable=("lidar", "camera")) as plant:
        run_controller(driver, plant, driver.name, robot, timeout_s=args.timeout)
    wall = time.monotonic() - t0
    rows = driver.rows
    _write_csv(os.path.join(args.out, "endpoints.csv"),
               ["run", "seed", "gps_x_m", "gps_y_m", "yaw_rad", "encoder_distance_m",
                "true_distance_m", "t_s"],
               [[i, s, _fmt(x), _fmt(y), _fmt(th), _fmt(e), _fmt(d), _fmt(t, 3)]
                for i, s, x, y, th, e, d, t in rows])
    ends = np.array([(row[2], row[3]) for row in rows])
    mean = ends.mean(axis=0)
    cov = np.cov(ends.T) if len(ends) > 1 else np.zeros((2, 2))
    std = ends.std(axis=0, ddof=1) if len(ends) > 1 else np.zeros(2)
    enc = np.array([row[5] for row in rows])
    true = np.array([row[6] for row in rows])
    from .experiment_plots import plot_endpoints
    plot_endpoints(ends, rs.pose, ideal, os.path.join(args.out, "motion_noise.png"),
                   f"Motion noise: {len(ends)} open-loop {args.distance:g} m runs at "
                   f"{args.wheel_speed:g} rad/s\ncommand noise {args.command_noise:g} rad/s, "
                   f"friction {args.friction:g} (seeds {args.seed}..{args.seed + len(ends) - 1})")
    return {
        "parameters": {
            "runs": args.runs, "world": args.world, "robot": robot, "start_pose": list(rs.pose),
            "drive": "open loop: both wheels at wheel_speed_radps for drive_time_s "
                     "(= distance / (wheel radius x wheel speed), whole ticks), then 0",
            "distance_m": args.distance, "wheel_speed_radps": args.wheel_speed,
            "drive_ticks": drive_ticks, "drive_time_s": drive_ticks * tick,
            "settle_s": settle_ticks * tick,
            "command_noise_std_radps": args.command_noise,
            "command_noise": "Gaussian, added by the plant to each wheel's commanded speed "
                             "every control tick (the study: noise on the controller's "
                             "velocity commands; Webots has no device field for it)",
            "wheel_floor_friction": args.friction,
            "friction_note": "Coulomb coefficient, the same in both directions: dartpy "
                             "binds only a single friction coefficient (Webots' asymmetric "
                             "coulombFriction is not reproducible here)",
            "contact_solver": spec.contact_solver, "control_tick_s": tick,
            "seeds": [args.seed, args.seed + args.runs - 1],
        },
        "endpoint_mean_m": mean.tolist(), "endpoint_std_m": std.tolist(),
        "endpoint_cov_m2": cov.tolist(),
        "ideal_end_m": list(ideal),
        "mean_shortfall_m": float(ideal_dist - true.mean()),
        "mean_true_distance_m": float(true.mean()),
        "mean_encoder_distance_m": float(enc.mean()),
        "mean_slip_gap_m": float((enc - true).mean()),
        "runs_done": len(rows), "plant_process_starts": 1,
        "experiment_wall_time_s": wall, "wall_time_per_run_s": wall / max(len(rows), 1),
    }


# ------------------------------------------------------------------ noisy-odometry (Fig. 10)
def _toml_str(s: str) -> str:
    return jsonio.dumps(s)


def noisy_odometry(args) -> dict:
    from ..launch.launcher import main as run_main
    from ..launch.scenario import load_scenario
    sc = load_scenario("square")
    robot = sc.robot
    noise_set = f"robots.{robot}.encoders.noise={{webots_noise = {args.encoder_noise!r}}}"
    plant_args = [*sc.plant_args, "--set", noise_set]
    lines = ["[scenario]",
             f"description = {_toml_str('the square with noisy encoders (study Figure 10)')}",
             f"world = {_toml_str(sc.world)}", f"mode = {_toml_str(sc.mode)}",
             f"duration_s = {sc.duration_s or 300.0!r}", 'analysis = "square"',
             f"robot = {_toml_str(robot)}",
             "plant_args = [" + ", ".join(_toml_str(a) for a in plant_args) + "]"]
    for p in sc.processes:
        cmd = list(p.command)
        if cmd[:2] == ["controller", "square_path"]:
            if "--side" in cmd:
                cmd[cmd.index("--side") + 1] = repr(args.side)
            else:
                cmd += ["--side", repr(args.side)]
        if args.odometry == "python" and cmd[:1] == ["fmu-node"]:
            cmd = ["controller", "odometry", "--robot", robot]
        lines += ["", "[[process]]", f"name = {_toml_str(p.name)}",
                  "command = [" + ", ".join(_toml_str(c) for c in cmd) + "]",
                  f"required = {str(p.required).lower()}", f"ends_run = {str(p.ends_run).lower()}",
                  f"sync = {str(p.sync).lower()}"]
    path = os.path.join(args.out, "noisy-odometry.toml")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    print(f"noisy-odometry: the square scenario ({args.side:g} m) with encoder noise "
          f"{args.encoder_noise:g} rad (Webots PositionSensor noise = absolute std in rad); "
          f"scenario file {path}", file=sys.stderr)
    code = run_main([path, "--out", args.out, "--seed", str(args.seed),
                     "--timeout", repr(args.timeout)])
    try:
        with open(os.path.join(args.out, "summary.json")) as f:
            run = json.load(f)
    except (OSError, ValueError):
        run = {}
    if code != 0:
        raise ExperimentError(f"the square run failed (exit code {code}): "
                              f"{run.get('end_reason', 'see ' + args.out + '/logs')}")
    traj = os.path.join(args.out, "trajectory.csv")
    a = np.loadtxt(traj, delimiter=",", skiprows=1, ndmin=2)
    if a.size == 0:
        raise ExperimentError("the square run recorded no trajectory")
    from ..analysis.runs import plot_odometry_vs_gps
    plot_odometry_vs_gps(a, os.path.join(args.out, "odometry_vs_gps.png"),
                         f"Noisy odometry (encoder noise {args.encoder_noise:g} rad per reading) "
                         f"vs GPS,\n{args.side:g} m square, seed {args.seed}")
    err = np.hypot(a[:, 1] - a[:, 4], a[:, 2] - a[:, 5])
    m = run.get("metrics", {}).get(robot, {})
    return {
        "parameters": {"world": sc.world, "robot": robot, "side_m": args.side,
                       "encoder_noise_webots": args.encoder_noise,
                       "encoder_noise_std_rad": args.encoder_noise,
                       "noise_meaning": "Webots PositionSensor noise: absolute Gaussian std in "
                                        "rad, added to each reading (not accumulated)",
                       "odometry": "C FMU node (fmus/build/odometry_fmi2.fmu)"
                       if args.odometry == "fmu" else "Python odometry node",
                       "controller": "square_path, closed loop on the (noisy) odometry",
                       "plant_args": plant_args},
        "final_odom_error_m": float(err[-1]), "max_odom_error_m": float(err.max()),
        "mean_odom_error_m": float(err.mean()),
        "path_length_m": m.get("path_length_m"), "path_closure_m": m.get("path_closure_m"),
        "samples": int(len(a)), "run": run,
    }
