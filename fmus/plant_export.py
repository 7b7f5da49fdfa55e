"""Export the DART plant as a co-simulation FMU: ``diffbot fmu export-plant``.

    diffbot fmu export-plant [--world W] [--robots R ...] [--fmi 3|2] [--set K=V ...] --out robot.fmu

The FMU is a *tool-coupling* FMU (``needsExecutionTool="true"``), as PythonFMU's are: it
carries no Python, and runs :mod:`fmus.plant_fmu` in a Python >= 3.10 of the machine it runs
on that has diffbot-cosim of the same release series installed (0.1.x for 0.1.0). Its binary
(fmus/plant_wrapper/, compiled here against Python's limited C API, so one binary serves
every Python >= 3.10) uses the host's Python when the host runs one (fmpy, libcosimpy,
ecospy), else the Python that ``$DIFFBOT_FMU_PYTHON`` names, else the active virtual
environment's, else ``python3`` on PATH, whose shared libpython it loads (:mod:`fmus.plant_guest`
says how). No path of the exporting machine is inside; ``--bound-to-this-python`` writes
this interpreter's path into ``resources/plant.cfg`` (the FMU then looks there before the
virtual environment and PATH). ``resources/plant.json`` holds the FMU's variables' layout.
The variables are described in :mod:`fmus.plant_fmu` and docs/fmu.md.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import uuid
from datetime import datetime, timezone
from pathlib import Path
from xml.sax.saxutils import quoteattr

from . import plant_docs
from .build import (FmuBuildError, _shared_library_suffix, _zip_directory, find_c_compiler,
                    fmi_headers_dir, platform_dirs)
from .plant_fmu import Var, layout

MODEL_IDENTIFIER = "diffbot_plant"
AUTHOR = "the diffbot-cosim authors"
LICENSE = "MIT"
_HERE = Path(__file__).resolve().parent
_SHIM_DIR = _HERE / "plant_wrapper"
_UNITS = ("m", "rad", "m/s", "rad/s", "s")
#: the declared type (and its quantity) of a variable of each unit
_TYPES = {"m": ("Position", "Length"), "rad": ("Angle", "Angle"), "m/s": ("Velocity", "Velocity"),
          "rad/s": ("AngularVelocity", "AngularVelocity"), "s": ("Time", "Time")}
_BASE_UNITS = {"m": 'm="1"', "rad": 'rad="1"', "m/s": 'm="1" s="-1"',
               "rad/s": 's="-1" rad="1"', "s": 's="1"'}
DESCRIPTION = ("The diffbot-cosim DART plant (robots, noise, lidar) as a tool-coupling "
               "co-simulation FMU: it runs in a Python >= 3.10 with diffbot-cosim installed "
               "(the host's, else $DIFFBOT_FMU_PYTHON, else the active virtual environment's, "
               "else python3 on PATH); the communication step must be a whole number of "
               "control ticks.")


def package_version() -> str:
    """The installed diffbot-cosim's version (what the FMU asks of the Python it runs in)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("diffbot-cosim")
    except PackageNotFoundError:
        raise FmuBuildError("diffbot-cosim is not installed in this Python (`make setup` or "
                            "pip install): the FMU records its version") from None


def python_include() -> str:
    """This Python's C headers (the shim uses only the limited API of 3.10 from them)."""
    include = sysconfig.get_paths()["include"]
    if not os.path.isfile(os.path.join(include, "Python.h")):
        raise FmuBuildError(f"Python.h not found in {include}: install this Python's "
                            "development headers (python3-dev)")
    return include


def world_layout(world: str, robots: list[str] | None, overrides=()) -> tuple[str, list, float]:
    """(world parameter's start value, [(robot, lidar rays, start pose, (max linear m/s, max
    angular rad/s))], control tick s)."""
    from plant.world import load_world, resolve_world_path, WORLDS_DIR
    spec = load_world(world, list(overrides))
    path = resolve_world_path(world)
    shipped = os.path.dirname(os.path.abspath(path)) == os.path.abspath(WORLDS_DIR)
    name = Path(path).stem if shipped else os.path.abspath(path)
    names = [r.name for r in spec.robots]
    chosen = robots or names
    for r in chosen:
        if r not in names:
            raise FmuBuildError(f"world {world!r} has no robot {r!r} (it has {', '.join(names)})")
    rows = [(r, spec.robot(r).sensors.lidar.num_rays if spec.robot(r).sensors.lidar else 0,
             list(spec.robot(r).pose),
             [spec.robot(r).drive.max_linear_mps, spec.robot(r).drive.max_angular_radps])
            for r in chosen]
    return name, rows, spec.control_tick_s


def _xml_start(v: Var, fmi: int) -> str:
    if v.start is None:
        return ""
    if v.type == "Boolean":
        return "true" if v.start else "false"
    return str(v.start) if v.type == "String" else repr(v.start)


def generation_time() -> str:
    """Now (or $SOURCE_DATE_EPOCH, for a reproducible build) as xs:dateTime in UTC."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    when = (datetime.fromtimestamp(int(epoch), timezone.utc) if epoch and epoch.isdigit()
            else datetime.now(timezone.utc))
    return when.strftime("%Y-%m-%dT%H:%M:%SZ")


def model_description(variables: list[Var], fmi: int, token: str, tick_s: float,
                      version: str = "", generated: str = "") -> str:
    """modelDescription.xml of the plant FMU (FMI 2.0 or 3.0)."""
    units = "\n".join(f'    <Unit name="{u}"><BaseUnit {_BASE_UNITS[u]}/></Unit>' for u in _UNITS)
    cs = (f'  <CoSimulation modelIdentifier="{MODEL_IDENTIFIER}" needsExecutionTool="true" '
          'canHandleVariableCommunicationStepSize="false" canBeInstantiatedOnlyOncePerProcess="false"'
          + (' canGetAndSetFMUState="true" canSerializeFMUState="true"' if fmi == 3
             else ' canGetAndSetFMUstate="true" canSerializeFMUstate="true"')
          + (f' fixedInternalStepSize="{tick_s!r}" hasEventMode="false"/>' if fmi == 3
             else ' canNotUseMemoryManagementFunctions="true"/>'))
    head = (f'<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription fmiVersion="{fmi}.0" '
            f'modelName="diffbot_plant" {"instantiationToken" if fmi == 3 else "guid"}="{token}" '
            f'description={quoteattr(DESCRIPTION)} author={quoteattr(AUTHOR)} '
            f'version={quoteattr(version)} license={quoteattr(LICENSE)} '
            f'generationTool={quoteattr(f"diffbot-cosim {version} (diffbot fmu export-plant)")} '
            + (f'generationDateAndTime="{generated}" ' if generated else "")
            + 'variableNamingConvention="structured"'
            + (' numberOfEventIndicators="0"' if fmi == 2 else "") + ">\n" + cs + "\n"
            f"  <UnitDefinitions>\n{units}\n  </UnitDefinitions>\n"
            f"  <TypeDefinitions>\n{_type_definitions(fmi)}\n  </TypeDefinitions>\n"
            "  <LogCategories>\n"
            '    <Category name="logEvents" description="instantiation and mode changes"/>\n'
            '    <Category name="logStatusWarning" description="warnings"/>\n'
            '    <Category name="logStatusError" description="errors"/>\n'
            "  </LogCategories>\n"
            f'  <DefaultExperiment startTime="0" stopTime="10" stepSize="{tick_s!r}"/>\n'
            "  <ModelVariables>\n")
    rows = [_variable3(v) if fmi == 3 else _variable2(v) for v in variables]
    outputs = [(i + 1, v) for i, v in enumerate(variables) if v.causality == "output"]
    if fmi == 3:
        structure = "".join(f'    <Output valueReference="{v.vr}" dependencies=""/>\n'
                            for _, v in outputs)
        structure += "".join(f'    <InitialUnknown valueReference="{v.vr}"/>\n'
                             for _, v in outputs)
    else:
        structure = ("    <Outputs>\n" + "".join(f'      <Unknown index="{i}" dependencies=""/>\n'
                                                  for i, _ in outputs) + "    </Outputs>\n"
                     "    <InitialUnknowns>\n" + "".join(f'      <Unknown index="{i}"/>\n'
                                                         for i, _ in outputs)
                     + "    </InitialUnknowns>\n")
    return (head + "".join(rows) + "  </ModelVariables>\n  <ModelStructure>\n" + structure
            + "  </ModelStructure>\n</fmiModelDescription>\n")


def _type_definitions(fmi: int) -> str:
    return "\n".join(
        f'    <Float64Type name="{t}" quantity="{q}" unit="{u}"/>' if fmi == 3 else
        f'    <SimpleType name="{t}"><Real quantity="{q}" unit="{u}"/></SimpleType>'
        for u, (t, q) in _TYPES.items())


def _declared(v: Var) -> str:
    return f' declaredType="{_TYPES[v.unit][0]}"' if v.unit in _TYPES else ""


def _common(v: Var) -> str:
    return (f'name={quoteattr(v.name)} valueReference="{v.vr}" causality="{v.causality}" '
            f'variability="{v.variability}" description={quoteattr(v.description)}')


def _range(v: Var) -> str:
    return "".join(f' {k}="{getattr(v, k)!r}"' for k in ("min", "max")
                   if getattr(v, k) is not None)


def _variable3(v: Var) -> str:
    attrs = _common(v)
    if v.causality == "output":
        attrs += ' initial="calculated"'
    if v.unit:
        attrs += f'{_declared(v)} unit="{v.unit}"'
    attrs += _range(v)
    start = _xml_start(v, 3)
    if v.type == "String":
        return f"    <String {attrs}><Start value={quoteattr(start)}/></String>\n"
    if start:
        attrs += f' start="{start}"'
    if v.size:
        return f'    <{v.type} {attrs}><Dimension start="{v.size}"/></{v.type}>\n'
    return f"    <{v.type} {attrs}/>\n"


def _variable2(v: Var) -> str:
    attrs = _common(v) + (' initial="calculated"' if v.causality == "output" else "")
    kind = {"Float64": "Real", "Int32": "Integer", "Boolean": "Boolean", "String": "String"}[v.type]
    inner = (f'{_declared(v)} unit="{v.unit}"' if v.unit else "") + _range(v)
    start = _xml_start(v, 2)
    if start:
        inner += f" start={quoteattr(start)}"
    return f"    <ScalarVariable {attrs}><{kind}{inner}/></ScalarVariable>\n"


def compile_shim(fmi: int, binary: Path, include: str) -> None:
    """The C shim for FMI ``fmi`` against this interpreter's headers, limited API of 3.10
    (never linked with libpython: the C API is looked up at run time)."""
    sources = [_SHIM_DIR / name for name in ("plant_python.c", "plant_locate.c", "plant_state.c",
                                             f"fmi{fmi}Functions.c")]
    binary.parent.mkdir(parents=True, exist_ok=True)
    command = [*find_c_compiler(), "-std=gnu99", "-O2", "-fPIC", "-shared", "-fvisibility=hidden",
               "-Wall", "-Wno-unused-parameter", "-I", str(fmi_headers_dir()), "-I", include,
               "-I", str(_SHIM_DIR), *map(str, sources), "-o", str(binary), "-ldl", "-lpthread"]
    try:
        result = subprocess.run(command, capture_output=True, text=True)
    except OSError as e:
        raise FmuBuildError(f"no C compiler found: install gcc or set CC ({e})") from e
    if result.returncode != 0:
        raise FmuBuildError(f"compiling the plant FMU's shim failed:\n{' '.join(command)}\n"
                            f"{result.stdout}{result.stderr}")


def export_plant(out: str | os.PathLike, world: str = "living_room", robots: list[str] | None = None,
                 fmi: int = 3, overrides=(), seed: int = 0, bound: bool = False,
                 scan_scalars: bool = False) -> Path:
    """Write the plant FMU to ``out``; returns its path. ``bound``: record this Python's path
    (module docstring); ``scan_scalars``: FMI 3's scan as scalars, as FMI 2's."""
    if fmi not in (2, 3):
        raise ValueError(f"fmi must be 2 or 3, not {fmi!r}")
    include = python_include()
    version = package_version()
    cfg = {"package": "diffbot-cosim", "package_version": version}
    if bound:
        cfg["python"] = str(Path(sys.executable).absolute())
    world_name, rows, tick_s = world_layout(world, robots, overrides)
    scan_scalars = scan_scalars and fmi == 3
    variables = layout(rows, fmi, world_name, seed, scan_scalars)
    token = "{%s}" % uuid.uuid5(uuid.NAMESPACE_URL, json.dumps(
        ["diffbot-plant", fmi, world_name, rows, list(overrides), tick_s, scan_scalars]))
    target = Path(out)
    target.parent.mkdir(parents=True, exist_ok=True)
    fmi2_dir, fmi3_dir = platform_dirs()
    with tempfile.TemporaryDirectory(prefix="plant_fmu_") as tmp:
        stage = Path(tmp)
        (stage / "modelDescription.xml").write_text(model_description(
            variables, fmi, token, tick_s, version, generation_time()), encoding="utf-8")
        (stage / "documentation").mkdir()
        (stage / "documentation" / plant_docs.file_name(fmi)).write_text(
            plant_docs.page(variables, fmi, world_name, tick_s, version), encoding="utf-8")
        resources = stage / "resources"
        resources.mkdir()
        (resources / "plant.json").write_text(json.dumps(
            {"token": token, "fmi": fmi, "world": world_name, "robots": rows, "seed": seed,
             "tick_s": tick_s, "overrides": list(overrides), "scan_scalars": scan_scalars},
            indent=1), encoding="utf-8")
        (resources / "plant.cfg").write_text("".join(f"{k}={v}\n" for k, v in cfg.items()),
                                             encoding="utf-8")
        shutil.copyfile(_HERE / "plant_guest.py", resources / "plant_guest.py")
        sources = stage / "sources"
        sources.mkdir()
        for src in sorted(_SHIM_DIR.iterdir()):
            if src.suffix in (".c", ".h"):
                shutil.copyfile(src, sources / src.name)
        binary = (stage / "binaries" / (fmi3_dir if fmi == 3 else fmi2_dir)
                  / (MODEL_IDENTIFIER + _shared_library_suffix()))
        compile_shim(fmi, binary, include)
        _zip_directory(stage, target)
    return target


def main(argv: list[str] | None = None, prog: str = "diffbot fmu export-plant") -> int:
    p = argparse.ArgumentParser(prog=prog, description="Export the DART plant (its robots, "
                                "noise and lidar) as a tool-coupling co-simulation FMU.")
    p.add_argument("--world", default="living_room", help="world file or shipped name "
                   "(default living_room)")
    p.add_argument("--robots", nargs="+", metavar="ROBOT", help="the robots given inputs and "
                   "outputs (default: every robot of the world)")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=3, help="FMI version (default 3)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="world file override, as diffbot plant --set (repeatable)")
    p.add_argument("--seed", type=int, default=0, help="the seed parameter's start value")
    p.add_argument("--bound-to-this-python", dest="bound", action="store_true",
                   help="write this interpreter's path into the FMU: it runs there (unless "
                   "$DIFFBOT_FMU_PYTHON says otherwise) and nowhere that path does not exist")
    p.add_argument("--scan-scalars", action="store_true", help="FMI 3: the lidar scan as "
                   "R.scan[1] ... R.scan[n] (as in FMI 2), not one array: for masters that "
                   "take no arrays")
    p.add_argument("--out", required=True, help="the FMU file to write (robot.fmu)")
    args = p.parse_args(argv)
    from plant.world import WorldError
    try:
        path = export_plant(args.out, args.world, args.robots, args.fmi, args.overrides,
                            args.seed, args.bound, args.scan_scalars)
    except (FmuBuildError, WorldError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2 if isinstance(e, WorldError) else 1
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
