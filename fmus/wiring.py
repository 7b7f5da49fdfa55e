"""Where an FMU node's inputs come from and its outputs go (docs/fmu.md).

An input variable is fed by one :class:`Feed`: a numeric field of a robot topic (mapping
file), another FMU node's key ``fmu/<instance>/<variable>`` (mapping file or
``--connect VAR=KEY``: awaited every tick in lockstep, so FMUs chain), or, when nothing
else feeds it, the node's own key ``fmu/<instance>/<variable>`` (anyone may publish there;
never awaited: the last value received holds, the start value until one comes).
An output variable is published on ``fmu/<instance>/<variable>`` unless a mapping file
builds robot messages from the outputs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bus.keys import TOPICS, Topic, check_fmu_topic, fmu_topic

from .mapping import FieldPath, FmuNodeError, InputMap
from .variables import Unsupported, Variable

_INT_TYPES = ("Int8", "Int16", "Int32", "Int64", "UInt8", "UInt16", "UInt32", "UInt64")


@dataclass
class Feed:
    """One input variable and where its values come from."""
    var: Variable
    topic: str                    # robot topic name or fmu/<instance>/<variable>
    field: FieldPath | None       # robot topic: the numeric field
    rate: bool = False            # value difference over the tick instead of the value
    scale: float = 1.0
    external: bool = False        # the node's own key: never awaited, last value holds
    where: str = ""

    def __post_init__(self) -> None:
        self.kind = self.var.msgtype.rsplit("/", 1)[1].replace("MultiArray", "")

    def raw(self, msg) -> list:
        """The values in ``msg`` as numbers (bool / str for those types); ValueError,
        LookupError or TypeError if the message does not carry them."""
        if self.field is not None:
            return [float(self.field.get(msg)) * self.scale]
        if self.var.shape:
            values = self.var.values(msg)
        else:
            values = [msg.data]
        if self.var.numeric and self.scale != 1.0:
            values = [float(v) * self.scale for v in values]
        return values

    def convert(self, values: list) -> list:
        """``values`` as the variable's FMI type; ValueError when they do not fit (a
        fraction or an out-of-range number for an integer, a non-finite number)."""
        kind = self.kind
        if kind == "Float64":           # the common case first
            out = [float(v) for v in values]
            if not all(map(math.isfinite, out)):
                raise ValueError(f"{out} is not finite")
            return out
        if kind == "String":
            return [str(v) for v in values]
        if kind == "Bool":
            return [bool(v) for v in values]
        out = []
        for v in values:
            if isinstance(v, str):
                raise ValueError(f"{v!r} is not a number")
            if not math.isfinite(float(v)):
                raise ValueError(f"{float(v)} is not finite")
            if kind in _INT_TYPES:
                if float(v) != int(v):
                    raise ValueError(f"{v} is not an integer ({self.var.fmi_type})")
                info = np.iinfo(kind.lower())
                lo, hi = int(info.min), int(info.max)
                if not lo <= int(v) <= hi:
                    raise ValueError(f"{int(v)} is out of the range of {self.var.fmi_type}")
                out.append(int(v))
            else:
                out.append(float(v))
        return out


def build_feeds(fmu, instance: str, inputs: list[InputMap], connect: dict[str, str],
                log) -> tuple[list[Feed], dict[str, Topic]]:
    """The feeds of every input variable, and the catalog entries of the ``fmu/`` topics
    they read (bus.node's ``topics``)."""
    feeds: list[Feed] = []
    topics: dict[str, Topic] = {}
    for i in inputs:
        var = fmu.variable(i.variable, "input", f"{i.where}.variable")
        if i.field is None:
            topics[i.topic] = _fmu_topic(i.topic, i.msgtype or var.msgtype, "node", var)
        elif not var.numeric or var.shape:
            raise FmuNodeError(f"{i.where}.variable: {i.variable!r} is {var.fmi_type}"
                               f"{' array' if var.shape else ''}: a message field cannot "
                               "feed it (an fmu/ key can)")
        if i.transform == "rate" and not var.numeric:
            raise FmuNodeError(f"{i.where}.transform: {i.variable!r} is {var.fmi_type}: "
                               "no rate of it")
        feeds.append(Feed(var, i.topic, i.field, i.transform == "rate", i.scale, False,
                          i.where))
    for name, key in connect.items():
        where = f"--connect {name}={key}"
        if any(f.var.name == name for f in feeds):
            raise FmuNodeError(f"{where}: {name!r} is fed twice")
        try:
            check_fmu_topic(key)
        except ValueError as exc:
            raise FmuNodeError(f"{where}: {exc}") from None
        var = fmu.variable(name, "input", where)
        topics[key] = _fmu_topic(key, var.msgtype, "node", var)
        feeds.append(Feed(var, key, None, where=where))
    fed = {f.var.name for f in feeds}
    for v in fmu.md.modelVariables:
        if v.causality != "input" or v.name in fed:
            continue
        try:
            var = fmu.bus_variable(v.name)
        except Unsupported as exc:
            log.warning("%s: input %s: left at its start value", fmu.name, exc)
            continue
        topic = fmu_topic(instance, v.name)
        topics[topic] = _fmu_topic(topic, var.msgtype, "external", var)
        feeds.append(Feed(var, topic, None, external=True, where=f"input {v.name!r}"))
    for t in topics:
        if t in TOPICS:
            raise FmuNodeError(f"{t}: not an fmu/ key")
    return feeds, topics


def _fmu_topic(topic: str, msgtype: str, source: str, var: Variable) -> Topic:
    return Topic(topic, msgtype, source, "every control tick", var.unit or "-", "-")


def output_variables(fmu, log) -> list[Variable]:
    """Every output variable the bus can carry (the others are named in the log)."""
    out = []
    for v in fmu.md.modelVariables:
        if v.causality != "output":
            continue
        try:
            out.append(fmu.bus_variable(v.name))
        except Unsupported as exc:
            log.warning("%s: output %s: not published", fmu.name, exc)
    return out
