"""FMU variables as bus messages: which ROS 2 ``std_msgs`` type carries which FMI type, and
how values go into and out of those messages (docs/fmu.md, "Types").

=================================  ==========================  ===============================
FMI 2                              FMI 3                       message (scalar / FMI 3 array)
=================================  ==========================  ===============================
Real                               Float64                     Float64 / Float64MultiArray
-                                  Float32                     Float32 / Float32MultiArray
Integer, Enumeration               Int32                       Int32 / Int32MultiArray
-                                  Int8, Int16, Int64          Int8.. / Int8MultiArray..
-                                  UInt8 .. UInt64             UInt8.. / UInt8MultiArray..
-                                  Enumeration                 Int64 / Int64MultiArray
Boolean                            Boolean                     Bool (no array type)
String                             String                      String (no array type)
=================================  ==========================  ===============================

FMI 3 Binary and Clock variables, and arrays of Boolean or String (std_msgs has no such
array type) are not carried: the node says so at start and leaves them out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bus import codec
from bus.keys import escape_variable

T = codec.T

#: FMI type -> (the fmpy get/set suffix, std_msgs type name, numpy dtype of an array)
_FMI2 = {"Real": ("Real", "Float64", "float64"), "Integer": ("Integer", "Int32", "int32"),
         "Enumeration": ("Integer", "Int32", "int32"), "Boolean": ("Boolean", "Bool", None),
         "String": ("String", "String", None)}
_FMI3 = {"Float64": ("Float64", "Float64", "float64"), "Float32": ("Float32", "Float32", "float32"),
         **{t: (t, t, t.lower()) for t in ("Int8", "Int16", "Int32", "Int64", "UInt8", "UInt16",
                                          "UInt32", "UInt64")},
         "Enumeration": ("Int64", "Int64", "int64"), "Boolean": ("Boolean", "Bool", None),
         "String": ("String", "String", None)}


class Unsupported(ValueError):
    """A variable the bus cannot carry (the reason is the message)."""


@dataclass(eq=False)     # hashed by identity: fmus.fmu caches its call plans per variables
class Variable:
    """One FMU variable as the bus sees it."""
    name: str
    vr: int
    fmi_type: str           # as in the model description (Real, Int32, ...)
    access: str             # fmpy get/set suffix: getReal, getFloat64, getInteger, ...
    msgtype: str            # ROS 2 type on the bus
    shape: tuple[int, ...]  # () for a scalar
    causality: str
    variability: str
    unit: str | None
    min: float | None
    max: float | None
    start: str | None
    description: str | None
    dtype: str | None = None   # numpy dtype of an array's elements

    def __post_init__(self) -> None:
        #: number of values (1 for a scalar)
        self.size = math.prod(self.shape) if self.shape else 1
        #: a number (not a Bool or a String)
        self.numeric = self.msgtype not in ("std_msgs/msg/Bool", "std_msgs/msg/String")


    @property
    def segment(self) -> str:
        """The variable's key segment (bus.keys.escape_variable)."""
        return escape_variable(self.name)

    # ------------------------------------------------------------------ messages
    def message(self, values: list):
        """The message carrying ``values`` (a list of ``size`` values)."""
        if not self.shape:
            x = values[0]
            if self.msgtype == "std_msgs/msg/Bool":
                x = bool(x)
            elif self.msgtype == "std_msgs/msg/String" and isinstance(x, bytes):
                x = x.decode("utf-8", "replace")
            return T[self.msgtype](data=x)
        dims = []
        stride = self.size
        for i, n in enumerate(self.shape):
            dims.append(T["std_msgs/msg/MultiArrayDimension"](label=f"dim{i}", size=n,
                                                               stride=stride))
            stride //= n
        layout = T["std_msgs/msg/MultiArrayLayout"](dim=dims, data_offset=0)
        return T[self.msgtype](layout=layout, data=np.asarray(values, dtype=self.dtype))

    def values(self, msg) -> list:
        """The values in a message of this variable's type (ValueError if they do not fit)."""
        if not self.shape:
            return [msg.data]
        data = np.asarray(msg.data).ravel()
        if data.size != self.size:
            raise ValueError(f"{self.name} has {self.size} elements {list(self.shape)}, the "
                             f"message {data.size}")
        return data.tolist()

    def info(self, key: str) -> dict:
        """The variable's entry in ``fmu/<instance>/info``."""
        d = {"name": self.name, "key": key, "type": self.msgtype, "fmi_type": self.fmi_type,
             "causality": self.causality, "variability": self.variability}
        if self.shape:
            d["shape"] = list(self.shape)
        for k in ("unit", "min", "max", "start", "description"):
            if getattr(self, k) is not None:
                d[k] = getattr(self, k)
        return d


def _number(text) -> float | None:
    try:
        return float(text) if text is not None else None
    except ValueError:
        return None


def variable(v, version: int, md_variables: list) -> Variable:
    """The bus view of fmpy's ModelVariable ``v`` (Unsupported if the bus cannot carry it)."""
    table = _FMI2 if version == 2 else _FMI3
    if v.type not in table:
        raise Unsupported(f"{v.name}: FMI type {v.type} is not carried on the bus")
    access, msg, dtype = table[v.type]
    shape: tuple[int, ...] = ()
    if getattr(v, "dimensions", None):
        if dtype is None:
            raise Unsupported(f"{v.name}: an array of {v.type} (std_msgs has no such array)")
        by_vr = {w.valueReference: w for w in md_variables}
        dims = []
        for d in v.dimensions:
            if d.start is not None:
                dims.append(int(d.start))
            else:
                src = by_vr.get(d.valueReference)
                if src is None or src.start is None:
                    raise Unsupported(f"{v.name}: its size has no start value")
                dims.append(int(src.start))
        shape = tuple(dims)
        msg += "MultiArray"
    unit = v.unit or (v.declaredType.unit if getattr(v, "declaredType", None) is not None and
                      hasattr(v.declaredType, "unit") else None)
    return Variable(v.name, v.valueReference, v.type, access, f"std_msgs/msg/{msg}", shape,
                    v.causality, v.variability, unit, _number(_bound(v, "min")),
                    _number(_bound(v, "max")), v.start, v.description, dtype)


def _bound(v, which: str):
    value = getattr(v, which, None)
    if value is None and getattr(v, "declaredType", None) is not None:
        value = getattr(v.declaredType, which, None)
    return value

