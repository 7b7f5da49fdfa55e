"""The wheel's build step: compiles what the package loads at run time into the wheel.

``pip wheel .``, ``python -m build`` or ``uv build`` (pyproject.toml holds the metadata) run
:class:`BuildPy`, which after copying the Python files compiles into the build directory

- the plant's C kernels: ``plant/kernels/build/libplant_kernels.so`` (plant/kernels/build.py,
  the library whose ABI numbers :mod:`plant.kernels` checks when it loads it);
- the controllers' C kernels: ``controllers/kernels/build/libcontroller_kernels.so`` (the
  same build tool; :mod:`controllers.kernels` checks their ABI numbers);
- the odometry FMUs: ``fmus/build/odometry_fmi2.fmu`` and ``odometry_fmi3.fmu`` (fmus/build.py),

the places where the package looks for them, installed or in a clone. An editable install
(``make setup``) leaves them to ``make``, which builds them into the clone. The wheel holds
compiled code but no Python extension module: it is tagged for the platform only
(``py3-none-<platform>``), one wheel for every Python the project supports.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

from setuptools import Distribution, setup
from setuptools.command.build_py import build_py

try:                                    # setuptools >= 70.1
    from setuptools.command.bdist_wheel import bdist_wheel
except ImportError:                     # pragma: no cover - older setuptools, with wheel
    from wheel.bdist_wheel import bdist_wheel

HERE = os.path.dirname(os.path.abspath(__file__))


class BuildPy(build_py):
    """build_py, then the C kernels and the odometry FMUs into the build directory."""

    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return                      # `make setup` builds them into the clone
        sys.path.insert(0, HERE)        # the build tools of this source tree
        try:
            from fmus.build import build_fmus
            from plant.kernels.build import build as build_kernels
        finally:
            sys.path.remove(HERE)
        kernels = build_kernels(Path(self.build_lib, "plant", "kernels", "build"))
        ours = Path(HERE, "controllers", "kernels")
        controller_kernels = build_kernels(Path(self.build_lib, "controllers", "kernels", "build"),
                                           sorted(ours.glob("*.c")), "libcontroller_kernels")
        fmus = build_fmus(os.path.join(self.build_lib, "fmus", "build"))
        for path in (kernels, controller_kernels, *fmus.values()):
            self.announce(f"built {path}", level=2)


class PlatformDistribution(Distribution):
    """Holds compiled libraries: installed into platlib, a wheel tagged for the platform."""

    def has_ext_modules(self) -> bool:
        return True


class BdistWheel(bdist_wheel):
    """A platform wheel for any Python 3 (no extension module): ``py3-none-<platform>``."""

    def get_tag(self) -> tuple[str, str, str]:
        _, _, plat = super().get_tag()
        return "py3", "none", plat


setup(distclass=PlatformDistribution, cmdclass={"build_py": BuildPy, "bdist_wheel": BdistWheel})
