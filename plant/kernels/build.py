"""Build the plant's C kernels (plant/kernels/*.c) into one shared library that
:mod:`plant.kernels` loads: ``python -m plant.kernels.build`` (``make setup`` runs it).

Needs only a C compiler (``$CC``, else cc, gcc or clang). The flags keep IEEE double
arithmetic as written (``-ffp-contract=off``: no fused multiply-adds, which would change
the last bit of a range and so a recording's bytes; no ``-ffast-math``; ``-fno-math-errno`` only lets ``sqrt`` be one instruction).
"""
from __future__ import annotations

import argparse
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from plant.kernels import BUILD_DIR, LIBRARY

HERE = Path(__file__).resolve().parent
SOURCES = sorted(HERE.glob("*.c"))
CFLAGS = ["-std=c99", "-O3", "-fPIC", "-shared", "-fvisibility=hidden", "-ffp-contract=off",
          "-fno-fast-math", "-fno-math-errno", "-Wall", "-Wextra"]


def find_c_compiler() -> list[str]:
    """``$CC`` if set, else the first of cc, gcc, clang on PATH (RuntimeError if none)."""
    cc = os.environ.get("CC", "").strip()
    if cc:
        command = shlex.split(cc)
        if shutil.which(command[0]):
            return command
        raise RuntimeError(f"no C compiler found: install gcc or set CC (CC={cc!r} is not on PATH)")
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return [path]
    raise RuntimeError("no C compiler found: install gcc or set CC")


def build(out_dir: Path = BUILD_DIR, sources: list[Path] | None = None,
          name: str | None = None) -> Path:
    """Compile every kernel source (``sources``: the .c files of another folder, e.g. the
    controllers' kernels) into ``out_dir``/LIBRARY (``name``: another library's name, the
    platform's suffix added), written atomically."""
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / (LIBRARY if name is None else name + Path(LIBRARY).suffix)
    fd, tmp = tempfile.mkstemp(prefix=".lib-", suffix=target.suffix, dir=out_dir)
    os.close(fd)
    cmd = [*find_c_compiler(), *CFLAGS, "-pthread", "-o", tmp,
           *map(str, SOURCES if sources is None else sources), "-lm"]
    try:
        subprocess.run(cmd, check=True)
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return target


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m plant.kernels.build", description=__doc__)
    p.add_argument("--out", type=Path, default=BUILD_DIR, help="output folder (default: %(default)s)")
    p.add_argument("--src", type=Path, help="build the .c files of this folder instead "
                   "(with --out and --name)")
    p.add_argument("--name", help="the library's name, without the platform's suffix")
    args = p.parse_args(argv)
    try:
        path = build(args.out, sorted(args.src.glob("*.c")) if args.src else None, args.name)
    except (RuntimeError, subprocess.CalledProcessError) as e:
        print(f"plant kernels: {e}", file=sys.stderr)
        return 1
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
