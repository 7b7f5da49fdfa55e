"""Build the odometry FMUs (FMI 2.0 and FMI 3.0) from the C sources in fmus/, and the
small test models of fmus/models/ (stairs: FMI 2 Integer counter; bouncing: FMI 3 ball;
gain: FMI 3 y = k u; signals: FMI 3 Boolean, String, Float64 arrays) that the tests run
on the bus with no mapping (docs/fmu.md).

Each FMU offers Model Exchange and Co-Simulation, ships its binary for the
build platform and its C sources (so that ``fmpy compile X.fmu`` rebuilds it
on another platform). The FMI headers come from the installed fmpy
(``fmpy/c-code``); they are neither copied into the repository nor into the
FMU: an importer that compiles the sources supplies its own (``fmpy compile``
puts its ``c-code`` directory on the include path).

Usage::

    python -m fmus.build [--out DIR]

or from Python::

    from fmus.build import build_fmus
    paths = build_fmus("fmus/build")   # {"fmi2": Path(...), "fmi3": Path(...)}

The output is deterministic: the same sources, compiler and flags give
byte-identical FMUs (fixed ZIP timestamps and order, no paths in the binary).
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path
from xml.etree import ElementTree

__all__ = [
    "FmuBuildError",
    "MODEL_IDENTIFIER",
    "FMU_NAMES",
    "find_c_compiler",
    "fmi_headers_dir",
    "platform_dirs",
    "build_fmu",
    "build_fmus",
    "main",
]

MODEL_IDENTIFIER = "odometry"

#: file names of the built FMUs, by FMI major version
FMU_NAMES = {2: "odometry_fmi2.fmu", 3: "odometry_fmi3.fmu"}

_HERE = Path(__file__).resolve().parent
_WRAPPER_DIR = _HERE / "wrapper"
#: the test models: fmus/models/<name>/ (config.h, model.c, modelDescription<N>.xml)
MODELS_DIR = _HERE / "models"
TEST_MODELS = ("stairs", "bouncing", "gain", "signals", "square")

_WRAPPERS = {
    2: (_WRAPPER_DIR / "fmi2Functions.c", "fmi2Functions.c"),
    3: (_WRAPPER_DIR / "fmi3Functions.c", "fmi3Functions.c"),
}


def _model_dir(model: str) -> Path:
    return _HERE / "odometry" if model == MODEL_IDENTIFIER else MODELS_DIR / model


def _common_sources(model: str) -> list[tuple[Path, str]]:
    """sources/ of the FMU: (file in the repository, name in sources/)."""
    d = _model_dir(model)
    return [(d / "config.h", "config.h"), (_WRAPPER_DIR / "model.h", "model.h"),
            (d / "model.c", "model.c")]


def model_versions(model: str) -> list[int]:
    """The FMI versions a model has a model description for."""
    return [v for v in (2, 3) if (_model_dir(model) / f"modelDescription{v}.xml").is_file()]


def fmu_name(model: str, fmi_version: int) -> str:
    return f"{model}_fmi{fmi_version}.fmu"

_CFLAGS = ["-std=c99", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-Wall", "-Wextra"]

# fixed ZIP metadata for reproducible archives
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


class FmuBuildError(RuntimeError):
    """The FMUs could not be built (no compiler, compiler error, inconsistent sources)."""


def find_c_compiler() -> list[str]:
    """Return the C compiler command: ``$CC`` if set, else the first of cc, gcc, clang on PATH
    (the plant's kernels are built with the same one: :func:`plant.kernels.build.find_c_compiler`).

    Raises FmuBuildError("no C compiler found: install gcc or set CC") if there is none.
    """
    from plant.kernels.build import find_c_compiler as find
    try:
        return find()
    except RuntimeError as exc:
        raise FmuBuildError(str(exc)) from None


def fmi_headers_dir() -> Path:
    """Directory with the FMI 2 and FMI 3 C headers shipped by the installed fmpy."""
    try:
        import fmpy
    except ImportError as e:  # pragma: no cover - fmpy is a project dependency
        raise FmuBuildError("fmpy is not installed: it provides the FMI headers (pip install fmpy)") from e
    path = Path(fmpy.__file__).resolve().parent / "c-code"
    for header in ("fmi2Functions.h", "fmi3Functions.h"):
        if not (path / header).is_file():
            raise FmuBuildError(f"{header} not found in {path}: reinstall fmpy")
    return path


def platform_dirs() -> tuple[str, str]:
    """Names of the binaries/ folder for this platform: (FMI 2 name, FMI 3 platform tuple).

    For example ("linux64", "x86_64-linux") or ("linux64", "aarch64-linux").
    """
    if sys.platform.startswith("linux"):
        system = "linux"
    elif sys.platform == "darwin":
        system = "darwin"
    else:
        raise FmuBuildError(
            f"building on {sys.platform} is not supported by fmus/build.py: "
            "build the FMU on Linux or macOS, then run `fmpy compile` on this platform")
    machine = platform.machine().lower()
    bits64 = sys.maxsize > 2**32
    if machine in {"x86_64", "amd64", "x64", "i386", "i686", "x86"}:
        architecture = "x86_64" if bits64 else "x86"
    elif machine in {"aarch64", "arm64", "armv8", "armv8l"}:
        architecture = "aarch64"
    else:
        raise FmuBuildError(f"unsupported architecture: {platform.machine()}")
    return f"{system}{64 if bits64 else 32}", f"{architecture}-{system}"


def _shared_library_suffix() -> str:
    return ".dylib" if sys.platform == "darwin" else ".so"


def _read_token_from_config(model: str = MODEL_IDENTIFIER) -> str:
    config = _model_dir(model) / "config.h"
    text = config.read_text(encoding="utf-8")
    match = re.search(r'#define\s+INSTANTIATION_TOKEN\s+"([^"]+)"', text)
    if not match:
        raise FmuBuildError(f"INSTANTIATION_TOKEN not found in {config}")
    return match.group(1)


def _check_model_description(fmi_version: int, model: str = MODEL_IDENTIFIER) -> None:
    """The model description must agree with config.h and the shipped sources (the
    odometry FMU offers both interfaces, a test model at least co-simulation)."""
    path = _model_dir(model) / f"modelDescription{fmi_version}.xml"
    root = ElementTree.parse(path).getroot()
    token = root.get("guid" if fmi_version == 2 else "instantiationToken")
    expected = _read_token_from_config(model)
    if token != expected:
        raise FmuBuildError(f"{path.name}: token {token!r} differs from INSTANTIATION_TOKEN {expected!r} in config.h")
    c_files = sorted(name for _, name in _common_sources(model) + [_WRAPPERS[fmi_version]]
                     if name.endswith(".c"))
    for interface in ("ModelExchange", "CoSimulation"):
        element = root.find(interface)
        if element is None and (interface == "CoSimulation" or model == MODEL_IDENTIFIER) \
                or element is not None and element.get("modelIdentifier") != model:
            raise FmuBuildError(f"{path.name}: <{interface} modelIdentifier={model!r}> missing")
        if fmi_version == 2 and element is not None:
            listed = sorted(f.get("name") for f in element.findall("SourceFiles/File"))
            if listed != c_files:
                raise FmuBuildError(f"{path.name}: <{interface}><SourceFiles> lists {listed}, expected {c_files}")
    if fmi_version == 3:
        build = ElementTree.parse(_model_dir(model) / "buildDescription.xml").getroot()
        listed = sorted(f.get("name") for f in build.iter("SourceFile"))
        if listed != c_files:
            raise FmuBuildError(f"buildDescription.xml lists {listed}, expected {c_files}")


def _compile(cc: list[str], stage: Path, fmi_version: int, binary: Path) -> None:
    """Compile sources/*.c of the staged FMU into binary (paths relative to stage)."""
    c_files = sorted(p.relative_to(stage).as_posix() for p in (stage / "sources").glob("*.c"))
    binary.parent.mkdir(parents=True, exist_ok=True)
    command = [
        *cc, *_CFLAGS,
        "-I", str(fmi_headers_dir()),
        "-I", "sources",
        *c_files,
        "-o", binary.relative_to(stage).as_posix(),
        "-lm",
    ]
    try:
        result = subprocess.run(command, cwd=stage, capture_output=True, text=True)
    except OSError as e:
        raise FmuBuildError(f"no C compiler found: install gcc or set CC ({e})") from e
    if result.returncode != 0:
        raise FmuBuildError(
            f"compiling the FMI {fmi_version} FMU failed (exit code {result.returncode}):\n"
            f"$ {shlex.join(command)}\n{result.stdout}{result.stderr}")


def _zip_directory(stage: Path, target: Path) -> None:
    """Zip stage into target with sorted entries and fixed metadata (reproducible)."""
    files = sorted(p for p in stage.rglob("*") if p.is_file())
    tmp = target.with_name(target.name + ".tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for path in files:
            name = path.relative_to(stage).as_posix()
            info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.create_system = 3  # unix, so that the permissions below are honoured
            executable = name.startswith("binaries/")
            info.external_attr = ((0o755 if executable else 0o644) | 0o100000) << 16
            zf.writestr(info, path.read_bytes())
    os.replace(tmp, target)


def build_fmu(fmi_version: int, out_dir: str | os.PathLike = "fmus/build",
              model: str = MODEL_IDENTIFIER) -> Path:
    """Build the FMI ``fmi_version`` (2 or 3) FMU of ``model`` (the odometry FMU, or a test
    model of fmus/models) into ``out_dir``; return its path."""
    if fmi_version not in (2, 3):
        raise ValueError(f"fmi_version must be 2 or 3, not {fmi_version!r}")

    cc = find_c_compiler()
    _check_model_description(fmi_version, model)
    fmi2_platform, fmi3_platform = platform_dirs()
    platform_dir = fmi2_platform if fmi_version == 2 else fmi3_platform

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    target = out / fmu_name(model, fmi_version)
    model_dir = _model_dir(model)

    with tempfile.TemporaryDirectory(prefix=f"{model}_fmi{fmi_version}_") as tmp:
        stage = Path(tmp)
        sources = stage / "sources"
        sources.mkdir()
        for src, name in _common_sources(model) + [_WRAPPERS[fmi_version]]:
            shutil.copyfile(src, sources / name)
        if fmi_version == 3:
            shutil.copyfile(model_dir / "buildDescription.xml", sources / "buildDescription.xml")
        shutil.copyfile(model_dir / f"modelDescription{fmi_version}.xml",
                        stage / "modelDescription.xml")

        binary = stage / "binaries" / platform_dir / (model + _shared_library_suffix())
        _compile(cc, stage, fmi_version, binary)

        _zip_directory(stage, target)

    return target


def build_fmus(out_dir: str | os.PathLike = "fmus/build") -> dict[str, Path]:
    """Build odometry_fmi2.fmu and odometry_fmi3.fmu into ``out_dir``.

    Returns {"fmi2": path, "fmi3": path}. Raises FmuBuildError (e.g. no C compiler).
    """
    return {f"fmi{version}": build_fmu(version, out_dir) for version in (2, 3)}


def build_test_fmus(out_dir: str | os.PathLike = "fmus/build") -> dict[str, Path]:
    """Build the test models into ``out_dir``: {"stairs_fmi2": path, ...}."""
    return {f"{m}_fmi{v}": build_fmu(v, out_dir, m) for m in TEST_MODELS
            for v in model_versions(m)}


def main(argv: list[str] | None = None, prog: str = "python -m fmus.build") -> int:
    """Command line: ``python -m fmus.build [--out DIR]`` (``diffbot fmu build``); prints the
    built paths."""
    parser = argparse.ArgumentParser(prog=prog, description=" ".join(
        __doc__.split("\n\n")[0].split()))
    parser.add_argument("--out", default="fmus/build", help="output directory (default: fmus/build)")
    args = parser.parse_args(argv)
    try:
        paths = {**build_fmus(args.out), **build_test_fmus(args.out)}
    except FmuBuildError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    for path in paths.values():
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
