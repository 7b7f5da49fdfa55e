"""One co-simulation FMU (FMI 2.0 or 3.0) through fmpy: load, check, call, by variable.

Errors at load time are one line (:class:`FmuNodeError`: not an FMU, no co-simulation, no
binary for this platform -- with the platforms it ships and how to compile its sources);
errors of FMI calls at run time are :class:`FmuCallError` carrying the FMU's last log
message. The FMU is extracted under ``<tmp>/diffbot-fmu/<pid>-*``; a process killed
before it could remove its folder (SIGKILL) leaves it there, and the next start removes
the folders of processes that are gone.
"""
from __future__ import annotations

import atexit
import functools
import logging
import os
import shutil
import tempfile
import zipfile
from collections import deque
from ctypes import byref, c_double, c_uint
from pathlib import Path

from .mapping import FmuNodeError
from .variables import Unsupported, Variable, variable

#: where FMUs are extracted: one folder per process, ``<pid>-<random>``
TMP_ROOT = Path(tempfile.gettempdir()) / "diffbot-fmu"


class FmuCallError(RuntimeError):
    """An FMI call returned an error at run time (the FMU's last log message attached)."""


_TMP_DIRS: list[str] = []


@atexit.register
def _remove_tmp_dirs() -> None:
    for d in _TMP_DIRS:
        shutil.rmtree(d, ignore_errors=True)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_tmp(root: Path = TMP_ROOT) -> list[Path]:
    """Remove the extraction folders of fmu-node processes that are gone (killed before
    they could clean up); return them."""
    gone = []
    for d in root.glob("*-*") if root.is_dir() else ():
        pid = d.name.split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _pid_alive(int(pid)):
            shutil.rmtree(d, ignore_errors=True)
            gone.append(d)
    return gone


def extraction_dir() -> str:
    """A new folder for one FMU of this process (after sweeping the dead ones')."""
    sweep_tmp()
    TMP_ROOT.mkdir(parents=True, exist_ok=True)
    d = tempfile.mkdtemp(prefix=f"{os.getpid()}-", dir=TMP_ROOT)
    _TMP_DIRS.append(d)
    return d


def platforms_of(path: Path, model_identifier: str, version: int) -> list[str]:
    """The platforms an FMU ships a binary for (folder names under binaries/)."""
    with zipfile.ZipFile(path) as z:
        names = z.namelist()
    return sorted({n.split("/")[1] for n in names
                   if n.startswith("binaries/") and n.count("/") >= 2 and
                   Path(n).stem == model_identifier})


def check_binary(path: Path, model_identifier: str, version: int, has_sources: bool) -> None:
    """FmuNodeError unless the FMU has a binary for this platform: the message names the
    platforms it ships and, if it carries its C sources, how to compile them."""
    from fmpy import platform, platform_tuple, sharedLibraryExtension
    here = platform if version == 2 else platform_tuple
    with zipfile.ZipFile(path) as z:
        if f"binaries/{here}/{model_identifier}{sharedLibraryExtension}" in z.namelist():
            return
    ships = platforms_of(path, model_identifier, version)
    msg = (f"{path.name}: no binary for this platform ({here}); it ships "
           f"{', '.join(ships) if ships else 'no binaries'}")
    if has_sources:
        msg += (f"; it has C sources: `fmpy compile {path}` builds one for {here} "
                "(needs a C compiler)")
    raise FmuNodeError(msg)


class Fmu:
    """One co-simulation instance of an FMI 2 or 3 FMU through fmpy, addressed by variable
    names; errors at load time raise FmuNodeError naming the FMU (and the variable)."""

    def __init__(self, path: str | Path, instance_name: str = "fmu",
                 log: logging.Logger | None = None) -> None:
        from fmpy import extract, read_model_description
        self.path = Path(path)
        self.name = self.path.name
        self.log = log or logging.getLogger("fmu")
        self.messages: deque[str] = deque(maxlen=8)
        self.fmu = None
        if not zipfile.is_zipfile(self.path):
            raise FmuNodeError(f"{self.path}: not an FMU (not a ZIP archive)")
        try:
            md = read_model_description(str(self.path))
        except Exception as exc:
            raise FmuNodeError(f"{self.path}: not a valid FMU: {_one_line(exc)}") from None
        self.md = md
        self.version = int(md.fmiVersion.split(".")[0]) if md.fmiVersion else 0
        if self.version not in (2, 3):
            raise FmuNodeError(f"{self.name}: FMI {md.fmiVersion} is not supported "
                               "(FMI 2.0 or 3.0 co-simulation)")
        if md.coSimulation is None:
            offers = [k for k, v in (("model exchange", md.modelExchange),
                                     ("scheduled execution",
                                      getattr(md, "scheduledExecution", None))) if v is not None]
            raise FmuNodeError(f"{self.name}: the FMU has no co-simulation interface "
                               f"(it offers {', '.join(offers) or 'nothing'}); fmu-node "
                               "runs co-simulation FMUs")
        self.model_identifier = md.coSimulation.modelIdentifier
        self.can_snapshot = bool(md.coSimulation.canGetAndSetFMUstate)
        self.variables = {v.name: v for v in md.modelVariables}
        with zipfile.ZipFile(self.path) as z:
            has_sources = any(n.startswith("sources/") and n.endswith(".c")
                              for n in z.namelist())
        check_binary(self.path, self.model_identifier, self.version, has_sources)
        experiment = md.defaultExperiment
        #: the FMU's own communication step (DefaultExperiment stepSize), s, or None
        self.step_size = float(experiment.stepSize) if experiment is not None and \
            experiment.stepSize not in (None, "") and float(experiment.stepSize) > 0 else None
        self._snapshot = None
        #: variables -> their FMI calls (:meth:`_calls`); float64 access -> its C setter
        self._plans: dict = {}
        self._setter = {"Real": "fmi2SetReal"} if self.version == 2 else \
            {"Float64": "fmi3SetFloat64"}
        self.unzipdir = extraction_dir()
        self.instance_name = instance_name
        try:
            extract(str(self.path), self.unzipdir)
            self._instantiate()
        except BaseException:
            self._remove_dir()
            raise
        self.time = 0.0

    # ------------------------------------------------------------------ plumbing
    def _logger(self):
        if self.version == 2:
            def log2(env, instance, status, category, message):
                self._record(status, message)
            return log2

        def log3(env, status, category, message):
            self._record(status, message)
        return log3

    def _record(self, status, message) -> None:
        text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
        self.messages.append(text)
        if status >= 2:
            self.log.debug("%s: %s", self.name, text)

    def last_message(self) -> str:
        return self.messages[-1] if self.messages else ""

    def _instantiate(self) -> None:
        from fmpy.simulation import instantiate_fmu
        try:
            self.fmu = instantiate_fmu(self.unzipdir, self.md, "CoSimulation",
                                       logger=self._logger())
        except Exception as exc:
            raise FmuNodeError(f"{self.name}: cannot instantiate the FMU for co-simulation: "
                               f"{_one_line(exc)}{self._why()}") from None

    def _why(self) -> str:
        m = self.last_message()
        return f" ({m})" if m else ""

    def variable(self, name: str, role: str, where: str) -> Variable:
        """The model variable ``name`` checked for ``role`` (input, output, parameter)."""
        v = self.variables.get(name)
        if v is None:
            close = [n for n in self.variables if n.lower() == name.lower()]
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise FmuNodeError(f"{where}: the FMU {self.name} has no variable {name!r}{hint}")
        ok = {"input": v.causality == "input",
              "parameter": v.causality == "parameter" or
              (v.causality in ("local", "output") and v.initial == "exact" and
               v.variability != "constant"),
              "output": v.causality in ("output", "local", "parameter",
                                        "calculatedParameter", "input")}[role]
        if not ok:
            article = "a" if role == "parameter" else "an"
            raise FmuNodeError(f"{where}: variable {name!r} of {self.name} has causality "
                               f"{v.causality!r}; it cannot be used as {article} {role}")
        try:
            return self.bus_variable(name)
        except Unsupported as exc:
            raise FmuNodeError(f"{where}: variable {exc} of {self.name}") from None

    def bus_variable(self, name: str) -> Variable:
        """The bus view of variable ``name`` (Unsupported if the bus cannot carry it)."""
        return variable(self.variables[name], self.version, self.md.modelVariables)

    # ------------------------------------------------------------------ calls
    def _call(self, what: str, method: str, *args):
        """Call fmpy's ``method`` of the instance; FMI errors become FmuCallError."""
        if self.fmu is None:
            raise FmuCallError(f"{what}: the FMU has no instance (it could not be created again)")
        try:
            return getattr(self.fmu, method)(*args)
        except Exception as exc:
            from fmpy.fmi1 import FMICallException      # (imported once fmpy failed a call)
            if isinstance(exc, FMICallException):
                raise FmuCallError(f"{what} failed with status {exc.status}{self._why()}") \
                    from None
            raise FmuCallError(f"{what} failed: {_one_line(exc)}") from None  # ctypes errors

    def read(self, variables: list[Variable]) -> list[list]:
        """The values of ``variables`` (a list of values per variable), one FMI call per type."""
        out: list[list] = [[] for _ in variables]
        for access, vrs, n, spans, arrays in self._calls(tuple(variables)):
            if arrays is not None:          # float64: straight into the arrays built once
                c_vrs, c_vals, fn = arrays
                self._call(f"get{access}", fn, *self._args(c_vrs, len(vrs), c_vals, n))
                flat = c_vals[:]
            else:
                flat = self._call(f"get{access}", f"get{access}", vrs) if self.version == 2 \
                    else self._call(f"get{access}", f"get{access}", vrs, n)
            for i, a, b in spans:
                out[i] = flat[a:b]
        return out

    def write(self, variables: list[Variable], values: list[list], what: str = "set") -> None:
        """Set ``variables`` to ``values`` (a list of values per variable)."""
        for access, vrs, n, spans, arrays in self._calls(tuple(variables)):
            flat = [x for i, _, _ in spans for x in values[i]]
            if arrays is not None and len(flat) == n:
                c_vrs, c_vals, _ = arrays
                c_vals[:] = flat
                self._call(f"{what} ({access})", self._setter[access],
                           *self._args(c_vrs, len(vrs), c_vals, n))
            else:
                self._call(f"{what} ({access})", f"set{access}", vrs, flat)

    def _args(self, c_vrs, nvr: int, c_vals, n: int) -> tuple:
        """The arguments of fmi2Get/SetReal, fmi3Get/SetFloat64 on the instance."""
        if self.version == 2:
            return (self.fmu.component, c_vrs, nvr, c_vals)
        return (self.fmu.component, c_vrs, nvr, c_vals, n)

    def _calls(self, variables: tuple[Variable, ...]) -> list:
        """:func:`_plan` of ``variables``, each float64 group with its value references and
        a value buffer as C arrays, built once per set of variables (fmpy's getReal/setReal
        build both at every call, a tick's largest share of an FMU node's time)."""
        calls = self._plans.get(variables)
        if calls is None:
            calls = []
            for access, vrs, n, spans in _plan(variables):
                arrays = None
                if access in self._setter and n:
                    arrays = ((c_uint * len(vrs))(*vrs), (c_double * n)(),
                              "fmi2GetReal" if self.version == 2 else "fmi3GetFloat64")
                calls.append((access, vrs, n, spans, arrays))
            if len(self._plans) >= 64:
                self._plans.clear()
            self._plans[variables] = calls
        return calls

    def initialize(self, t: float, start: list[tuple[Variable, list]]) -> None:
        """Set parameters and inputs (``start``: variable, values), initialise at time t; the
        instance is then in step mode."""
        if self.fmu is None:
            try:
                self._instantiate()
            except FmuNodeError as exc:
                raise FmuCallError(str(exc)) from None
        if start:
            self.write([v for v, _ in start], [x for _, x in start],
                       "setting the parameters and inputs")
        if self.version == 2:
            self._call("setupExperiment", "setupExperiment", None, t)
            self._call("enterInitializationMode", "enterInitializationMode")
        else:
            self._call("enterInitializationMode", "enterInitializationMode", None, t)
        self._call("exitInitializationMode", "exitInitializationMode")
        self.time = t
        self.snapshot()

    def do_step(self, h: float, t_next: float | None = None) -> None:
        """Advance from self.time by h (to ``t_next`` if given: the time is then exactly
        that grid point); raises FmuCallError (the instance is not advanced)."""
        if self.version == 2:
            self._call("doStep", "doStep", self.time, h)
        else:
            event, terminate, early, last = self._call("doStep", "doStep", self.time, h)
            if terminate:
                raise FmuCallError(f"doStep asked to terminate the simulation{self._why()}")
        self.time = t_next if t_next is not None else self.time + h

    def snapshot(self) -> None:
        """Remember the current state (FMUs that can get and set their state)."""
        if not self.can_snapshot or self.fmu is None:
            return
        try:
            if self._snapshot is None:
                self._snapshot = self._call("getFMUstate", "getFMUState")
            else:   # update the saved state in place (FMI: *FMUstate != NULL on entry)
                f = "fmi2GetFMUstate" if self.version == 2 else "fmi3GetFMUState"
                self._call("getFMUstate", f, self.fmu.component, byref(self._snapshot))
        except FmuCallError as exc:
            self.log.warning("%s: cannot save its state (%s): a failed step will "
                             "initialise it again", self.name, exc)
            self.can_snapshot = False
            self._snapshot = None

    def rollback(self, t_good: float) -> bool:
        """Back to the state after the last good step; True if the state was kept."""
        if self._snapshot is not None:
            try:
                self._call("setFMUstate", "setFMUState", self._snapshot)
                self.time = t_good
                return True
            except FmuCallError:
                pass
        return False

    def reset(self) -> None:
        """Back to the instantiated state: fmiReset, else a new instance (never raises; if
        no instance can be made, the next :meth:`initialize` tries again)."""
        self._free_snapshot()
        try:
            self._call("reset", "reset")
            return
        except FmuCallError:
            pass
        self._free_instance()
        try:
            self._instantiate()
        except FmuNodeError as exc:
            self.log.error("%s", exc)

    def _free_snapshot(self) -> None:
        if self._snapshot is not None:
            try:
                self.fmu.freeFMUState(self._snapshot)
            except Exception:
                pass
            self._snapshot = None

    def _free_instance(self) -> None:
        if self.fmu is None:
            return
        try:
            self.fmu.freeInstance()
        except Exception:
            pass
        self.fmu = None

    def close(self) -> None:
        """Terminate and free the instance, and remove its extraction folder (never raises;
        the object is done then)."""
        if self.fmu is not None:
            self._free_snapshot()
            try:
                self.fmu.terminate()
            except Exception:
                pass
            self._free_instance()
        self._remove_dir()

    def _remove_dir(self) -> None:
        """The extraction folder gone now, not at the process's exit (a master or a test
        opens many FMUs in one process)."""
        d = getattr(self, "unzipdir", None)
        if d and d in _TMP_DIRS:
            _TMP_DIRS.remove(d)
            shutil.rmtree(d, ignore_errors=True)



@functools.lru_cache(maxsize=64)
def _plan(variables: tuple[Variable, ...]) -> list[tuple[str, list[int], int, list]]:
    """One FMI call per type: (access, value references, number of values, [(index of the
    variable, start, end) in the values])."""
    groups: dict[str, list[int]] = {}
    for i, v in enumerate(variables):
        groups.setdefault(v.access, []).append(i)
    plan = []
    for access, idx in groups.items():
        spans, k = [], 0
        for i in idx:
            spans.append((i, k, k + variables[i].size))
            k += variables[i].size
        plan.append((access, [variables[i].vr for i in idx], k, spans))
    return plan


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
