"""Run any co-simulation FMU (FMI 2.0 or 3.0) as a node on the bus.

    diffbot fmu-node FMU --robot R [--mapping FILE] [--name NAME] [bus options]

The FMU is loaded with fmpy (``instantiate_fmu``: FMU2Slave / FMU3Slave) and wrapped in a
controller object for :mod:`bus.node`, which does all of the bus work (session, lockstep,
stamping). A small TOML *mapping file* (read and checked by :mod:`fmus.mapping`) says how
messages and FMU variables meet::

    [[input]]                       # one per FMU input (Real / Float64)
    variable  = "omega_left"        # FMU input variable
    topic     = "joint_states"      # robot topic (bus.keys.TOPICS) it is read from
    field     = "position[0]"       # field path in the message: names, dots, [index]
    transform = "rate"              # "value" (default) or "rate" = delta value / delta t
    scale     = 1.0                 # optional factor on the field's value (deg -> rad...)

    [output]                        # or [[output]] for several messages
    topic   = "odom"                # robot topic the message is published on
    message = "odometry"            # builder: odometry, point, twist, wheel_speeds
    frame_id = "world"              # options of the builder
    x = "x"                         # builder field = FMU variable
    yaw = "theta"

    [parameters]                    # FMU parameter = number or path into sim/info
    wheel_radius = "robots.{robot}.wheel_radius_m"
    x0 = "robots.{robot}.pose[0]"

Without ``--mapping`` the node uses ``fmus/<modelIdentifier>/mapping.toml`` (the odometry
FMU ships one). The FMU argument is a path; a relative path that does not exist here is
looked up in the repository, and a bare name (``odometry``, ``odometry_fmi3``) means the
FMU built into ``fmus/build``.

Stepping (co-simulation semantics: inputs are held over a communication step): at each
control tick t_k the node reads the latest sample of each input topic, turns it into input
values (``rate`` inputs: value difference since the previous *accepted* sample over
h = t_k - t_prev), sets them, calls ``doStep(t_prev, h)`` and publishes the outputs
stamped t_k. So the step covers the interval that ends at the tick and the outputs carry
no lag; with encoder angles and ``rate`` this reproduces exact-arc dead reckoning. At the
first tick there is no previous reading: the FMU is initialised at t_0 (``rate`` inputs 0)
and its initial outputs are published (the start pose for the odometry FMU).

Bad samples never stop the node. A sample whose mapped field is missing or not finite
(NaN, inf, or a rate that overflows) is rejected: counted and logged (rate limited, reason
``input``), the FMU is not stepped, the previous accepted sample stays the reference for
the next rate (so no encoder increment is lost: the next good sample covers both
intervals), and the last good outputs are published again with the new stamp, so the nodes
that wait for them in lockstep keep going. A ``doStep`` that fails (status discard, error,
fatal, or a terminate request) or that yields non-finite outputs is rejected the same way
(reason ``step``); the FMU is rolled back to its state after the last good step
(``getFMUstate``/``setFMUstate`` when the FMU can, else it is reset and initialised again
from its parameters at the last good time, losing its internal state, which is logged).
If the simulation time goes backwards (the plant was reset) the FMU is reset and
initialised again from the current tick. The counters are in the ``--stats`` JSON.
"""
from __future__ import annotations

import atexit
import logging
import math
import shutil
import sys
import tempfile
import zipfile
from collections import deque
from ctypes import byref
from pathlib import Path

from bus.log import RejectCounter, setup_logging
from bus.jsonio import write_json
from bus.node import node_arg_parser, run_node_args
from bus.runtime import EXIT_BAD_CONFIG

from .mapping import FieldPath, FmuNodeError, Mapping, default_mapping, load_mapping

__all__ = ["FmuNodeError", "FieldPath", "Mapping", "load_mapping", "resolve_fmu", "Fmu",
           "FmuNode", "open_node", "main"]

FMUS_DIR = Path(__file__).resolve().parent
REPO_DIR = FMUS_DIR.parent
BUILD_DIR = FMUS_DIR / "build"
BUILD_HINT = "build it with `diffbot fmu build` (or `make setup`)"


# ====================================================================== FMU path

def resolve_fmu(arg: str | Path) -> Path:
    """The FMU file meant by ``arg``: a path (relative to the current directory, else to the
    repository), or a bare name of an FMU built into fmus/build (``odometry`` is
    ``odometry_fmi2.fmu``, ``odometry_fmi3`` is ``odometry_fmi3.fmu``)."""
    p = Path(arg).expanduser()
    candidates = [p]
    if not p.is_absolute():
        candidates.append(REPO_DIR / p)
    if p.suffix != ".fmu" and len(p.parts) == 1:
        candidates += [BUILD_DIR / f"{p.name}.fmu", BUILD_DIR / f"{p.name}_fmi2.fmu"]
    for c in candidates:
        if c.is_file():
            return c.resolve()
    built = any(c.parent.resolve() == BUILD_DIR for c in candidates[1:] + [p.absolute()])
    if built:
        raise FmuNodeError(f"{arg}: FMU not found (looked in {BUILD_DIR}): {BUILD_HINT}")
    if p.is_dir():
        raise FmuNodeError(f"{arg}: is a directory, not an FMU file")
    raise FmuNodeError(f"{arg}: no such FMU file")


# ====================================================================== the FMU

class FmuCallError(RuntimeError):
    """An FMI call returned an error at run time (the FMU's last log message attached)."""


_TMP_DIRS: list[str] = []


@atexit.register
def _remove_tmp_dirs() -> None:
    for d in _TMP_DIRS:
        shutil.rmtree(d, ignore_errors=True)


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
        self.unzipdir = tempfile.mkdtemp(prefix="fmu-node-")
        _TMP_DIRS.append(self.unzipdir)
        extract(str(self.path), self.unzipdir)
        self.instance_name = instance_name
        self._instantiate()
        self._snapshot = None
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
        self._set, self._get = ("setReal", "getReal") if self.version == 2 else \
            ("setFloat64", "getFloat64")

    def _why(self) -> str:
        m = self.last_message()
        return f" ({m})" if m else ""

    def variable(self, name: str, role: str, where: str):
        """The model variable ``name`` checked for ``role`` (input, output, parameter)."""
        v = self.variables.get(name)
        if v is None:
            close = [n for n in self.variables if n.lower() == name.lower()]
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise FmuNodeError(f"{where}: the FMU {self.name} has no variable {name!r}{hint}")
        if v.type not in ("Real", "Float64"):
            raise FmuNodeError(f"{where}: variable {name!r} of {self.name} is {v.type}; "
                               "only Real / Float64 variables can be mapped")
        ok = {"input": v.causality == "input",
              "parameter": v.causality == "parameter" or
              (v.causality in ("local", "output") and v.initial == "exact" and
               v.variability != "constant"),
              "output": v.causality in ("output", "local", "parameter",
                                        "calculatedParameter", "input")}[role]
        if not ok:
            raise FmuNodeError(f"{where}: variable {name!r} of {self.name} has causality "
                               f"{v.causality!r}; it cannot be used as an {role}"
                               if role != "parameter" else
                               f"{where}: variable {name!r} of {self.name} has causality "
                               f"{v.causality!r}; it cannot be used as a parameter")
        return v

    def vrs(self, names: list[str]) -> list[int]:
        return [self.variables[n].valueReference for n in names]

    # ------------------------------------------------------------------ calls
    def _call(self, what: str, method: str, *args):
        """Call fmpy's ``method`` of the instance; FMI errors become FmuCallError."""
        from fmpy.fmi1 import FMICallException
        if self.fmu is None:
            raise FmuCallError(f"{what}: the FMU has no instance (it could not be created again)")
        try:
            return getattr(self.fmu, method)(*args)
        except FMICallException as exc:
            raise FmuCallError(f"{what} failed with status {exc.status}{self._why()}") from None
        except Exception as exc:  # ctypes errors
            raise FmuCallError(f"{what} failed: {_one_line(exc)}") from None

    def set(self, vrs: list[int], values: list[float]) -> None:
        self._call("set", self._set, vrs, values)

    def get(self, vrs: list[int]) -> list[float]:
        return self._call("get", self._get, vrs)

    def initialize(self, t: float, params: dict[int, float], inputs: dict[int, float]) -> None:
        """Set parameters and inputs, initialise at time t; the instance is then in step mode."""
        if self.fmu is None:
            try:
                self._instantiate()
            except FmuNodeError as exc:
                raise FmuCallError(str(exc)) from None
        if params:
            self._call("setting the parameters", self._set, list(params), list(params.values()))
        if inputs:
            self._call("setting the inputs", self._set, list(inputs), list(inputs.values()))
        if self.version == 2:
            self._call("setupExperiment", "setupExperiment", None, t)
            self._call("enterInitializationMode", "enterInitializationMode")
        else:
            self._call("enterInitializationMode", "enterInitializationMode", None, t)
        self._call("exitInitializationMode", "exitInitializationMode")
        self.time = t
        self.snapshot()

    def do_step(self, h: float) -> None:
        """Advance from self.time by h; raises FmuCallError (the instance is not advanced)."""
        if self.version == 2:
            self._call("doStep", "doStep", self.time, h)
        else:
            event, terminate, early, last = self._call("doStep", "doStep", self.time, h)
            if terminate:
                raise FmuCallError(f"doStep asked to terminate the simulation{self._why()}")
        self.time += h

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
        """Terminate and free the instance (never raises)."""
        if self.fmu is None:
            return
        self._free_snapshot()
        try:
            self.fmu.terminate()
        except Exception:
            pass
        self._free_instance()


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


# ====================================================================== the controller

class FmuNode:
    """A bus.node controller that steps an FMU once per control tick (see module docstring)."""

    sync = True
    check_inputs = False     # it checks its mapped fields itself (and holds its outputs)

    def __init__(self, fmu: Fmu, mapping: Mapping, log: logging.Logger | None = None) -> None:
        self.fmu = fmu
        self.mapping = mapping
        self.name = fmu.model_identifier
        self.log = log or logging.getLogger(self.name)
        self.rejects = RejectCounter(self.log)
        self.inputs = mapping.topics
        for i in mapping.inputs:
            fmu.variable(i.variable, "input", f"{i.where}.variable")
        for o in mapping.outputs:
            for f, var in o.fields.items():
                fmu.variable(var, "output", f"{o.where}.{f}")
        for p in mapping.parameters:
            fmu.variable(p, "parameter", f"{mapping.where_parameters}.{p}")
        self.in_vrs = fmu.vrs([i.variable for i in mapping.inputs])
        self.rate = [i.transform == "rate" for i in mapping.inputs]
        self.out_names = list(dict.fromkeys(v for o in mapping.outputs for v in o.fields.values()))
        self.out_vrs = fmu.vrs(self.out_names)
        self.params: dict[int, float] = {}
        # run state
        self.t_ns: int | None = None         # tick of the FMU's current time
        self.prev: list[float] | None = None  # raw input values of the last accepted sample
        self.outputs: dict[str, float] | None = None
        self.steps = 0
        self.held = 0
        self.rollbacks = 0
        self.reinitialised = 0

    # ------------------------------------------------------------------ configure
    def configure(self, info: dict, robot: str) -> None:
        """Parameters from sim/info (the node API calls this once the plant answered)."""
        params: dict[int, float] = {}
        for name, spec in self.mapping.parameters.items():
            where = f"{self.mapping.where_parameters}.{name}"
            if isinstance(spec, str):
                text = spec.replace("{robot}", robot)
                try:
                    value = FieldPath(text).get(info)
                except LookupError:
                    raise FmuNodeError(f"{where}: sim/info has no {text}") from None
            else:
                value = spec
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise FmuNodeError(f"{where}: {spec} is {value!r}, not a finite number")
            params[self.fmu.variables[name].valueReference] = float(value)
        try:   # set them now, so that a value the FMU refuses is a configuration error
            self.fmu.set(list(params), list(params.values()))
        except FmuCallError as exc:
            raise FmuNodeError(f"{self.mapping.where_parameters}: the FMU {self.fmu.name} "
                               f"refused the parameters: {exc}") from None
        self.params = params

    # ------------------------------------------------------------------ step
    def read(self, obs) -> list[float] | None:
        """Raw input values (scaled) from the latest messages, or None (and a reject)."""
        values = []
        for m in self.mapping.inputs:
            msg = obs[m.topic]
            if msg is None:
                return None               # nothing received yet: not a bad sample
            try:
                v = float(m.field.get(msg)) * m.scale
            except (LookupError, TypeError, ValueError) as exc:
                self.rejects.reject("input", f"{self.fmu.name}: {m.variable} from "
                                             f"{m.topic}.{m.field}: {exc}")
                return None
            if not math.isfinite(v):
                self.rejects.reject("input", f"{self.fmu.name}: {m.variable} from "
                                             f"{m.topic}.{m.field} is {v}")
                return None
            values.append(v)
        return values

    def step(self, obs):
        """One tick: outputs stamped obs.t_ns (never raises: see the module docstring)."""
        try:
            return self._step(obs)
        except Exception as exc:     # a bug or an FMU misbehaving in a way not foreseen
            self.rejects.reject("step", f"{self.fmu.name}: {type(exc).__name__}: {exc}")
            self.held += 1
            return self.publish(obs.t_ns)

    def _step(self, obs):
        t_ns = obs.t_ns
        if self.t_ns is not None and t_ns < self.t_ns:
            self.log.info("time went back from %.3f s to %.3f s (simulation reset): "
                          "initialising %s again", self.t_ns * 1e-9, t_ns * 1e-9, self.fmu.name)
            self.fmu.reset()
            self.t_ns = None
        raw = self.read(obs)
        if self.t_ns is None:
            return self._start(t_ns, raw)
        if raw is None or t_ns == self.t_ns:      # bad sample, or this tick again
            self.held += raw is None
            return self.publish(t_ns)
        h_ns = t_ns - self.t_ns
        h = h_ns * 1e-9
        values = []
        for i, v in enumerate(raw):
            if self.rate[i]:
                v = (v - self.prev[i]) / h if self.prev is not None else 0.0
            values.append(v)
        if not all(math.isfinite(v) for v in values):
            bad = [m.variable for m, v in zip(self.mapping.inputs, values) if not math.isfinite(v)]
            self.rejects.reject("input", f"{self.fmu.name}: {', '.join(bad)} not finite")
            self.held += 1
            return self.publish(t_ns)
        t_good = self.fmu.time
        try:
            if self.in_vrs:
                self.fmu.set(self.in_vrs, values)
            self.fmu.do_step(h)
            out = self.fmu.get(self.out_vrs)
            if not all(math.isfinite(v) for v in out):
                bad = [n for n, v in zip(self.out_names, out) if not math.isfinite(v)]
                raise FmuCallError(f"non-finite output {', '.join(bad)}")
        except FmuCallError as exc:
            self.rejects.reject("step", f"{self.fmu.name} at t={t_ns * 1e-9:.3f} s: {exc}")
            self._recover(t_good)
            self.held += 1
            return self.publish(t_ns)
        self.fmu.snapshot()
        self.outputs = dict(zip(self.out_names, out))
        self.prev = raw
        self.t_ns = t_ns
        self.steps += 1
        return self.publish(t_ns)

    def _start(self, t_ns: int, raw: list[float] | None):
        """First tick (or after a reset): initialise at t_ns, publish the initial outputs."""
        inputs = {}
        if raw is not None:
            inputs = {vr: (0.0 if r else v) for vr, r, v in zip(self.in_vrs, self.rate, raw)}
        try:
            self.fmu.initialize(t_ns * 1e-9, self.params, inputs)
            self.outputs = dict(zip(self.out_names, self.fmu.get(self.out_vrs)))
        except FmuCallError as exc:
            self.rejects.reject("step", f"{self.fmu.name}: initialisation at "
                                        f"t={t_ns * 1e-9:.3f} s failed: {exc}")
            self.fmu.reset()
            return self.publish(t_ns)
        self.t_ns = t_ns
        self.prev = raw
        return self.publish(t_ns)

    def _recover(self, t_good: float) -> None:
        if self.fmu.rollback(t_good):
            self.rollbacks += 1
            return
        # No saved state: start again from the parameters at the last good time.
        self.log.warning("%s cannot restore its state: initialising it again at t=%.3f s "
                         "(its internal state is lost)", self.fmu.name, t_good)
        self.reinitialised += 1
        self.fmu.reset()
        try:
            self.fmu.initialize(t_good, self.params, {})
        except FmuCallError as exc:
            self.rejects.reject("step", f"{self.fmu.name}: initialisation failed: {exc}")
            self.fmu.reset()
            self.t_ns = None
            self.prev = None

    def publish(self, t_ns: int) -> dict | None:
        """The mapped messages from the last good outputs, stamped t_ns."""
        if self.outputs is None:
            return None
        out = {}
        for o in self.mapping.outputs:
            values = {f: self.outputs[var] for f, var in o.fields.items()}
            out[o.topic] = o.kind.build(t_ns, values, o.options)
        return out

    def stats(self) -> dict:
        return {"fmu": str(self.fmu.path), "fmi_version": self.fmu.version,
                "steps": self.steps, "held": self.held, "rollbacks": self.rollbacks,
                "reinitialised": self.reinitialised, "rejected": dict(self.rejects.counts)}

    def close(self) -> None:
        self.fmu.close()


# ====================================================================== command line

def open_node(fmu_arg: str | Path, mapping_path: str | Path | None = None,
              log: logging.Logger | None = None, instance_name: str = "fmu") -> FmuNode:
    """Load the FMU and its mapping and check them against each other (FmuNodeError)."""
    path = resolve_fmu(fmu_arg)
    fmu = Fmu(path, instance_name, log)
    try:
        if mapping_path is None:
            mapping_path = default_mapping(fmu.model_identifier)
            if mapping_path is None:
                raise FmuNodeError(f"{fmu.name}: no mapping for model "
                                   f"{fmu.model_identifier!r}: pass --mapping FILE")
        return FmuNode(fmu, load_mapping(mapping_path), log)
    except BaseException:
        fmu.close()
        raise


def main(argv: list[str] | None = None) -> int:
    p = node_arg_parser("Run a co-simulation FMU (FMI 2 or 3) as a node on the bus.")
    p.prog = "diffbot fmu-node"
    p.add_argument("fmu", metavar="FMU",
                   help="FMU file, or a name built into fmus/build (odometry, odometry_fmi3)")
    p.add_argument("--mapping", metavar="FILE",
                   help="TOML mapping of messages to FMU variables "
                        "(default fmus/<modelIdentifier>/mapping.toml)")
    args = p.parse_args(argv)
    try:
        node = open_node(args.fmu, args.mapping, instance_name=args.name or "fmu")
    except FmuNodeError as exc:
        setup_logging(args.name or "fmu-node", args.log_level).error("%s", exc)
        return EXIT_BAD_CONFIG
    name = args.name or f"{node.name}_{args.robot}"
    node.log = node.rejects.log = node.fmu.log = setup_logging(name, args.log_level)
    try:
        code = run_node_args(node, args, name)
    finally:
        node.close()
    if args.stats:
        _merge_stats(args.stats, node)
    return code


def _merge_stats(path: str, node: FmuNode) -> None:
    """Add the node's own counters to the stats JSON bus.node wrote."""
    import json
    try:
        with open(path) as f:
            data = json.load(f)
    except (OSError, ValueError):
        return      # bus.node wrote nothing (the node never got on the bus)
    st = node.stats()
    for reason, n in st.pop("rejected").items():
        data.setdefault("rejected", {})[reason] = data.get("rejected", {}).get(reason, 0) + n
    data["fmu"] = st
    write_json(path, data)


if __name__ == "__main__":
    sys.exit(main())
