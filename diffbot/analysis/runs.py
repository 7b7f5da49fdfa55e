"""What each scenario writes after its run: CSV, PNG and summary metrics.

An analysis names the keys it wants kept (``keys``) and turns the observed
messages into files in the run's output directory (``analyse``).
"""
from __future__ import annotations

import csv
import importlib
import os
import threading

import numpy as np

from bridges import scene
from bus import codec
from bus.keys import TOPICS, Keys


def _stamp(m) -> int:
    return codec.msg_stamp_ns(m)


def _fmt(x: float) -> str:
    return f"{x:.9f}"


def import_plots_meanwhile() -> threading.Thread:
    """Import matplotlib (:mod:`diffbot.analysis.plots`: ~0.5-0.9 s) on a thread of its own, started
    while the run goes on: the launcher only waits then, and a lockstep run's processes take
    turns, so a core is mostly free. The analysis after the run then draws at once (its own
    import waits for this one if it is not done). A failed import here is left to the
    analysis to report."""
    def load() -> None:
        try:
            importlib.import_module("diffbot.analysis.plots")
        except Exception:      # (the analysis imports it again and says why)
            pass
    t = threading.Thread(target=load, name="import-plots")
    t.start()
    return t


class NoAnalysis:
    draws = False          # whether ``analyse`` plots (diffbot.analysis.plots)

    @staticmethod
    def keys(keys: Keys, spec, world) -> dict[str, str]:
        return {}

    @staticmethod
    def analyse(observer, keys, spec, world, out, plots: bool = True) -> dict:
        return {}


class SquareAnalysis:
    """Odometry against GPS over the square: ``trajectory.csv``, ``odometry_vs_gps.png``."""

    draws = True

    @staticmethod
    def keys(keys: Keys, spec, world) -> dict[str, str]:
        r = spec.robot
        return {keys.topic(r, t): TOPICS[t].msgtype
                for t in ("odom", "gps", "cmd_vel", "joint_states")}

    @staticmethod
    def analyse(observer, keys, spec, world, out, plots: bool = True) -> dict:
        r = spec.robot
        odom = {_stamp(m): m for m in observer.messages(keys.topic(r, "odom"))}
        gps = {_stamp(m): m for m in observer.messages(keys.topic(r, "gps"))}
        enc = {_stamp(m): m.position for m in observer.messages(keys.topic(r, "joint_states"))}
        cmds = observer.messages(keys.topic(r, "cmd_vel"))
        # The path ends where the controller stopped the robot: its last command.
        t_end = _stamp(cmds[-1]) if cmds else max(odom, default=0)
        # odometry lives in <robot>/odom (REP 105), GPS in world: compared in world, through
        # the static transform world -> <robot>/odom (the start pose)
        start = next(rs.pose for rs in world.robots if rs.name == r)
        rows = []
        for t in sorted(set(odom) & set(gps) & set(enc)):
            if t > t_end:
                break
            o, g, e = odom[t].pose.pose, gps[t].point, enc[t]
            ox, oy, oth = scene.to_world(start, o.position.x, o.position.y,
                                         codec.quaternion_to_yaw(o.orientation))
            rows.append((t * 1e-9, ox, oy, oth, g.x, g.y, e[0], e[1]))
        path = os.path.join(out, "trajectory.csv")
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["t_s", "odom_x_m", "odom_y_m", "odom_theta_rad", "gps_x_m", "gps_y_m",
                        "enc_left_rad", "enc_right_rad"])
            for row in rows:
                w.writerow([_fmt(v) for v in row])
        if not rows:
            return {"rows": 0}
        a = np.array(rows)
        err = float(np.hypot(a[-1, 1] - a[-1, 4], a[-1, 2] - a[-1, 5]))
        length = float(np.sum(np.hypot(np.diff(a[:, 4]), np.diff(a[:, 5]))))
        closure = float(np.hypot(a[-1, 4] - a[0, 4], a[-1, 5] - a[0, 5]))
        if plots:
            plot_odometry_vs_gps(a, os.path.join(out, "odometry_vs_gps.png"),
                                 f"Odometry and GPS, {spec.name} ({len(rows)} samples)")
        return {r: {"final_odom_error_m": err, "path_length_m": length,
                    "path_closure_m": closure, "duration_s": float(a[-1, 0] - a[0, 0]),
                    "max_odom_error_m": float(np.max(np.hypot(a[:, 1] - a[:, 4],
                                                              a[:, 2] - a[:, 5])))},
                "final_odom_error_m": err, "path_length_m": length}


def plot_odometry_vs_gps(a: np.ndarray, path: str, title: str, every: int = 10) -> str:
    """Odometry as '*', GPS as 'o', as in the study's Figure 7."""
    from .plots import plt, save
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(a[::every, 1], a[::every, 2], "*", color="tab:blue", ms=5, label="odometry")
    ax.plot(a[::every, 4], a[::every, 5], "o", color="tab:orange", ms=5, mfc="none", label="GPS")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.axis("equal")
    ax.grid(True, alpha=0.3)
    ax.legend()
    return save(fig, path)


class DriveTestAnalysis:
    """Linear and angular velocity from ground truth: ``velocity.csv``, ``velocity.png``."""

    draws = True

    @staticmethod
    def keys(keys: Keys, spec, world) -> dict[str, str]:
        r = spec.robot
        return {keys.topic(r, "ground_truth"): TOPICS["ground_truth"].msgtype,
                keys.topic(r, "wheel_cmd"): TOPICS["wheel_cmd"].msgtype}

    @staticmethod
    def analyse(observer, keys, spec, world, out, plots: bool = True) -> dict:
        r = spec.robot
        gt = observer.messages(keys.topic(r, "ground_truth"))
        cmds = observer.messages(keys.topic(r, "wheel_cmd"))
        t0 = _stamp(cmds[0]) * 1e-9 if cmds else 0.0
        rows = [(_stamp(m) * 1e-9, m.twist.twist.linear.x, m.twist.twist.angular.z) for m in gt]
        with open(os.path.join(out, "velocity.csv"), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["t_s", "linear_velocity_mps", "angular_velocity_radps"])
            for row in rows:
                w.writerow([_fmt(v) for v in row])
        if not rows:
            return {"rows": 0}
        a = np.array(rows)

        metrics: dict = {}

        def steady(name: str, col: int, t_from: float, t_to: float) -> None:
            """Mean over the window, or null with the reason (JSON has no NaN)."""
            sel = (a[:, 0] >= t0 + t_from) & (a[:, 0] < t0 + t_to)
            metrics[name] = float(np.mean(a[sel, col])) if sel.any() else None
            if not sel.any():
                metrics[f"{name}_reason"] = (
                    f"no ground truth between {t_from:g} and {t_to:g} s after the first "
                    f"command (the run covered {a[-1, 0] - t0:.2f} s of it)")

        steady("steady_linear_velocity_mps", 1, 3.0, 5.0)
        steady("steady_angular_velocity_radps", 2, 8.0, 10.0)
        if plots:
            plot_velocities(a, t0, os.path.join(out, "velocity.png"))
        return {**metrics, "expected_linear_velocity_mps": 0.12,
                "expected_angular_velocity_radps": -0.12 / 0.18}


def plot_velocities(a: np.ndarray, t0: float, path: str) -> str:
    """The study's Figures 2 and 3: linear and angular velocity against time."""
    from .plots import plt, save
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    t = a[:, 0] - t0
    ax1.plot(t, a[:, 1], color="tab:blue")
    ax1.set_ylabel("linear velocity [m/s]")
    ax1.set_title("Drive test: wheels 1 rad/s for 5 s, then left +1 / right -1 rad/s")
    ax1.grid(True, alpha=0.3)
    ax2.plot(t, a[:, 2], color="tab:red")
    ax2.set_ylabel("angular velocity [rad/s]")
    ax2.set_xlabel("time since first command [s]")
    ax2.grid(True, alpha=0.3)
    return save(fig, path)


from .follow import FollowAnalysis  # noqa: E402
from .swarm import SwarmAnalysis  # noqa: E402

ANALYSES = {"square": SquareAnalysis, "drive-test": DriveTestAnalysis, "follow": FollowAnalysis,
            "swarm": SwarmAnalysis, "none": NoAnalysis}
