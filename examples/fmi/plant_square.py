"""The study's square in an FMI master: the plant FMU feeds the odometry FMU (an SSP
system), the square-path controller is the master's own logic; prints its odometry error.

    diffbot fmu export-plant --fmi 2 --out out/robot.fmu
    python examples/fmi/plant_square.py out/robot.fmu [--master libcosim|ecos] [--ssp FILE]

Compare with ``diffbot run square --out out/square`` (its summary.json's
``final_odom_error_m``): the same world, controller and odometry, over Zenoh instead.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from bus import codec                                    # noqa: E402
from controllers.square_path import SquarePath           # noqa: E402
from fmus.plant_ssp import run_square, write_ssp         # noqa: E402

DEFAULT_ODOMETRY = HERE.parent / "build" / "odometry_fmi2.fmu"


def square(plant_fmu: str, master: str = "libcosim", ssp: str | None = None,
           odometry_fmu: str = str(DEFAULT_ODOMETRY), side_m: float = 1.5,
           start=(-1.0, -1.0, 0.0)) -> dict:
    """Run the square; the summary (odometry error, path length, duration)."""
    ssp = ssp or str(Path(plant_fmu).with_suffix(".ssp"))
    write_ssp(ssp, plant_fmu, odometry_fmu)
    ctl = SquarePath(side_m=side_m)

    def step(t, pose):
        x, y, th = pose
        cmd = ctl.step({"odom": codec.odometry(int(round(t * 1e9)), x, y, th, 0.0, 0.0)})
        return cmd.linear, cmd.angular

    return run_square(ssp, step, start, master=master, done=lambda: ctl.done)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("plant_fmu")
    p.add_argument("--master", choices=("libcosim", "ecos"), default="libcosim")
    p.add_argument("--odometry", default=str(DEFAULT_ODOMETRY), help="the odometry FMU")
    p.add_argument("--ssp", help="where to write the SSP (default: beside the plant FMU)")
    args = p.parse_args(argv)
    print(json.dumps(square(args.plant_fmu, args.master, args.ssp, args.odometry), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
