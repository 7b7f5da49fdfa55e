"""The controllers' compiled kernels (C, built into controllers/kernels/build/ by ``make
setup`` in a clone, or by the wheel's build), loaded with ctypes: the masked row sums of
:mod:`controllers.rowsum` (rowsum.c) and the avoid controller's batch of commands
(avoid.c), both numpy's arithmetic in numpy's order (pairwise.h), and the ball follower's
noise estimate (vision.c: a median of pixel differences, integers only). Built with the plant's
kernels' flags (IEEE double arithmetic as written). There is no silent fallback: without
the library, :func:`function` raises :class:`KernelsMissing`, which says how to build it.
"""
from __future__ import annotations

import ctypes
import sys
from functools import lru_cache
from pathlib import Path

#: where the build puts the library, and its name
BUILD_DIR = Path(__file__).resolve().parent / "build"
LIBRARY = "libcontroller_kernels" + (".dylib" if sys.platform == "darwin" else ".so")
HOW_TO_BUILD = ("`make setup` in a clone, `python -m plant.kernels.build --src "
                "controllers/kernels --out controllers/kernels/build --name "
                "libcontroller_kernels`, or reinstall diffbot-cosim (its wheel's build "
                "compiles them)")


class KernelsMissing(RuntimeError):
    pass


@lru_cache(maxsize=1)
def library() -> ctypes.CDLL:
    path = BUILD_DIR / LIBRARY
    if not path.is_file():
        raise KernelsMissing(f"the controllers' C kernels are not built ({path} is missing): "
                             f"run {HOW_TO_BUILD}")
    return ctypes.CDLL(str(path))


@lru_cache(maxsize=None)
def function(name: str, abi: tuple[str, int], nargs: int):
    """The kernel ``name`` taking ``nargs`` arguments (integers and addresses), its source
    file's ABI checked (``abi``: its ABI function, the number expected): KernelsMissing if
    the library is not built, or was built before it."""
    lib = library()
    got = getattr(lib, abi[0])() if hasattr(lib, abi[0]) else None
    if got != abi[1]:
        raise KernelsMissing(f"the controllers' C kernels are out of date ({abi[0]} {got}, "
                             f"expected {abi[1]}): {HOW_TO_BUILD}")
    fn = getattr(lib, name)
    fn.restype = None
    fn.argtypes = [ctypes.c_int64] * nargs
    return fn
