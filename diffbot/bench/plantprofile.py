"""``python -m diffbot.bench.plantprofile SCENARIO...``: py-spy the plant of a running
scenario and print where its tick goes (phases, top functions) as markdown tables; the
profile of docs/benchmarks.md. ``diffbot bench --suite tick`` gives the phase shares."""
from __future__ import annotations

import argparse
import sys
import tempfile

from .tick import SCENARIOS, profile_run


def print_profile(name: str, p: dict) -> None:
    print(f"## {name}: {p['samples']} samples, real-time factor "
          f"{p['real_time_factor'] or 0:.1f}x (profiled), per tick ms {p['plant_per_tick_ms']}")
    print("| phase | share |\n|---|---|")
    for k, v in sorted(p["phases"].items(), key=lambda kv: -kv[1]):
        print(f"| {k} | {100 * v:.1f} % |")
    for what in ("self", "inclusive"):
        print(f"\n| function ({what}) | share |\n|---|---|")
        for f, v in p[what]:
            print(f"| `{f}` | {100 * v:.1f} % |")
    print()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m diffbot.bench.plantprofile",
                                 description="py-spy the plant of a running scenario")
    ap.add_argument("scenario", nargs="+", choices=sorted(SCENARIOS))
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--rate", type=int, default=500)
    ap.epilog = "after --: more arguments for diffbot run"
    argv = list(sys.argv[1:] if argv is None else argv)
    extra: list[str] = []
    if "--" in argv:                    # (argparse's REMAINDER would take --seconds too)
        cut = argv.index("--")
        argv, extra = argv[:cut], argv[cut + 1:]
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenario:
            print_profile(name, profile_run(name, SCENARIOS[name] + extra, tmp,
                                            args.seconds, args.rate))
    return 0


if __name__ == "__main__":
    sys.exit(main())
