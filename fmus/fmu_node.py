"""Run any co-simulation FMU (FMI 2.0 or 3.0) as a node on the bus (docs/fmu.md).

    diffbot fmu-node FMU [--instance I] [--connect VAR=fmu/OTHER/VAR] [--param NAME=VALUE]
                         [--step-size fmu|tick|S] [--from-zero] [--mapping FILE] [bus options]

The FMU is loaded with fmpy (:mod:`fmus.fmu`) and wrapped in a controller object for
:mod:`bus.node`, which does all of the bus work (session, lockstep, stamping). With no
mapping file every output goes on ``fmu/<instance>/<variable>`` as the std_msgs type of its
FMI type (:mod:`fmus.variables`) and every input is read from its key or another node's
(:mod:`fmus.wiring`); the node answers ``fmu/<instance>/info``. A TOML *mapping file* (read
and checked by :mod:`fmus.mapping`) wires the FMU to robot topics instead::

    [[input]]                       # one per FMU input (any numeric FMI type that fits)
    variable  = "omega_left"        # FMU input variable
    topic     = "joint_states"      # robot topic (bus.keys.TOPICS), or fmu/<instance>/<var>
    field     = "position[0]"       # field path in the message: names, dots, [index]
    transform = "rate"              # "value" (default) or "rate" = delta value / delta t
    scale     = 1.0                 # optional factor on the field's value (deg -> rad...)

    [output]                        # or [[output]] for several messages; none: fmu/ keys
    topic   = "odom"                # robot topic the message is published on
    message = "odometry"            # builder: odometry, point, twist, wheel_speeds
    frame_id = "{robot}/odom"       # options of the builder ({robot}: the node's --robot)
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
h = t_k - t_prev), sets them, calls ``doStep(t_prev, h)`` -- or, for an FMU stepping with
its own step size, the doSteps between its grid points up to t_k -- and publishes the
outputs stamped t_k. So the step covers the interval that ends at the tick and the outputs carry
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

import json
import logging
import math
from functools import partial
from pathlib import Path

from bus import jsonio
from bus.encoded import Encoded
from bus.keys import TOPICS, Keys, check_name, fmu_topic
from bus.log import RejectCounter

from .floatstep import FloatStep
from .fmu import Fmu, FmuCallError
from .mapping import (FieldPath, FmuNodeError, Mapping, cli_parameters, default_mapping,
                      in_bounds, load_mapping)
from .variables import Variable
from .wiring import build_feeds, output_variables

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


# ====================================================================== the controller

class FmuNode:
    """A bus.node controller that steps an FMU at each control tick (module docstring)."""

    sync = True
    check_inputs = False     # it checks its inputs itself (and holds its outputs)

    def __init__(self, fmu: Fmu, mapping: Mapping | None = None, log: logging.Logger | None = None,
                 instance: str | None = None, connect: dict[str, str] | None = None,
                 start_values: dict[str, str] | None = None, step: str | float | None = None,
                 from_zero: bool = False) -> None:
        self.fmu = fmu
        self.mapping = mapping or Mapping("")
        self.name = fmu.model_identifier
        self.instance = check_name(instance or fmu.model_identifier, "FMU instance name")
        self.log = log or logging.getLogger(self.name)
        self.rejects = RejectCounter(self.log)
        self.feeds, self.topics = build_feeds(fmu, self.instance, self.mapping.inputs,
                                              connect or {}, self.log)
        self.inputs = list(dict.fromkeys(f.topic for f in self.feeds))
        self.rate = [f.rate for f in self.feeds]
        self.builders = self.mapping.outputs
        builder_vars = [fmu.variable(var, "output", f"{o.where}.{f}")
                        for o in self.builders for f, var in o.fields.items()]
        for v in builder_vars:
            if not v.numeric or v.shape:
                raise FmuNodeError(f"{self.mapping.path}: output {v.name!r} is {v.fmi_type}"
                                   f"{' array' if v.shape else ''}: a message field takes a "
                                   "number (leave [output] out to publish it on its fmu/ key)")
        #: outputs published on their fmu/ keys: all of them when no [output] builds messages
        self.generic = [] if self.builders else output_variables(fmu, self.log)
        self.out_vars = list({v.name: v for v in builder_vars + self.generic}.values())
        self.generic_topics = [fmu_topic(self.instance, v.name) for v in self.generic]
        for p in self.mapping.parameters:
            fmu.variable(p, "parameter", f"{self.mapping.where_parameters}.{p}")
        self.cli_params = cli_parameters(fmu, start_values or {})
        self.params: list[tuple[Variable, list]] = []
        self.step_size = _step_size(fmu, step if step is not None else self.mapping.step_size)
        self.from_zero = from_zero
        # run state
        self.t_ns: int | None = None          # tick of the FMU's current time
        self.t0 = 0.0                         # time the FMU was initialised at, s
        self.j = 0                            # FMU steps since t0 (its own step size)
        self.prev: list | None = None         # raw input values of the last accepted sample
        self.held_inputs: list = [None] * len(self.feeds)   # external inputs: last good
        self.outputs: dict[str, list] | None = None
        self.steps = 0
        self.fmu_steps = 0
        self.held = 0
        self.rollbacks = 0
        self.reinitialised = 0
        self.waiting_said = False
        self.options = [dict(o.options) for o in self.builders]
        self.floats = FloatStep.of(fmu, self.feeds, self.out_vars)

    # ------------------------------------------------------------------ configure
    def configure(self, info: dict, robot: str) -> None:
        """Parameters (mapping file: numbers or sim/info paths; --param), checked against
        their min / max and set now, so a value the FMU refuses is a configuration error."""
        self.robot = robot
        # builder options may name the robot's frames: frame_id = "{robot}/odom"
        self.options = [{k: v.replace("{robot}", robot) for k, v in o.options.items()}
                        for o in self.builders]
        params = dict(self.cli_params)
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
            var = self.fmu.bus_variable(name)
            params[name] = (var, [in_bounds(var, value, where)])
        self.params = list(params.values())
        try:
            if self.params:
                self.fmu.write([v for v, _ in self.params], [x for _, x in self.params])
        except FmuCallError as exc:
            raise FmuNodeError(f"{self.mapping.where_parameters or '--param'}: the FMU "
                               f"{self.fmu.name} refused the parameters: {exc}") from None
        now = int(info.get("time_ns", 0) or 0)
        if now > 0 and not self.from_zero:
            self.log.info("%s joins at t=%.3f s: its model starts at the current bus time "
                          "(not 0; --from-zero waits for t=0)", self.instance, now * 1e-9)

    def on_session(self, session, keys) -> None:
        """Answer ``fmu/<instance>/info`` (bus.node calls this once the session is open)."""
        self.bus_keys = keys
        if self.generic_topics:        # its keys must be its own
            for reply in session.get(keys.fmu_info(self.instance), timeout=0.5):
                if reply.ok is not None:
                    other = json.loads(reply.ok.payload.to_bytes()).get("node") or "a node"
                    raise FmuNodeError(f"instance {self.instance!r} is on the bus already "
                                       f"({other}): give this one another --instance")
        self._queryable = session.declare_queryable(keys.fmu_info(self.instance),
                                                    self._answer_info)

    def _answer_info(self, query) -> None:
        try:
            query.reply(query.key_expr, jsonio.dumps(self.info()).encode())
        except Exception as exc:     # the asker went away
            self.log.debug("fmu info reply: %s", exc)

    def info(self) -> dict:
        """What ``fmu/<instance>/info`` answers: the node, its time base, its variables."""
        keys = getattr(self, "bus_keys", None) or Keys()
        robot = getattr(self, "robot", "<robot>")

        def key(topic):
            return keys.topic(robot, topic)

        def mapped(topic, field):    # a field of a robot message (mapping file)
            return {"type": TOPICS[topic].msgtype, "field": field} if topic in TOPICS else {}
        variables = [dict(f.var.info(key(f.topic)), direction="input",
                          **mapped(f.topic, str(f.field)),
                          awaited=not f.external) for f in self.feeds]
        variables += [dict(v.info(key(t)), direction="output")
                      for v, t in zip(self.generic, self.generic_topics)]
        variables += [dict(self.fmu.bus_variable(var).info(key(o.topic)), direction="output",
                           message=o.message, **mapped(o.topic, f))
                      for o in self.builders for f, var in o.fields.items()]
        variables += [dict(v.info(""), direction="parameter", value=x if v.shape else x[0])
                      for v, x in self.params]
        return {"instance": self.instance, "node": getattr(self, "node_name", None),
                "model_identifier": self.fmu.model_identifier,
                "fmu": self.fmu.name, "fmi_version": self.fmu.md.fmiVersion,
                "step_size_s": self.step_size, "step": "own" if self.step_size else "tick",
                "start": "from zero" if self.from_zero else "bus time",
                "started_at_s": self.t0 if self.t_ns is not None else None,
                "mapping": self.mapping.path or None,
                "variables": variables}

    # ------------------------------------------------------------------ step
    def read(self, obs) -> list | None:
        """Values per feed from the latest messages (None: nothing yet), or None and a
        reject for a bad sample; an external input's bad value is rejected and its last
        good one kept."""
        values = []
        for i, f in enumerate(self.feeds):
            msg = obs[f.topic]
            if msg is None:
                if f.external:
                    values.append(self.held_inputs[i])
                    continue
                return None               # nothing received yet: not a bad sample
            try:
                v = f.convert(f.raw(msg))
            except (LookupError, TypeError, ValueError) as exc:
                self.rejects.reject("input", f"{self.fmu.name}: {f.var.name} from "
                                             f"{f.topic}{'.' + str(f.field) if f.field else ''}"
                                             f": {exc}")
                if f.external:
                    values.append(self.held_inputs[i])
                    continue
                return None
            if f.external:
                self.held_inputs[i] = v
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
        fast = self.floats if self.t_ns is not None and t_ns != self.t_ns and self.prev \
            else None                 # (every value a good float64: fmus/floatstep.py)
        got = fast.inputs(obs, self.prev, (t_ns - self.t_ns) * 1e-9) if fast else None
        raw = self.read(obs) if got is None else got[0]
        if self.t_ns is None:
            if self.from_zero and t_ns != 0:
                if not self.waiting_said:
                    self.log.info("%s: bus time is %.3f s; waiting for t=0 to start "
                                  "(--from-zero: a plant started with --expect %s, or a "
                                  "reset)", self.instance, t_ns * 1e-9,
                                  getattr(self, "node_name", None) or self.instance)
                    self.waiting_said = True
                return None
            return self._start(t_ns, raw)
        if raw is None or t_ns == self.t_ns:      # bad sample, or this tick again
            self.held += raw is None
            return self.publish(t_ns)
        h = (t_ns - self.t_ns) * 1e-9
        values = got[1] if got is not None else self._values(raw, h)
        if values is None:
            self.held += 1
            return self.publish(t_ns)
        t_good, j_good = self.fmu.time, self.j
        try:
            out = fast.step(values, partial(self._advance, t_ns, h)) if got is not None \
                else self._step_fmu(values, t_ns, h)
        except FmuCallError as exc:
            self.rejects.reject("step", f"{self.fmu.name} at t={t_ns * 1e-9:.3f} s: {exc}")
            self.j = j_good
            self._recover(t_good)
            self.held += 1
            return self.publish(t_ns)
        self.fmu.snapshot()
        self.outputs = {v.name: x for v, x in zip(self.out_vars, out)}
        self.prev = raw
        self.t_ns = t_ns
        self.steps += 1
        return self.publish(t_ns)

    def _values(self, raw: list, h: float) -> list | None:
        """The values to set of ``raw`` (``rate`` inputs: the difference over ``h``), or None
        and a reject where one is not finite."""
        values = []
        for i, v in enumerate(raw):
            if self.rate[i] and v is not None:
                v = [(v[0] - self.prev[i][0]) / h] if self.prev is not None else [0.0]
            values.append(v)
        bad = [f.var.name for f, v in zip(self.feeds, values)
               if v is not None and f.var.numeric and not all(map(math.isfinite, v))]
        if bad:
            self.rejects.reject("input", f"{self.fmu.name}: {', '.join(bad)} not finite")
            return None
        return values

    def _step_fmu(self, values: list, t_ns: int, h: float) -> list:
        """Set ``values``, advance to ``t_ns``, the outputs (FmuCallError: a call failed or
        an output is not finite)."""
        given = [(f.var, v) for f, v in zip(self.feeds, values) if v is not None]
        if given:
            self.fmu.write([g[0] for g in given], [g[1] for g in given])
        self._advance(t_ns, h)
        out = self.fmu.read(self.out_vars)
        bad = [v.name for v, x in zip(self.out_vars, out)
               if v.numeric and not all(map(math.isfinite, x))]
        if bad:
            raise FmuCallError(f"non-finite output {', '.join(bad)}")
        return out

    def _advance(self, t_ns: int, h: float) -> None:
        """The FMU to the tick: one doStep over the tick, or (with its own step size dt)
        doSteps between its grid points t0 + j dt up to the tick, as fmpy's simulate_fmu
        steps (an FMU step longer than the tick happens at the tick that reaches it)."""
        if self.step_size is None:
            self.fmu.do_step(h)
            self.fmu_steps += 1
            return
        t = t_ns * 1e-9
        dt = self.step_size
        while (self.j + 1) * dt <= (t - self.t0) * (1 + 1e-12) + 1e-12:
            t_next = self.t0 + (self.j + 1) * dt
            self.fmu.do_step(t_next - self.fmu.time, t_next)
            self.j += 1
            self.fmu_steps += 1

    def _start(self, t_ns: int, raw: list | None):
        """First tick (or after a reset): initialise at t_ns, publish the initial outputs."""
        start = list(self.params)
        if raw is not None:
            start += [(f.var, [0.0] if r else v)
                      for f, r, v in zip(self.feeds, self.rate, raw) if v is not None]
        try:
            self.fmu.initialize(t_ns * 1e-9, start)
            self.outputs = {v.name: x for v, x in zip(self.out_vars,
                                                      self.fmu.read(self.out_vars))}
        except FmuCallError as exc:
            self.rejects.reject("step", f"{self.fmu.name}: initialisation at "
                                        f"t={t_ns * 1e-9:.3f} s failed: {exc}")
            self.fmu.reset()
            return self.publish(t_ns)
        if self.t0 != t_ns * 1e-9 or self.steps == 0:
            self.log.info("%s starts at t=%.3f s; %s", self.instance, t_ns * 1e-9,
                          f"its own step {self.step_size:g} s" if self.step_size else
                          "one doStep per control tick")
        self.t_ns = t_ns
        self.t0 = t_ns * 1e-9
        self.j = 0
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
            self.fmu.initialize(t_good, self.params)
            self.t0, self.j = t_good, 0
        except FmuCallError as exc:
            self.rejects.reject("step", f"{self.fmu.name}: initialisation failed: {exc}")
            self.fmu.reset()
            self.t_ns = None
            self.prev = None

    def publish(self, t_ns: int) -> dict | None:
        """The messages of the last good outputs, stamped t_ns (header) or by the
        attachment (the std_msgs of fmu/ keys)."""
        if self.outputs is None:
            return None
        out = {}
        for o, options in zip(self.builders, self.options):
            values = {f: float(self.outputs[var][0]) for f, var in o.fields.items()}
            # (its bytes written from the values; read as a message, it is built from the
            # values where its kind can (a member composed beside it), else decoded)
            make = o.kind.made
            out[o.topic] = Encoded(o.kind.pack(t_ns, values, options), o.kind.msgtype,
                                   make and partial(make, t_ns, values, options))
        for v, topic in zip(self.generic, self.generic_topics):
            out[topic] = v.message(self.outputs[v.name])
        return out

    def stats(self) -> dict:
        """The node's own counters (bus.controller.own_stats): under ``fmu`` in its
        ``--stats`` JSON, its rejects added to the node's."""
        return {"fmu": {"fmu": str(self.fmu.path), "fmi_version": self.fmu.version,
                        "instance": self.instance, "step_size_s": self.step_size,
                        "steps": self.steps, "fmu_steps": self.fmu_steps, "held": self.held,
                        "rollbacks": self.rollbacks, "reinitialised": self.reinitialised},
                "rejected": dict(self.rejects.counts)}

    def close(self) -> None:
        self.fmu.close()


def _step_size(fmu: Fmu, step: str | float) -> float | None:
    """The FMU's communication step: its DefaultExperiment stepSize ("fmu", the default;
    None if it declares none), one per control tick ("tick": None), or a number of s."""
    if step == "tick":
        return None
    if step == "fmu":
        return fmu.step_size
    return float(step)


# ====================================================================== command line

def open_node(fmu_arg: str | Path, mapping_path: str | Path | None = None,
              log: logging.Logger | None = None, instance_name: str = "fmu",
              **options) -> FmuNode:
    """Load the FMU and its mapping (``mapping_path``, else the model's shipped
    fmus/<modelIdentifier>/mapping.toml, else none: every variable on its fmu/ key) and
    check them against each other (FmuNodeError). ``options`` go to :class:`FmuNode`."""
    path = resolve_fmu(fmu_arg)
    fmu = Fmu(path, instance_name, log)
    try:
        if mapping_path is None:
            mapping_path = default_mapping(fmu.model_identifier)
        mapping = load_mapping(mapping_path) if mapping_path is not None else None
        return FmuNode(fmu, mapping, log, **options)
    except BaseException:
        fmu.close()
        raise
