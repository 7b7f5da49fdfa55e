"""The plant FMU's FMU state: everything one instance's next tick depends on, taken and put
back (FMI ``getFMUState``/``setFMUState``) and written as bytes (``serializeFMUState``).

A state holds, for a :class:`fmus.plant_fmu.PlantInstance`: its FMI state, start time and
tick count, every variable's value (inputs and parameters), the last outputs (pose,
odometry, encoder readings, scans, contact flags) and the dead reckoning's last pose; and of
its world (:class:`plant.tick.Tick`), when one is built: the physics time (steps), each DART
skeleton's positions, velocities and accelerations, each robot's wheel set-points and its
drive limiter (the commanded v, w and wheel speeds it ramps from). The sensors' schedule
and all noise follow from the tick count (a noise value is a function of the seed, the
stream, the tick and its index: :mod:`plant.noise`). Putting a state back and stepping
again gives the same outputs to the bit (``tests/fmus/test_plant_fmu.py``).

Serialized, a state is UTF-8 JSON (floats written as Python's shortest round-trip repr, so
they come back to the bit; no pickle: deserializing runs no code), tagged with the FMU's
instantiation token: a state of another FMU is refused. A kinematic world's state is not
supported (the call says so).
"""
from __future__ import annotations

import ctypes
import json

import numpy as np

FORMAT = "diffbot-plant-fmu-state/2"
OK = 0


def _array(a) -> list:
    return np.asarray(a, dtype=np.float64).tolist()


def world_state(tick, touching: set | None) -> dict:
    """The world's part of a state (module docstring)."""
    sim = tick.sim
    if sim.kin is not None:
        raise ValueError("the FMU state of a kinematic world is not supported")
    world = sim.world
    return {
        "steps": sim.steps,
        "time": world.getTime(),
        "skeletons": [[sk.getName(), _array(sk.getPositions()), _array(sk.getVelocities()),
                       _array(sk.getAccelerations())]
                      for sk in (world.getSkeleton(i) for i in range(world.getNumSkeletons()))],
        "robots": {name: {"targets": sim.drive.targets[i].tolist(),
                          "limiter": [v, w, list(wheels)]}
                   for i, name in enumerate(sim.drive.names)
                   for v, w, wheels in [sim.drive.limiter(i)]},
        "touching": sorted(touching) if touching is not None else None,
    }


def set_world_state(tick, state: dict) -> None:
    """Put a world's state back into ``tick`` (a world of the same spec)."""
    sim = tick.sim
    world = sim.world
    if len(state["skeletons"]) != world.getNumSkeletons():
        raise ValueError(f"the state has {len(state['skeletons'])} bodies, the world "
                         f"{world.getNumSkeletons()}: a state of another world")
    for i, (name, q, dq, ddq) in enumerate(state["skeletons"]):
        sk = world.getSkeleton(i)
        if sk.getName() != name or sk.getNumDofs() != len(q):
            raise ValueError(f"the state's body {name!r} is not the world's {sk.getName()!r}")
        sk.setPositions(np.array(q, dtype=np.float64))
        sk.setVelocities(np.array(dq, dtype=np.float64))
        sk.setAccelerations(np.array(ddq, dtype=np.float64))
    world.setTime(float(state["time"]))
    sim.restore_clock(state["steps"])
    drive = sim.drive
    for name, r in state["robots"].items():
        i = drive.index[name]
        drive.targets[i] = [float(v) for v in r["targets"]]
        drive.set_limiter(i, float(r["limiter"][0]), float(r["limiter"][1]),
                          [float(v) for v in r["limiter"][2]])


def to_bytes(token: str, state: dict) -> bytes:
    return json.dumps({"format": FORMAT, "token": token, "state": state},
                      separators=(",", ":")).encode("utf-8")


def from_bytes(token: str, data: bytes) -> dict:
    """A state written by :func:`to_bytes` for this FMU (ValueError otherwise)."""
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"not a serialized state of the plant FMU ({e})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"not a serialized state of the plant FMU (format {FORMAT} expected)")
    if doc.get("token") != token:
        raise ValueError(f"a state of another FMU (token {doc.get('token')!r}, this one's "
                         f"{token!r})")
    return doc["state"]


class FmuStates:
    """The FMU state calls of :class:`fmus.plant_fmu.PlantInstance` (a mixin: it uses the
    instance's variables, world and error handling)."""

    def get_state(self, sid: int, sid_addr: int) -> int:
        """getFMUState: a new state (``sid`` 0) or state ``sid`` overwritten; its id is
        written at ``sid_addr`` (uint64)."""
        return self._guard(self._get_state, sid, sid_addr)

    def set_state(self, sid: int) -> int:
        return self._guard(lambda: self._restore(self._state(sid)) or OK)

    def free_state(self, sid: int) -> int:
        self.states.pop(sid, None)
        return OK

    def state_size(self, sid: int, size_addr: int) -> int:
        return self._guard(self._state_size, sid, size_addr)

    def serialize_state(self, sid: int, addr: int, size: int) -> int:
        return self._guard(self._serialize_state, sid, addr, size)

    def deserialize_state(self, addr: int, size: int, sid_addr: int) -> int:
        return self._guard(self._deserialize_state, addr, size, sid_addr)

    def _state(self, sid: int) -> dict:
        if sid not in self.states:
            raise ValueError(f"FMU state {sid} is not one of this instance's (freed?)")
        return self.states[sid]

    def _new_state(self, state: dict, sid_addr: int) -> int:
        self._last_state += 1
        self.states[self._last_state] = state
        ctypes.c_uint64.from_address(sid_addr).value = self._last_state
        return OK

    def _get_state(self, sid: int, sid_addr: int) -> int:
        state = self._capture()
        if not sid:
            return self._new_state(state, sid_addr)
        self._state(sid)
        self.states[sid] = state
        self._serialized = None
        ctypes.c_uint64.from_address(sid_addr).value = sid
        return OK

    def _bytes(self, sid: int) -> bytes:
        if self._serialized is None or self._serialized[0] != sid:
            self._serialized = (sid, to_bytes(self.cfg["token"], self._state(sid)))
        return self._serialized[1]

    def _state_size(self, sid: int, size_addr: int) -> int:
        ctypes.c_uint64.from_address(size_addr).value = len(self._bytes(sid))
        return OK

    def _serialize_state(self, sid: int, addr: int, size: int) -> int:
        data = self._bytes(sid)
        if size < len(data):
            return self.fail(f"serializeFMUState: {size} bytes given, the state takes {len(data)}")
        ctypes.memmove(addr, data, len(data))
        return OK

    def _deserialize_state(self, addr: int, size: int, sid_addr: int) -> int:
        return self._new_state(from_bytes(self.cfg["token"],
                                                      ctypes.string_at(addr, size)), sid_addr)

    def _params(self) -> list:
        return sorted([v.vr, self.values[v.vr]] for v in self.vars if v.causality == "parameter")

    def _capture(self) -> dict:
        """This instance's state (fmus/py), plain data (JSON's types)."""
        if self.tick is not None and self.touching is None:
            self.touching = self.contacts_now()
        odom = getattr(self, "odom", {}) if self.tick is not None else {}
        return {"state": self.state, "start_time": self.start_time, "ticks": self.ticks,
                "values": [[vr, v] for vr, v in self.values.items()],
                "out": [[r, f, v] for (r, f), v in self.out.items()],
                "scans": {r: a.tolist() for r, a in self.scans.items()},
                "odom": {r: None if o is None else [list(o[0]), o[1].tolist()]
                         for r, o in odom.items()},
                "built_from": self._built_from if self.tick is not None else None,
                "world": (world_state(self.tick, self.touching)
                          if self.tick is not None else None)}

    def _restore(self, s: dict) -> None:
        self.values = {int(vr): v for vr, v in s["values"]}
        if s["world"] is None:
            self._close_tick()
        else:
            if self.tick is None or self._built_from != s["built_from"]:
                self._close_tick()
                self._build()              # the world of the state's parameters
            set_world_state(self.tick, s["world"])
        self.state, self.start_time, self.ticks = s["state"], s["start_time"], s["ticks"]
        self.out = {(r, f): v for r, f, v in s["out"]}
        self.scans = {r: np.array(a, dtype=np.float64) for r, a in s["scans"].items()}
        self.odom = {r: None if o is None else (tuple(o[0]), np.array(o[1], dtype=np.float64))
                     for r, o in s["odom"].items()}
        touching = s["world"]["touching"] if s["world"] else None
        self.touching = None if touching is None else set(touching)
        self._serialized = None
