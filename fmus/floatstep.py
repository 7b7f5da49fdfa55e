"""An FMU node's tick where every value is one float64: :class:`FloatStep`.

The odometry FMU's node, like most FMU nodes that turn robot messages into robot messages,
reads a few scalar fields (encoder angles), sets as many float64 inputs, steps and reads a
few float64 outputs. :meth:`fmus.fmu_node.FmuNode.step` handles every variable type and
every bad sample; for this case, once the FMU has started and every input is good, a tick
is done here with one ``fmi2SetReal``/``fmi3SetFloat64`` and one ``fmi2GetReal``/
``fmi3GetFloat64`` call on value-reference and value arrays built once (:class:`FloatIO`),
each field read by one ``operator.attrgetter``: the same values in the same calls as the
general path, without building its per-variable lists every tick. Anything else (an input
missing, not a number, not finite; the first tick; a tick again) goes the general way,
which rejects and reports it, before anything here touched the FMU.
"""
from __future__ import annotations

import math
from ctypes import c_double, c_uint
from operator import attrgetter
from typing import Callable

from .fmu import Fmu, FmuCallError
from .variables import Variable


class FloatIO:
    """Set a fixed list of float64 inputs and get a fixed list of float64 outputs of an
    :class:`fmus.fmu.Fmu`, one FMI call each; the calls' arguments are made again when the
    FMU's instance changes (a reset that instantiated it again)."""

    def __init__(self, fmu: Fmu, inputs: list[Variable], outputs: list[Variable]) -> None:
        self.fmu = fmu
        self._in = ((c_uint * len(inputs))(*[v.vr for v in inputs]), (c_double * len(inputs))())
        self._out = ((c_uint * len(outputs))(*[v.vr for v in outputs]),
                     (c_double * len(outputs))())
        self._setter = fmu._setter[inputs[0].access] if inputs else None
        self._getter = "fmi2GetReal" if fmu.version == 2 else "fmi3GetFloat64"
        self._inst = None
        self._args: tuple = ((), ())

    def _calls(self) -> tuple:
        if self.fmu.fmu is not self._inst:
            self._inst = self.fmu.fmu
            if self._inst is None:
                self._args = ((), ())
            else:
                self._args = tuple(self.fmu._args(vrs, len(vrs), vals, len(vrs))
                                   for vrs, vals in (self._in, self._out))
        return self._args

    def set(self, values: list[float]) -> None:
        if self._setter is None:
            return
        self._in[1][:] = values
        self.fmu._call("set (float64 inputs)", self._setter, *self._calls()[0])

    def get(self) -> list[float]:
        self.fmu._call("get (float64 outputs)", self._getter, *self._calls()[1])
        return self._out[1][:]


def _getter(steps: list) -> Callable | None:
    """A message field path's steps (:class:`fmus.mapping.FieldPath`) as one function:
    names, then at most one index; None for other paths (the general way reads them)."""
    names = [s for s in steps if isinstance(s, str)]
    index = steps[len(names):]
    if not names or steps[:len(names)] != names or len(index) > 1:
        return None
    get = attrgetter(".".join(names))
    if not index:
        return get
    i = index[0]
    return lambda msg: get(msg)[i]


class FloatStep:
    """The plan of a float64-only FMU node's tick (module docstring); :meth:`of` is None
    where the node is not one."""

    def __init__(self, fmu: Fmu, feeds: list, out_vars: list[Variable]) -> None:
        self.feeds = [(f.topic, _getter(f.field.steps), f.scale, f.rate) for f in feeds]
        self.io = FloatIO(fmu, [f.var for f in feeds], out_vars)
        self.names = [v.name for v in out_vars]

    @classmethod
    def of(cls, fmu: Fmu, feeds: list, out_vars: list[Variable]) -> "FloatStep | None":
        def scalar(v: Variable) -> bool:
            return v.access in fmu._setter and v.size == 1 and not v.shape
        if not feeds or not out_vars or not all(map(scalar, out_vars)):
            return None
        for f in feeds:
            if f.external or f.field is None or f.kind != "Float64" or not scalar(f.var) \
                    or _getter(f.field.steps) is None:
                return None
        return cls(fmu, feeds, out_vars)

    def inputs(self, obs, prev: list, h: float) -> tuple[list, list] | None:
        """(the raw values as the general path keeps them, the values to set: a ``rate``
        input's difference to ``prev`` over ``h``) of ``obs``; None where an input is
        missing, not a number or not finite (the general way says why)."""
        raw, values = [], []
        try:
            msgs = obs.msgs
            for i, (topic, get, scale, rate) in enumerate(self.feeds):
                v = float(get(msgs[topic])) * scale
                raw.append([v])
                values.append((v - prev[i][0]) / h if rate else v)
        except (LookupError, TypeError, ValueError, AttributeError, ZeroDivisionError):
            return None
        if not math.isfinite(sum(raw_v[0] for raw_v in raw)) or \
                not math.isfinite(sum(values)):
            return None
        return raw, values

    def step(self, values: list[float], advance: Callable[[], None]) -> list[list[float]]:
        """Set ``values``, ``advance()`` the FMU, and its outputs (a list of one value each,
        as :meth:`fmus.fmu.Fmu.read` gives them); FmuCallError if a call fails or an output
        is not finite."""
        io = self.io
        io.set(values)
        advance()
        out = io.get()
        if not math.isfinite(sum(out)):
            bad = [n for n, x in zip(self.names, out) if not math.isfinite(x)]
            if bad:
                raise FmuCallError(f"non-finite output {', '.join(bad)}")
        return [[x] for x in out]
