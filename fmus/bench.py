"""Cost of one odometry FMU step, from Python (fmpy) down to plain C.

:func:`benchmarks` returns ``(name, description, fn)`` triples; ``fn(number)`` performs
``number`` operations and returns the total seconds they took (like the inner loop of
:mod:`timeit`), so a harness (``diffbot bench``) picks ``number`` and repeats. One
operation is one communication step: set the two wheel speeds, ``doStep``, get x, y, theta.

- through fmpy, FMI 2 and FMI 3 (ctypes calls from Python, timed with perf_counter);
- in C, FMI 2 and FMI 3: a tiny driver (compiled on first use with the system C compiler
  against fmpy's FMI headers) ``dlopen``s the FMU's binary, makes the same calls in a C
  loop and times it with ``clock_gettime``; the seconds returned are measured in C;
- one tick of ``diffbot fmu-node`` without the bus: joint_states sample in, FMI 2 step,
  nav_msgs/Odometry message out.

The FMUs come from ``fmus/build`` when built there (``diffbot fmu build``), else they are
built into a temporary directory. Does not import ``diffbot``.

    python -m fmus.bench            # one quick run of each, printed per step
"""
from __future__ import annotations

import atexit
import ctypes
import shutil
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path
from typing import Callable

from . import build as fmu_build

H = 0.01                                    # communication step, s
INPUTS = ("omega_left", "omega_right")
OUTPUTS = ("x", "y", "theta")

_DRIVER_C = r"""
#include <dlfcn.h>
#include <stdlib.h>
#include <time.h>
#include "fmi2Functions.h"
#include "fmi3Functions.h"

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void log2(fmi2ComponentEnvironment e, fmi2String n, fmi2Status s, fmi2String c,
                 fmi2String m, ...) { (void)e; (void)n; (void)s; (void)c; (void)m; }
static void log3(fmi3InstanceEnvironment e, fmi3Status s, fmi3String c, fmi3String m) {
    (void)e; (void)s; (void)c; (void)m; }

volatile double sink;

#define SYM(type, name) type *name = (type *)dlsym(lib, #name); if (!name) { dlclose(lib); return -2.0; }

/* seconds for n steps (set 2 inputs, doStep, get 3 outputs); < 0 on failure */
double bench_fmi2(const char *path, const char *guid, const char *resources,
                  const unsigned int *vr_in, const unsigned int *vr_out, long n) {
    void *lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) return -1.0;
    SYM(fmi2InstantiateTYPE, fmi2Instantiate)
    SYM(fmi2SetupExperimentTYPE, fmi2SetupExperiment)
    SYM(fmi2EnterInitializationModeTYPE, fmi2EnterInitializationMode)
    SYM(fmi2ExitInitializationModeTYPE, fmi2ExitInitializationMode)
    SYM(fmi2SetRealTYPE, fmi2SetReal)
    SYM(fmi2DoStepTYPE, fmi2DoStep)
    SYM(fmi2GetRealTYPE, fmi2GetReal)
    SYM(fmi2TerminateTYPE, fmi2Terminate)
    SYM(fmi2FreeInstanceTYPE, fmi2FreeInstance)
    fmi2CallbackFunctions cb = {log2, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("bench", fmi2CoSimulation, guid, resources, &cb,
                                      fmi2False, fmi2False);
    if (!c) { dlclose(lib); return -3.0; }
    fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    double u[2] = {4.0, 4.5}, y[3] = {0.0, 0.0, 0.0}, t = 0.0, h = %(H)r;
    int bad = 0;
    double t0 = now();
    for (long i = 0; i < n; i++) {
        u[1] = 4.5 + 1e-3 * (double)(i & 7);
        bad |= fmi2SetReal(c, vr_in, 2, u);
        bad |= fmi2DoStep(c, t, h, fmi2True);
        bad |= fmi2GetReal(c, vr_out, 3, y);
        t += h;
    }
    double elapsed = now() - t0;
    sink = y[0] + y[1] + y[2];
    fmi2Terminate(c);
    fmi2FreeInstance(c);
    dlclose(lib);
    return bad ? -4.0 : elapsed;
}

double bench_fmi3(const char *path, const char *token, const char *resources,
                  const unsigned int *vr_in, const unsigned int *vr_out, long n) {
    void *lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) return -1.0;
    SYM(fmi3InstantiateCoSimulationTYPE, fmi3InstantiateCoSimulation)
    SYM(fmi3EnterInitializationModeTYPE, fmi3EnterInitializationMode)
    SYM(fmi3ExitInitializationModeTYPE, fmi3ExitInitializationMode)
    SYM(fmi3SetFloat64TYPE, fmi3SetFloat64)
    SYM(fmi3DoStepTYPE, fmi3DoStep)
    SYM(fmi3GetFloat64TYPE, fmi3GetFloat64)
    SYM(fmi3TerminateTYPE, fmi3Terminate)
    SYM(fmi3FreeInstanceTYPE, fmi3FreeInstance)
    fmi3Instance c = fmi3InstantiateCoSimulation("bench", token, resources, fmi3False, fmi3False,
                                                 fmi3False, fmi3False, NULL, 0, NULL, log3, NULL);
    if (!c) { dlclose(lib); return -3.0; }
    fmi3EnterInitializationMode(c, fmi3False, 0.0, 0.0, fmi3False, 0.0);
    fmi3ExitInitializationMode(c);
    double u[2] = {4.0, 4.5}, y[3] = {0.0, 0.0, 0.0}, t = 0.0, h = %(H)r, last;
    fmi3Boolean event, terminate, early;
    int bad = 0;
    double t0 = now();
    for (long i = 0; i < n; i++) {
        u[1] = 4.5 + 1e-3 * (double)(i & 7);
        bad |= fmi3SetFloat64(c, vr_in, 2, u, 2);
        bad |= fmi3DoStep(c, t, h, fmi3True, &event, &terminate, &early, &last);
        bad |= fmi3GetFloat64(c, vr_out, 3, y, 3);
        t += h;
    }
    double elapsed = now() - t0;
    sink = y[0] + y[1] + y[2];
    fmi3Terminate(c);
    fmi3FreeInstance(c);
    dlclose(lib);
    return bad ? -4.0 : elapsed;
}
""" % {"H": H}

_cache: dict = {}


def _tmpdir() -> Path:
    if "tmp" not in _cache:
        d = tempfile.mkdtemp(prefix="fmu-bench-")
        atexit.register(shutil.rmtree, d, True)
        _cache["tmp"] = Path(d)
    return _cache["tmp"]


def fmu_paths() -> dict[int, Path]:
    """{2: path, 3: path} of the odometry FMUs: fmus/build, else built into a temp dir."""
    if "fmus" not in _cache:
        built = Path(__file__).resolve().parent / "build"
        paths = {v: built / name for v, name in fmu_build.FMU_NAMES.items()}
        if not all(p.is_file() for p in paths.values()):
            out = fmu_build.build_fmus(_tmpdir() / "fmus")
            paths = {2: out["fmi2"], 3: out["fmi3"]}
        _cache["fmus"] = paths
    return _cache["fmus"]


def _unzipped(version: int):
    """(unzip dir, model description) of the FMI ``version`` FMU, extracted once."""
    key = ("unzipped", version)
    if key not in _cache:
        from fmpy import extract, read_model_description
        path = fmu_paths()[version]
        d = extract(str(path), str(_tmpdir() / f"fmi{version}"))
        _cache[key] = (d, read_model_description(str(path)))
    return _cache[key]


def _vrs(md, names) -> list[int]:
    by_name = {v.name: v.valueReference for v in md.modelVariables}
    return [by_name[n] for n in names]


# ---------------------------------------------------------------- through fmpy

def _fmpy_instance(version: int):
    """A co-simulation instance in step mode, created once and reused (freed at exit)."""
    key = ("fmpy", version)
    if key not in _cache:
        from fmpy.simulation import instantiate_fmu
        d, md = _unzipped(version)
        fmu = instantiate_fmu(d, md, "CoSimulation")
        if version == 2:
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
        else:
            fmu.enterInitializationMode(startTime=0.0)
        fmu.exitInitializationMode()
        atexit.register(fmu.freeInstance)
        _cache[key] = [fmu, 0.0, _vrs(md, INPUTS), _vrs(md, OUTPUTS)]
    return _cache[key]


def fmpy_step(version: int, number: int) -> float:
    """Seconds for ``number`` set + doStep + get through fmpy (FMI ``version``)."""
    state = _fmpy_instance(version)
    fmu, t, vr_in, vr_out = state
    set_, get = (fmu.setReal, fmu.getReal) if version == 2 else (fmu.setFloat64, fmu.getFloat64)
    do_step = fmu.doStep
    u = [4.0, 4.5]
    start = time.perf_counter()
    for i in range(number):
        set_(vr_in, u)
        do_step(t, H)
        get(vr_out)
        t += H
    elapsed = time.perf_counter() - start
    state[1] = t
    return elapsed


# ---------------------------------------------------------------- from C

def _driver():
    """The C driver, compiled on first use (ctypes CDLL)."""
    if "driver" not in _cache:
        cc = fmu_build.find_c_compiler()
        src = _tmpdir() / "bench_driver.c"
        lib = _tmpdir() / "bench_driver.so"
        src.write_text(_DRIVER_C)
        cmd = [*cc, "-std=c99", "-D_POSIX_C_SOURCE=200112L", "-O2", "-fPIC", "-shared",
               "-I", str(fmu_build.fmi_headers_dir()), str(src), "-o", str(lib), "-ldl"]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise fmu_build.FmuBuildError(f"compiling the benchmark driver failed:\n{r.stderr}")
        dll = ctypes.CDLL(str(lib))
        for fn in (dll.bench_fmi2, dll.bench_fmi3):
            fn.restype = ctypes.c_double
            fn.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p,
                           ctypes.POINTER(ctypes.c_uint), ctypes.POINTER(ctypes.c_uint),
                           ctypes.c_long]
        _cache["driver"] = dll
    return _cache["driver"]


def c_step(version: int, number: int) -> float:
    """Seconds, measured in C, for ``number`` set + doStep + get calls on the FMU binary."""
    dll = _driver()
    d, md = _unzipped(version)
    fmi2_dir, fmi3_dir = fmu_build.platform_dirs()
    suffix = ".dylib" if sys.platform == "darwin" else ".so"
    ident = md.coSimulation.modelIdentifier
    binary = Path(d) / "binaries" / (fmi2_dir if version == 2 else fmi3_dir) / (ident + suffix)
    resources = Path(d) / "resources"
    vr_in = (ctypes.c_uint * 2)(*_vrs(md, INPUTS))
    vr_out = (ctypes.c_uint * 3)(*_vrs(md, OUTPUTS))
    if version == 2:
        seconds = dll.bench_fmi2(str(binary).encode(), md.guid.encode(),
                                 resources.as_uri().encode(), vr_in, vr_out, number)
    else:
        seconds = dll.bench_fmi3(str(binary).encode(), md.instantiationToken.encode(),
                                 (str(resources) + "/").encode(), vr_in, vr_out, number)
    if seconds < 0:
        raise RuntimeError(f"the C benchmark of {binary} failed (code {seconds:g})")
    return seconds


# ---------------------------------------------------------------- one fmu-node tick

def node_tick(number: int) -> float:
    """Seconds for ``number`` ticks of the fmu-node controller (no bus): a joint_states
    sample is read, turned into wheel speeds, the FMI 2 FMU stepped (with its state saved
    for roll-back) and the nav_msgs/Odometry message built."""
    if "node" not in _cache:
        from bus import codec
        from bus.controller import Observation
        from .fmu_node import open_node
        node = open_node(fmu_paths()[2])
        node.configure({"robots": {"r": {"wheel_radius_m": 0.12, "wheel_separation_m": 0.36,
                                          "pose": [0.0, 0.0, 0.0]}}}, "r")
        atexit.register(node.close)
        msgs = [codec.joint_state(0, ("l", "r"), position=(0.1 * i, 0.11 * i)) for i in range(64)]
        _cache["node"] = [node, 0, Observation, msgs]
    state = _cache["node"]
    node, k, Observation, msgs = state
    start = time.perf_counter()
    for _ in range(number):
        k += 1
        node.step(Observation(k * 20_000_000, "r", {"joint_states": msgs[k & 63]}))
    elapsed = time.perf_counter() - start
    state[1] = k
    return elapsed


def generic_tick(number: int) -> float:
    """Seconds for ``number`` ticks of an fmu-node with no mapping (no bus): the FMI 3
    test model bouncing steps twice per 20 ms tick with its own 0.01 s step, both outputs
    are read and their std_msgs/Float64 messages built and CDR-encoded."""
    if "generic" not in _cache:
        from bus import codec
        from bus.controller import Observation
        from .fmu_node import open_node
        built = Path(__file__).resolve().parent / "build" / fmu_build.fmu_name("bouncing", 3)
        if not built.is_file():
            built = fmu_build.build_fmu(3, _tmpdir() / "fmus", "bouncing")
        node = open_node(built)
        node.configure({"robots": {}}, "r")
        atexit.register(node.close)
        _cache["generic"] = [node, 0, Observation, codec.encode]
    state = _cache["generic"]
    node, k, Observation, encode = state
    start = time.perf_counter()
    for _ in range(number):
        k += 1
        for msg in node.step(Observation(k * 20_000_000, "r", {})).values():
            encode(msg)
    elapsed = time.perf_counter() - start
    state[1] = k
    return elapsed


def benchmarks() -> list[tuple[str, str, Callable[[int], float]]]:
    """(name, description, fn) per benchmark; fn(number) -> total seconds."""
    return [
        ("FMI 2 step via fmpy", "setReal(2) + doStep + getReal(3) through fmpy, odometry FMU",
         partial(fmpy_step, 2)),
        ("FMI 3 step via fmpy", "setFloat64(2) + doStep + getFloat64(3) through fmpy",
         partial(fmpy_step, 3)),
        ("FMI 2 step in C", "fmi2SetReal + fmi2DoStep + fmi2GetReal in a C loop on the "
         "dlopened FMU binary, timed in C", partial(c_step, 2)),
        ("FMI 3 step in C", "fmi3SetFloat64 + fmi3DoStep + fmi3GetFloat64 in a C loop, "
         "timed in C", partial(c_step, 3)),
        ("fmu-node tick", "fmu-node controller step without the bus: joint_states -> "
         "wheel speeds -> FMI 2 step (+ state saved) -> nav_msgs/Odometry", node_tick),
        ("fmu-node tick, no map", "fmu-node with no mapping, FMI 3 bouncing model: 2 doSteps "
         "of its own 0.01 s per tick, 2 outputs -> std_msgs/Float64, encoded", generic_tick),
    ]


def main() -> int:
    for name, desc, fn in benchmarks():
        fn(10)                                     # warm up (and compile / load)
        number = 1000
        while (seconds := fn(number)) < 0.2 and number < 50_000_000:
            number *= 10
        print(f"{name:22s} {seconds / number * 1e6:9.3f} us per step   ({desc})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
