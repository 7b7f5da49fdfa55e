"""The mapping file of ``diffbot fmu-node``: which message fields feed which FMU inputs,
which FMU outputs make which message, which FMU parameters come from ``sim/info``.

The format is in fmus/README.md ("The FMU on the bus") and in fmus/fmu_node.py. This module
checks the file on its own (keys, topics, message fields, message builders); the FMU's
variables are checked against it when the node is built (fmus/fmu_node.py). Every error is
one line ``file:key: reason`` (:class:`FmuNodeError`).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from bus import codec, made, packed
from bus.keys import TOPICS, BadName, check_fmu_topic, is_fmu_topic
from bus.controller import WHEEL_JOINTS
from plant.tomlfile import Table, read_toml

from .variables import Variable

FMUS_DIR = Path(__file__).resolve().parent


class FmuNodeError(ValueError):
    """A configuration error (FMU file, mapping file, sim/info); one line, exit code 2."""

# ====================================================================== field paths

_SEGMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)")
_INDEX = re.compile(r"\[(\d+)\]")
_NUMERIC = {"float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32",
            "int64", "uint64", "byte", "octet", "char"}


class FieldPath:
    """A path into a message or a JSON document: ``position[0]``, ``pose.pose.position.x``,
    ``robots.{robot}.pose[2]`` (``{robot}`` is replaced before parsing)."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.steps: list[str | int] = []
        if not isinstance(text, str) or not text:
            raise ValueError("expected a field path like position[0] or pose.pose.position.x")
        for part in text.split("."):
            m = _SEGMENT.fullmatch(part)
            if not m:
                raise ValueError(f"bad field path {text!r}: segment {part!r} is not "
                                 "name or name[index]")
            self.steps.append(m.group(1))
            self.steps += [int(i) for i in _INDEX.findall(m.group(2))]

    def __str__(self) -> str:
        return self.text

    def get(self, obj) -> Any:
        """The value at this path; raises LookupError if it is not there."""
        for s in self.steps:
            if isinstance(s, int):
                try:
                    obj = obj[s]
                except (IndexError, KeyError, TypeError):
                    raise LookupError(f"{self.text}: no element [{s}]") from None
            elif isinstance(obj, dict):
                if s not in obj:
                    raise LookupError(f"{self.text}: no key {s!r}")
                obj = obj[s]
            else:
                try:
                    obj = getattr(obj, s)
                except AttributeError:
                    raise LookupError(f"{self.text}: no field {s!r}") from None
        return obj

    def check_msgtype(self, msgtype: str) -> None:
        """Raise ValueError unless the path names a numeric field of ``msgtype``."""
        node: tuple = (2, msgtype)      # rosbags Nodetype: 1 BASE, 2 NAME, 3 ARRAY, 4 SEQUENCE
        where = msgtype
        for s in self.steps:
            kind = int(node[0])
            if isinstance(s, int):
                if kind not in (3, 4):
                    raise ValueError(f"{where} is not an array: [{s}] does not apply")
                if kind == 3 and s >= node[1][1]:
                    raise ValueError(f"{where} has {node[1][1]} elements: [{s}] is out of range")
                node = node[1][0]
                continue
            if kind != 2:
                raise ValueError(f"{where} has no fields ({s!r} does not apply)")
            fields = dict(codec.TYPESTORE.fielddefs[node[1]][1])
            if s not in fields:
                raise ValueError(f"{node[1]} has no field {s!r} (fields: {', '.join(fields)})")
            node, where = fields[s], f"{where}.{s}"
        if int(node[0]) in (3, 4):
            raise ValueError(f"{where} is an array: add an index, e.g. {self.text}[0]")
        if int(node[0]) != 1 or node[1][0] not in _NUMERIC:
            raise ValueError(f"{where} is not a number")


# ====================================================================== messages

@dataclass(frozen=True)
class MessageKind:
    """How a message is built from named numbers (each one fed by an FMU variable)."""
    msgtype: str
    required: tuple[str, ...]
    optional: tuple[str, ...]
    options: dict[str, str]                      # option -> default (strings)
    build: Callable[..., Any]                    # build(t_ns, values: dict, options: dict)
    #: pack(t_ns, values, options): the bytes of build's message, written straight from the
    #: values (bus.packed: no message tree built and encoded every tick)
    pack: Callable[..., bytes]
    #: made(t_ns, values, options): the message decoding pack's bytes gives, built from the
    #: values (bus.made), for a reader in the node's process; None: decoded where read
    made: Callable[..., Any] | None = None


MESSAGES: dict[str, MessageKind] = {
    "odometry": MessageKind(
        "nav_msgs/msg/Odometry", ("x", "y", "yaw"), ("linear", "angular"),
        {"frame_id": "world", "child_frame_id": "base_link"},
        lambda t, v, o: codec.odometry(t, v["x"], v["y"], v["yaw"], v.get("linear", 0.0),
                                       v.get("angular", 0.0), frame_id=o["frame_id"],
                                       child_frame_id=o["child_frame_id"]),
        lambda t, v, o: packed.odometry(t, v["x"], v["y"], 0.0, codec.yaw_quaternion(v["yaw"]),
                                        v.get("linear", 0.0), v.get("angular", 0.0),
                                        o["frame_id"], o["child_frame_id"]),
        lambda t, v, o: made.odometry(t, o["frame_id"], o["child_frame_id"], v["x"], v["y"],
                                      0.0, codec.yaw_quaternion(v["yaw"]),
                                      v.get("linear", 0.0), v.get("angular", 0.0))),
    "point": MessageKind(
        "geometry_msgs/msg/PointStamped", ("x", "y"), ("z",), {"frame_id": "world"},
        lambda t, v, o: codec.point_stamped(t, v["x"], v["y"], v.get("z", 0.0), o["frame_id"]),
        lambda t, v, o: packed.point_stamped(t, v["x"], v["y"], v.get("z", 0.0),
                                             o["frame_id"])),
    "twist": MessageKind(
        "geometry_msgs/msg/TwistStamped", ("linear", "angular"), (), {"frame_id": "base_link"},
        lambda t, v, o: codec.twist_stamped(t, v["linear"], v["angular"], o["frame_id"]),
        lambda t, v, o: codec.twist_stamped_bytes(t, v["linear"], v["angular"], o["frame_id"])),
    "wheel_speeds": MessageKind(
        "sensor_msgs/msg/JointState", ("left", "right"), (), {},
        lambda t, v, o: codec.joint_state(t, WHEEL_JOINTS, velocity=(v["left"], v["right"])),
        lambda t, v, o: packed.joint_state(t, WHEEL_JOINTS, (), (v["left"], v["right"]))),
}


# ====================================================================== mapping file

@dataclass
class InputMap:
    variable: str
    topic: str                      # a robot topic, or an FMU node's key fmu/<instance>/<var>
    field: FieldPath | None         # None: an fmu/ key, its whole value
    transform: str = "value"        # "value" or "rate"
    scale: float = 1.0
    where: str = ""                 # "file:input[0]" for messages
    msgtype: str | None = None      # fmu/ key: the producer's std_msgs type (default: the
    #                                 input variable's own)


@dataclass
class OutputMap:
    topic: str
    kind: MessageKind
    message: str
    fields: dict[str, str]          # builder field -> FMU variable
    options: dict[str, str]
    where: str = ""


@dataclass
class Mapping:
    path: str
    inputs: list[InputMap] = field(default_factory=list)
    outputs: list[OutputMap] = field(default_factory=list)
    parameters: dict[str, float | str] = field(default_factory=dict)   # name -> number | path
    where_parameters: str = ""
    #: the FMU's communication step: "fmu" (its DefaultExperiment stepSize), "tick" (one
    #: doStep per control tick) or seconds; ``diffbot fmu-node --step-size`` overrides it
    step_size: str | float = "fmu"

    @property
    def topics(self) -> list[str]:
        """The input topics, in order of first use."""
        return list(dict.fromkeys(i.topic for i in self.inputs))


TRANSFORMS = ("value", "rate")


def load_mapping(path: str | Path) -> Mapping:
    """Read and check a mapping file (syntax, keys, topics, message fields); the FMU's
    variables are checked by :meth:`Fmu.check_mapping`. Raises FmuNodeError."""
    path = str(path)
    if not Path(path).exists():
        raise FmuNodeError(f"{path}: no such mapping file")
    data = read_toml(path, FmuNodeError)
    m = Mapping(path)
    top = Table(path, "", data, FmuNodeError)
    raw_inputs = top.raw("input", [])
    if isinstance(raw_inputs, dict):
        raw_inputs = [raw_inputs]
    if not isinstance(raw_inputs, list):
        top.fail("input", "expected [[input]] tables")
    seen: set[str] = set()
    for n, raw in enumerate(raw_inputs):
        t = Table(path, f"input[{n}]", raw, FmuNodeError)
        var = t.string("variable", nonempty=True)
        if var in seen:
            t.fail("variable", f"{var!r} is fed twice")
        seen.add(var)
        topic = t.string("topic", nonempty=True)
        fp, msgtype = _input_source(t, topic)
        transform = t.string("transform", "value", TRANSFORMS)
        scale = t.number("scale", 1.0)
        t.done(("variable", "topic", "field", "type", "transform", "scale"))
        m.inputs.append(InputMap(var, topic, fp, transform, scale, f"{path}:input[{n}]",
                                 msgtype))

    raw_outputs = top.raw("output", [])
    single = isinstance(raw_outputs, dict)
    if single:
        raw_outputs = [raw_outputs]
    if not isinstance(raw_outputs, list):
        top.fail("output", "expected [output] tables")   # none: every output on fmu/ keys
    for n, raw in enumerate(raw_outputs):
        t = Table(path, "output" if single else f"output[{n}]", raw, FmuNodeError)
        topic = t.string("topic", nonempty=True)
        if topic not in TOPICS:
            t.fail("topic", f"unknown topic {topic!r} (topics: {', '.join(TOPICS)})")
        message = t.string("message", nonempty=True)
        if message not in MESSAGES:
            t.fail("message", f"unknown message {message!r} (messages: {', '.join(MESSAGES)})")
        kind = MESSAGES[message]
        if kind.msgtype != TOPICS[topic].msgtype:
            t.fail("message", f"{message} builds {kind.msgtype} but {topic} carries "
                              f"{TOPICS[topic].msgtype}")
        options = {o: t.string(o, d, nonempty=True) for o, d in kind.options.items()}
        fields = {}
        for f in kind.required + kind.optional:
            if f in t.data or f in kind.required:
                fields[f] = t.string(f, nonempty=True)
        t.done(("topic", "message", *kind.options, *kind.required, *kind.optional))
        m.outputs.append(OutputMap(topic, kind, message, fields, options, f"{path}:{t.where}"))

    t = top.table("parameters")
    for name, v in t.data.items():
        t.used.add(name)
        if isinstance(v, str):
            try:
                FieldPath(v.replace("{robot}", "robot"))
            except ValueError as exc:
                t.fail(name, str(exc))
        elif isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            t.fail(name, f"expected a number or a sim/info path like "
                         f"\"robots.{{robot}}.wheel_radius_m\", got {v!r}")
        m.parameters[name] = v
    m.where_parameters = f"{path}:parameters"
    step = top.raw("step_size", "fmu")
    if step not in ("fmu", "tick") and (isinstance(step, bool) or not isinstance(
            step, (int, float)) or not 0 < step < math.inf):
        top.fail("step_size", f"expected \"fmu\", \"tick\" or a step in s > 0, got {step!r}")
    m.step_size = step
    top.done(("input", "output", "parameters", "step_size"))
    return m


def _input_source(t: Table, topic: str) -> tuple[FieldPath | None, str | None]:
    """(field path, producer's type) of an input: a robot topic needs a numeric field; an
    ``fmu/<instance>/<variable>`` key carries one variable whole (``type`` optional)."""
    if is_fmu_topic(topic):
        try:
            check_fmu_topic(topic)
        except BadName as exc:
            t.fail("topic", str(exc))
        if "field" in t.data:
            t.fail("field", f"{topic} carries one FMU variable: no field (docs/fmu.md)")
        kind = t.string("type", "", nonempty=True)
        if kind and f"std_msgs/msg/{kind}" not in codec.TYPESTORE.fielddefs:
            t.fail("type", f"unknown std_msgs type {kind!r} (e.g. Float64, Int32, Bool)")
        return None, f"std_msgs/msg/{kind}" if kind else None
    if topic not in TOPICS:
        t.fail("topic", f"unknown topic {topic!r} (topics: {', '.join(TOPICS)}, or an FMU "
                        "node's fmu/<instance>/<variable>)")
    text = t.string("field", nonempty=True)
    try:
        fp = FieldPath(text)
        fp.check_msgtype(TOPICS[topic].msgtype)
    except ValueError as exc:
        t.fail("field", str(exc))
    return fp, None


def default_mapping(model_identifier: str) -> Path | None:
    p = FMUS_DIR / model_identifier / "mapping.toml"
    return p if p.is_file() else None


# ====================================================================== parameters

def in_bounds(var: Variable, value: float, where: str) -> float:
    """``value`` if it is within the variable's declared min / max, else FmuNodeError."""
    lo = var.min if var.min is not None else -math.inf
    hi = var.max if var.max is not None else math.inf
    if not lo <= value <= hi:
        raise FmuNodeError(f"{where}: {value:g} is outside the bounds of {var.name!r} "
                           f"[{lo:g}, {hi:g}] declared by the FMU")
    if var.fmi_type not in ("Real", "Float64", "Float32") and value != int(value):
        raise FmuNodeError(f"{where}: {var.name!r} is {var.fmi_type}: {value!r} is not an "
                           "integer")
    return value if var.fmi_type in ("Real", "Float64", "Float32") else int(value)


def cli_parameters(fmu, given: dict[str, str]) -> dict[str, tuple[Variable, list]]:
    """``--param NAME=VALUE`` of ``fmu`` (an :class:`fmus.fmu.Fmu`): checked against the
    variable's causality, type and bounds."""
    out = {}
    for name, text in given.items():
        where = f"--param {name}={text}"
        var = fmu.variable(name, "parameter", where)
        if var.shape:
            raise FmuNodeError(f"{where}: {name!r} is an array: set it in a mapping file")
        if var.msgtype == "std_msgs/msg/String":
            out[name] = (var, [text])
            continue
        if var.msgtype == "std_msgs/msg/Bool":
            if text.lower() not in ("true", "false", "1", "0"):
                raise FmuNodeError(f"{where}: {name!r} is Boolean: true or false")
            out[name] = (var, [text.lower() in ("true", "1")])
            continue
        try:
            value = float(text)
        except ValueError:
            raise FmuNodeError(f"{where}: {text!r} is not a number") from None
        out[name] = (var, [in_bounds(var, value, where)])
    return out
