"""Replay a recorded square run through the odometry FMU in plain fmpy, no bus, no diffbot.

    diffbot run square --out out/square
    python fmus/examples/fmpy_trajectory.py out/square/trajectory.csv [--fmu FMU] [--png FILE]

``trajectory.csv`` has one row per control tick: t_s, odom_x_m, odom_y_m, odom_theta_rad,
gps_x_m, gps_y_m, enc_left_rad, enc_right_rad. The wheel speeds fed to the FMU are the
encoder increments over each tick divided by its length, held over that tick (a
piecewise-constant input: each tick boundary appears twice in the input table, a step
change in fmpy's terms), so the FMU's exact arcs reproduce the recorded dead reckoning.
The start pose is the first odometry row. The script writes a PNG of the FMU's x/y
against GPS and prints the final FMU-GPS error and the largest difference between the
FMU and the odometry recorded on the bus (rounded to 1e-9 in the CSV).

Any FMI tool can do the same; this only needs fmpy, numpy and matplotlib.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DEFAULT_FMU = HERE.parent / "build" / "odometry_fmi2.fmu"
COLUMNS = ("t_s", "odom_x_m", "odom_y_m", "odom_theta_rad", "gps_x_m", "gps_y_m",
           "enc_left_rad", "enc_right_rad")


def read_trajectory(path: Path) -> np.ndarray:
    """The CSV as a structured array; exits with a message if a column is missing."""
    data = np.genfromtxt(path, delimiter=",", names=True)
    missing = [c for c in COLUMNS if c not in (data.dtype.names or ())]
    if missing:
        sys.exit(f"{path}: missing column(s) {', '.join(missing)} "
                 "(record it with `diffbot run square --out DIR`)")
    if data.size < 2:
        sys.exit(f"{path}: needs at least two rows")
    return np.atleast_1d(data)


def wheel_speed_signal(t: np.ndarray, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """fmpy input table: the speed of tick i (increment / length) held over [t[i-1], t[i]]."""
    dt = np.diff(t)
    wl, wr = np.diff(left) / dt, np.diff(right) / dt
    sig = np.zeros(2 * len(dt), dtype=[("time", float), ("omega_left", float),
                                       ("omega_right", float)])
    sig["time"][0::2], sig["time"][1::2] = t[:-1], t[1:]
    sig["omega_left"][0::2] = sig["omega_left"][1::2] = wl
    sig["omega_right"][0::2] = sig["omega_right"][1::2] = wr
    return sig


def simulate(fmu: Path, traj: np.ndarray, wheel_radius: float, wheel_separation: float):
    """The FMU's x, y, theta at the CSV's times."""
    from fmpy import simulate_fmu
    t = traj["t_s"]
    result = simulate_fmu(
        str(fmu), fmi_type="CoSimulation", start_time=float(t[0]), stop_time=float(t[-1]),
        output_interval=float(np.median(np.diff(t))),
        input=wheel_speed_signal(t, traj["enc_left_rad"], traj["enc_right_rad"]),
        start_values={"wheel_radius": wheel_radius, "wheel_separation": wheel_separation,
                      "x0": float(traj["odom_x_m"][0]), "y0": float(traj["odom_y_m"][0]),
                      "theta0": float(traj["odom_theta_rad"][0])},
        output=["x", "y", "theta"])
    return (np.interp(t, result["time"], result[name]) for name in ("x", "y", "theta"))


def plot(traj, x, y, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(traj["gps_x_m"], traj["gps_y_m"], "o", color="tab:orange", ms=4, mfc="none",
            markevery=10, label="GPS")
    ax.plot(x, y, "-", color="tab:blue", lw=1.5, label="odometry FMU (fmpy)")
    ax.plot(x[-1], y[-1], "*", color="tab:blue", ms=12)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("Odometry FMU (fmpy, recorded encoders) vs GPS")
    ax.axis("equal")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("csv", type=Path, help="trajectory.csv of `diffbot run square --out DIR` "
                                          "(or the DIR)")
    p.add_argument("--fmu", type=Path, default=DEFAULT_FMU,
                   help=f"odometry FMU (default {DEFAULT_FMU.relative_to(HERE.parent.parent)})")
    p.add_argument("--png", type=Path, help="figure to write (default fmu_vs_gps.png next to "
                                            "the CSV)")
    p.add_argument("--wheel-radius", type=float, default=0.12, help="m (default 0.12)")
    p.add_argument("--wheel-separation", type=float, default=0.36, help="m (default 0.36)")
    args = p.parse_args(argv)
    csv = args.csv / "trajectory.csv" if args.csv.is_dir() else args.csv
    if not csv.is_file():
        sys.exit(f"{csv}: no such file (record one with `diffbot run square --out DIR`)")
    if not args.fmu.is_file():
        sys.exit(f"{args.fmu}: no such FMU (build it with `diffbot fmu build`)")
    traj = read_trajectory(csv)
    x, y, theta = simulate(args.fmu, traj, args.wheel_radius, args.wheel_separation)
    png = args.png or csv.with_name("fmu_vs_gps.png")
    plot(traj, x, y, png)
    final = float(np.hypot(x[-1] - traj["gps_x_m"][-1], y[-1] - traj["gps_y_m"][-1]))
    vs_odom = float(np.max(np.hypot(x - traj["odom_x_m"], y - traj["odom_y_m"])))
    print(f"{len(traj)} samples over {traj['t_s'][-1] - traj['t_s'][0]:.2f} s")
    print(f"final error FMU - GPS: {final:.4f} m")
    print(f"max |FMU - recorded odometry|: {vs_odom:.2e} m")
    print(f"figure: {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
