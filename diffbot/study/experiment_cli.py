"""``diffbot experiment NAME --out DIR``: the command line of the study's experiments
(:mod:`diffbot.study.experiments`, :mod:`diffbot.study.experiment_sensors`)."""
from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import time


from bus.cliargs import ArgumentParser, nonneg_float, nonneg_int, positive_float, positive_int
from bus.jsonio import write_json
from plant.world import WorldError, load_world

from .experiment_bus import (ExperimentError)

from .experiments import (EXIT_BAD_INPUT, EXIT_FAILED, _parse_pose, motion_noise, noisy_odometry)
from .experiment_sensors import camera, lidar, noisy_lidar


# ------------------------------------------------------------------ command line
EXPERIMENTS = {
    "motion-noise": (motion_noise, "Fig. 4: end positions of N noisy straight 0.3 m runs "
                                   "(one plant, sim/reset between runs)"),
    "lidar": (lidar, "Fig. 5: a lidar scan in the living room; room from above + polar plot"),
    "noisy-lidar": (noisy_lidar, "Fig. 9: noiseless vs noisy (Webots 0.2 = 16 m) scan"),
    "noisy-odometry": (noisy_odometry, "Fig. 10: the 1.5 m square with encoder noise 0.2 rad"),
    "camera": (camera, "Fig. 8/11: camera image without and with noise (Webots 0.2)"),
}


def experiment_list() -> str:
    return "\n".join(f"  {n:15s} {d}" for n, (_, d) in EXPERIMENTS.items())


def build_parser(name: str) -> argparse.ArgumentParser:
    p = ArgumentParser(prog=f"diffbot experiment {name}",
                                description=EXPERIMENTS[name][1])
    p.add_argument("--out", default=os.path.join("out", "experiments", name),
                   help="output directory (default out/experiments/NAME)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="noise seed (default 0)")
    if name != "noisy-odometry":            # the square scenario names its world and robot
        p.add_argument("--world", default="living_room", help="world name or file")
        p.add_argument("--robot", default="robot1")
    p.add_argument("--timeout", type=positive_float, default=600.0, metavar="S",
                   help="wall-clock limit (default 600 s)")
    if name == "motion-noise":
        p.add_argument("--runs", type=positive_int, default=100, help="number of runs (default 100)")
        p.add_argument("--command-noise", type=nonneg_float, default=0.1, metavar="RADPS",
                       help="std of the Gaussian noise on each commanded wheel speed, added "
                            "every control tick, rad/s (default 0.1)")
        p.add_argument("--friction", type=positive_float, default=0.4,
                       help="wheel-floor friction coefficient (default 0.4, as the study)")
        p.add_argument("--wheel-speed", type=positive_float, default=2.5, metavar="RADPS",
                       help="wheel speed of the open-loop drive, rad/s (default 2.5 = 0.3 m/s)")
        p.add_argument("--distance", type=positive_float, default=0.3, metavar="M",
                       help="distance without noise or slip, m (default 0.3)")
        p.add_argument("--settle", type=nonneg_float, default=0.5, metavar="S",
                       help="time stopped before the GPS reading, s (default 0.5)")
    if name != "noisy-odometry":           # the square starts at the world's start pose
        p.add_argument("--pose", default=None, metavar="X,Y,YAW",
                       help="robot pose (m, m, rad); default: the world's start pose"
                            + (" (camera: 0,0,-0.6, facing the dining corner)"
                               if name == "camera" else ""))
    if name == "noisy-lidar":
        p.add_argument("--lidar-noise", type=nonneg_float, default=0.2, metavar="WEBOTS",
                       help="Webots lidar noise: std relative to max range (default 0.2)")
        p.add_argument("--lidar-noise-std", type=nonneg_float, default=None, metavar="M",
                       help="lidar noise std in metres (overrides --lidar-noise)")
    if name == "noisy-odometry":
        p.add_argument("--encoder-noise", type=nonneg_float, default=0.2, metavar="RAD",
                       help="Webots PositionSensor noise = std per reading, rad (default 0.2)")
        p.add_argument("--side", type=positive_float, default=1.5, metavar="M",
                       help="side of the square, m (default 1.5)")
        p.add_argument("--odometry", choices=("fmu", "python"), default="fmu",
                       help="odometry node: the C FMU (default, as the square scenario) or "
                            "the Python reference")
    if name == "camera":
        p.add_argument("--camera-noise", type=nonneg_float, default=0.2, metavar="WEBOTS",
                       help="Webots camera noise: std as a fraction of 255 (default 0.2)")
        p.add_argument("--camera-noise-std", type=nonneg_float, default=None, metavar="LEVELS",
                       help="camera noise std in 0-255 levels (overrides --camera-noise)")
    return p


def _check(args) -> None:
    for key in ("runs",):
        if getattr(args, key, 1) < 1:
            raise ValueError(f"--{key} must be >= 1")
    for key in ("command_noise", "lidar_noise", "lidar_noise_std", "encoder_noise",
                "camera_noise", "camera_noise_std"):
        v = getattr(args, key, None)
        if v is not None and (not math.isfinite(v) or v < 0):
            raise ValueError(f"--{key.replace('_', '-')} must be a finite number >= 0, got {v}")
    for key in ("friction", "wheel_speed", "distance", "settle", "side", "timeout"):
        v = getattr(args, key, None)
        if v is not None and (not math.isfinite(v) or v <= 0):
            raise ValueError(f"--{key.replace('_', '-')} must be > 0, got {v}")
    if args.seed < 0:
        raise ValueError("--seed must be >= 0")
    if hasattr(args, "pose"):
        args.pose = _parse_pose(args.pose)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    usage = (f"usage: diffbot experiment NAME --out DIR [--runs N] [--seed S] [options]\n"
             f"experiments:\n{experiment_list()}")
    if not argv or argv[0] in ("-h", "--help"):
        print(usage, file=sys.stdout if argv else sys.stderr)
        return 0 if argv else EXIT_BAD_INPUT
    name = argv[0]
    if name not in EXPERIMENTS:
        print(f"diffbot experiment: unknown experiment {name!r}\n{usage}", file=sys.stderr)
        return EXIT_BAD_INPUT
    args = build_parser(name).parse_args(argv[1:])
    try:
        _check(args)
        load_world(getattr(args, "world", "living_room"))  # a bad world: exit 2 at once
    except (ValueError, WorldError) as exc:
        print(f"diffbot experiment {name}: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    args.out = os.path.abspath(args.out)
    os.makedirs(args.out, exist_ok=True)
    t0 = time.monotonic()

    def on_term(signum, frame):             # SIGTERM unwinds like Ctrl-C: plants are stopped
        raise KeyboardInterrupt
    old_term = signal.signal(signal.SIGTERM, on_term)
    try:
        result = EXPERIMENTS[name][0](args)
    except KeyboardInterrupt:
        print(f"diffbot experiment {name}: interrupted", file=sys.stderr)
        return 130
    except WorldError as exc:
        print(f"diffbot experiment {name}: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ExperimentError as exc:
        print(f"diffbot experiment {name}: {exc}", file=sys.stderr)
        return EXIT_FAILED
    finally:
        signal.signal(signal.SIGTERM, old_term)
    summary = {"experiment": name, "seed": args.seed, **result,
               "wall_time_s": time.monotonic() - t0}
    write_json(os.path.join(args.out, "summary.json"), summary)
    files = sorted(f for f in os.listdir(args.out) if f.endswith((".png", ".csv", ".json")))
    print(f"diffbot experiment {name}: done in {summary['wall_time_s']:.1f} s; "
          f"{', '.join(files)} in {args.out}", file=sys.stderr)
    return 0
