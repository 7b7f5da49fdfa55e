"""The DART plant as an FMI co-simulation instance: what the plant FMU's C shim runs.

``diffbot fmu export-plant`` (:mod:`fmus.plant_export`) writes an FMU whose binary
(fmus/plant_wrapper/*.c) embeds this package's Python interpreter: each FMI instance is a
:class:`PlantInstance`, which hosts the plant's tick (:class:`plant.tick.Tick`) in the
importer's process. Its variables (:func:`layout`) are fixed at export time; per robot:

- inputs ``<robot>.v`` (m/s) and ``<robot>.w`` (rad/s), held over the communication step
  and sent to the robot every control tick, as ``<robot>/cmd_vel`` is;
- outputs at the end of each step (the values the plant publishes at that tick): the true
  pose ``x, y, yaw``; ``odom_x, odom_y, odom_yaw``, the pose dead-reckoned from the
  encoder *readings* (``joint_states`` positions, noise included) from the start pose;
  ``wheel_angle_left/right`` (those readings, rad), ``wheel_speed_left/right`` (rad/s,
  exact, as published) and ``wheel_rate_left/right`` (a reading's increment over the last
  tick / tick: the odometry FMU's inputs, as the bus feeds them); ``contact`` (a robot
  solid touching anything but the floor at the tick's last physics step); ``scan`` (the
  last lidar scan's ranges, m: one Float64 array in FMI 3, ``scan[1]`` ... ``scan[n]`` in
  FMI 2), held between scans;
- parameters ``x0, y0, yaw0`` (start pose), and for the world ``world`` (file or shipped
  name), ``seed`` and ``noise`` (false: every sensor and motion noise of the world off).

Every method the C shim calls returns an FMI status (0 OK ... 3 error) and never raises;
the reason of a non-OK status is taken with :meth:`PlantInstance.pop_message`.
"""
from __future__ import annotations

import ctypes
import json
import math
import os
import traceback
from dataclasses import dataclass

import numpy as np

from .plant_state import FmuStates

OK, WARNING, DISCARD, ERROR, FATAL = 0, 1, 2, 3, 4
#: value references: a robot's variables start at ROBOT_VR * (its index + 1)
ROBOT_VR = 100_000
SCAN_OFFSET = 100
TICK_TOLERANCE_S = 1e-9


@dataclass(frozen=True)
class Var:
    name: str
    vr: int
    type: str                  # Float64 | Int32 | Boolean | String (FMI 3 names)
    causality: str             # independent | parameter | input | output
    variability: str
    description: str
    unit: str = ""
    start: object = None
    robot: str = ""
    field: str = ""
    size: int = 0              # FMI 3 array length (0: scalar)
    index: int = -1            # FMI 2: which ray of the robot's scan
    min: float | None = None   # declared range (the inputs: the world's drive limits)
    max: float | None = None


#: (field, unit, description) of a robot's Float64 outputs, in value-reference order
OUTPUTS = (
    ("x", "m", "true position x (world frame)"),
    ("y", "m", "true position y (world frame)"),
    ("yaw", "rad", "true heading, counter-clockwise, in (-pi, pi]"),
    ("odom_x", "m", "x dead-reckoned from the encoder readings (noise included) from x0"),
    ("odom_y", "m", "y dead-reckoned from the encoder readings from y0"),
    ("odom_yaw", "rad", "heading dead-reckoned from the encoder readings from yaw0, not wrapped"),
    ("wheel_angle_left", "rad", "left encoder reading (joint_states position, noise included)"),
    ("wheel_angle_right", "rad", "right encoder reading (joint_states position, noise included)"),
    ("wheel_speed_left", "rad/s", "left wheel speed (joint_states velocity)"),
    ("wheel_speed_right", "rad/s", "right wheel speed (joint_states velocity)"),
    ("wheel_rate_left", "rad/s", "left encoder reading's increment over the last tick / tick "
     "(what the odometry FMU takes as omega_left on the bus)"),
    ("wheel_rate_right", "rad/s", "right encoder reading's increment over the last tick / tick"),
)


def layout(robots: list, fmi: int, world: str, seed: int = 0,
           scan_scalars: bool = False) -> list[Var]:
    """The FMU's variables: ``robots`` is [(name, lidar rays or 0, start pose[, (max linear
    m/s, max angular rad/s)])]; ``scan_scalars``: the scan as ``scan[1]`` ... ``scan[n]`` in
    FMI 3 too (for masters that take no arrays), as it always is in FMI 2."""
    # FMI 3 needs its one independent variable; FMI 2 none (FMI Library then asks for a start)
    out = [Var("time", 0, "Float64", "independent", "continuous", "simulation time", "s")
           ] if fmi == 3 else []
    out += [Var("world", 1, "String", "parameter", "fixed",
                "world file or shipped world name (its robots and lidars must be the exported ones)",
                start=world),
            Var("seed", 2, "Int32", "parameter", "fixed", "seed of every noise stream", start=seed),
            Var("noise", 3, "Boolean", "parameter", "fixed",
                "false: every sensor and motion noise of the world is off", start=True)]
    for i, (name, rays, pose, *limits) in enumerate(robots):
        base = ROBOT_VR * (i + 1)
        r = dict(robot=name)
        v_max, w_max = limits[0] if limits else (None, None)
        out += [Var(f"{name}.v", base, "Float64", "input", "continuous",
                    "commanded linear velocity (the drive limits it to its range)", "m/s", 0.0,
                    field="v", min=None if v_max is None else -v_max, max=v_max, **r),
                Var(f"{name}.w", base + 1, "Float64", "input", "continuous",
                    "commanded angular velocity, counter-clockwise (the drive limits it to its "
                    "range)", "rad/s", 0.0, field="w", min=None if w_max is None else -w_max,
                    max=w_max, **r)]
        for j, (field, label) in enumerate((("x0", "start x"), ("y0", "start y"),
                                            ("yaw0", "start heading"))):
            out.append(Var(f"{name}.{field}", base + 2 + j, "Float64", "parameter", "fixed",
                           label, "rad" if field == "yaw0" else "m", float(pose[j]),
                           field=field, **r))
        for j, (field, unit, label) in enumerate(OUTPUTS):
            out.append(Var(f"{name}.{field}", base + 5 + j, "Float64", "output", "continuous",
                           label, unit, field=field, **r))
        out.append(Var(f"{name}.contact", base + 5 + len(OUTPUTS), "Boolean", "output",
                       "discrete", "a robot solid touches anything but the floor",
                       field="contact", **r))
        if rays:
            out.append(Var(f"{name}.scan_count", base + 6 + len(OUTPUTS), "Int32", "output",
                           "discrete", "lidar scans taken so far: changes when a new scan "
                           "arrives", field="scan_count", **r))
        if rays and fmi == 3 and not scan_scalars:
            out.append(Var(f"{name}.scan", base + SCAN_OFFSET, "Float64", "output", "discrete",
                           "last lidar scan's ranges (held between scans)", "m", field="scan",
                           size=rays, **r))
        elif rays:
            out += [Var(f"{name}.scan[{k + 1}]", base + SCAN_OFFSET + k, "Float64", "output",
                        "discrete", f"last lidar scan's range of ray {k + 1}", "m", field="scan",
                        index=k, **r) for k in range(rays)]
    return out


_CTYPES = {"Float64": ctypes.c_double, "Int32": ctypes.c_int32}


def _boolean_ctype(fmi: int):
    return ctypes.c_bool if fmi == 3 else ctypes.c_int


def _wanted(topic: str) -> bool:
    return topic in ("joint_states", "scan")


class PlantInstance(FmuStates):
    """One FMI instance of the plant (states: instantiated, init, step, terminated)."""

    def __init__(self, fmi: int, resources: str, name: str, token: str) -> None:
        with open(os.path.join(resources, "plant.json"), encoding="utf-8") as f:
            self.cfg = json.load(f)
        if token != self.cfg["token"]:
            raise ValueError(f"instantiation token {token!r} is not this FMU's "
                             f"({self.cfg['token']!r})")
        self.fmi, self.name = fmi, name
        robots = self.cfg["robots"]
        self.robots = [row[0] for row in robots]
        self.vars = layout(robots, fmi, self.cfg["world"], self.cfg["seed"],
                           self.cfg.get("scan_scalars", False))
        self.by_vr = {v.vr: v for v in self.vars}
        self.by_name = {v.name: v.vr for v in self.vars}
        self.messages: list[str] = []
        self.tick = None
        self.touching = None
        self.states: dict[int, dict] = {}    # FMU states taken (getFMUState), by id >= 1
        self._last_state = 0
        self._serialized: tuple[int, bytes] | None = None
        self._start_values()

    # -------------------------------------------------------------- FMI calls
    def _start_values(self) -> None:
        self.values = {v.vr: v.start for v in self.vars if v.start is not None}
        self.out: dict[tuple[str, str], object] = {}
        self.scans = {}
        self.state = "instantiated"
        self.start_time = 0.0
        self.ticks = 0
        self._close_tick()

    def _close_tick(self) -> None:
        if self.tick is not None:
            self.tick.close()
            self.tick = None               # (freed at once: no cycle holds it, a test checks)

    def _guard(self, f, *args) -> int:
        try:
            return f(*args)
        except Exception as exc:          # noqa: BLE001 - every error becomes an FMI status
            self.messages.append(f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}")
            return ERROR

    def fail(self, message: str, status: int = ERROR) -> int:
        self.messages.append(message)
        return status

    def pop_message(self) -> str:
        out = "\n".join(self.messages)
        self.messages.clear()
        return out

    def enter_init(self, start_time: float) -> int:
        self.start_time = float(start_time)
        self.state = "init"
        return OK

    def exit_init(self) -> int:
        return self._guard(self._exit_init)

    def _exit_init(self) -> int:
        if self.tick is None:
            self._build()
        self.state = "step"
        return OK

    def do_step(self, t: float, h: float) -> int:
        return self._guard(self._do_step, t, h)

    def reset(self) -> int:
        return self._guard(self._start_values) or OK

    def terminate(self) -> int:
        return self._guard(self._terminate) or OK

    def _terminate(self) -> None:
        """Drop the world, keeping the last outputs (getters are allowed when terminated)."""
        if self.tick is not None and self.touching is None:
            self.touching = contacts(self.tick.sim.world, self.robots)
        self.state = "terminated"
        self._close_tick()

    def free(self) -> int:
        return self._guard(self._close_tick) or OK

    def get(self, kind: str, vr_addr: int, nvr: int, val_addr: int, nval: int) -> int:
        return self._guard(self._get, kind, vr_addr, nvr, val_addr, nval)

    def set(self, kind: str, vr_addr: int, nvr: int, val_addr: int, nval: int) -> int:
        return self._guard(self._set, kind, vr_addr, nvr, val_addr, nval)

    def get_string(self, vr: int) -> str:
        v = self.by_vr.get(vr)
        return str(self.values.get(vr, "")) if v is not None and v.type == "String" else ""

    def set_string(self, vr: int, value: bytes) -> int:
        v = self.by_vr.get(vr)
        if v is None or v.type != "String":
            return self.fail(f"value reference {vr} is not a String variable")
        return self._store(v, value.decode("utf-8"))

    def contacts_now(self) -> set[str]:
        return contacts(self.tick.sim.world, self.robots)

    # -------------------------------------------------------------- values
    def _var(self, vr: int, kind: str) -> Var:
        v = self.by_vr.get(vr)
        if v is None:
            raise ValueError(f"unknown value reference {vr}")
        if v.type != kind:
            raise ValueError(f"{v.name} (value reference {vr}) is a {v.type}, not a {kind}")
        return v

    def _ctype(self, kind: str):
        return _boolean_ctype(self.fmi) if kind == "Boolean" else _CTYPES[kind]

    def _get(self, kind: str, vr_addr: int, nvr: int, val_addr: int, nval: int) -> int:
        vrs = (ctypes.c_uint32 * nvr).from_address(vr_addr)
        values: list = []
        for vr in vrs:
            values.extend(self._value(self._var(vr, kind)))
        if len(values) != nval:
            return self.fail(f"get{kind}: {nval} values asked for, the variables hold {len(values)}")
        if nval:
            (self._ctype(kind) * nval).from_address(val_addr)[:] = values
        return OK

    def _value(self, v: Var) -> list:
        if v.causality in ("parameter", "input"):
            return [self.values[v.vr]]
        if v.causality == "independent":
            return [self.time]
        if self.tick is None and self.state != "terminated":
            if self.state != "init":
                raise ValueError(f"{v.name} has no value before initialization")
            self._build()                  # outputs asked for in initialization mode
        if not self.out:
            raise ValueError(f"{v.name} has no value: the FMU was never initialized")
        if v.field == "contact":
            if self.touching is None:
                self.touching = contacts(self.tick.sim.world, self.robots)
            return [v.robot in self.touching]
        if v.field == "scan":
            scan = self.scans[v.robot]
            return [float(r) for r in scan] if v.size else [float(scan[v.index])]
        return [self.out[(v.robot, v.field)]]

    def _set(self, kind: str, vr_addr: int, nvr: int, val_addr: int, nval: int) -> int:
        if nval != nvr:
            return self.fail(f"set{kind}: {nval} values for {nvr} scalar variables")
        vrs = (ctypes.c_uint32 * nvr).from_address(vr_addr)
        vals = (self._ctype(kind) * nval).from_address(val_addr) if nval else []
        status = OK
        for vr, value in zip(vrs, vals):
            status = max(status, self._store(self._var(vr, kind), value))
        return status

    def _store(self, v: Var, value) -> int:
        if v.causality not in ("parameter", "input"):
            return self.fail(f"{v.name} is an {v.causality}: it cannot be set")
        if v.causality == "parameter" and self.state not in ("instantiated", "init"):
            return self.fail(f"{v.name} is a fixed parameter: set it before initialization ends")
        if v.type == "Float64" and not math.isfinite(value):
            return self.fail(f"{v.name} = {value}: not a finite number")
        self.values[v.vr] = bool(value) if v.type == "Boolean" else value
        if v.max is not None and not v.min <= value <= v.max:
            return self.fail(f"{v.name} = {value!r} is outside its range [{v.min:g}, {v.max:g}]:"
                             " the drive limits it", WARNING)
        if v.causality == "parameter":
            self._close_tick()             # built from older parameters in init mode
            self.out.clear()
            self.scans.clear()
        return OK

    # -------------------------------------------------------------- the world
    def param(self, name: str):
        return self.values[self.by_name[name]]

    @property
    def time(self) -> float:
        return self.start_time + self.ticks * self.cfg["tick_s"]

    def _build(self) -> None:
        """The world from the parameters, and its outputs at the start time."""
        from plant.tick import Tick
        from plant.world import load_world
        spec = load_world(self.param("world"), self.cfg.get("overrides", []))
        names = [r.name for r in spec.robots]
        for name, rays, *_ in self.cfg["robots"]:
            if name not in names:
                raise ValueError(f"world {self.param('world')!r} has no robot {name!r} "
                                 f"(it has {', '.join(names)}): export the FMU from that world")
            lidar = spec.robot(name).sensors.lidar
            if (lidar.num_rays if lidar else 0) != rays:
                raise ValueError(f"{name}'s lidar in {self.param('world')!r} has "
                                 f"{lidar.num_rays if lidar else 0} rays; the FMU has {rays}")
        spec.seed = int(self.param("seed"))
        if not self.param("noise"):
            silence(spec)
        for name in self.robots:
            spec.robot(name).pose = tuple(float(self.param(f"{name}.{k}"))
                                          for k in ("x0", "y0", "yaw0"))
        if abs(spec.control_tick_s - self.cfg["tick_s"]) > TICK_TOLERANCE_S:
            raise ValueError(f"the world's control tick is {spec.control_tick_s} s, the FMU's "
                             f"{self.cfg['tick_s']} s")
        self.tick = Tick(spec, disabled=("camera",))
        self._built_from = self._params()
        self.ticks = 0
        self.odom = {name: None for name in self.robots}
        self._sense()

    def _sense(self) -> None:
        """Take tick k's sensors (every robot's noise drawn, as the plant does)."""
        readings = {}
        for robot, topic, msg in self.tick.messages({n: _wanted for n in self.tick.sensors}):
            if robot not in self.odom or msg is None:
                continue
            if topic == "joint_states":
                readings[robot] = (np.asarray(msg.position, dtype=float),
                                   np.asarray(msg.velocity, dtype=float))
            elif topic == "scan":
                self.scans[robot] = np.asarray(msg.ranges, dtype=np.float64)
                self.out[(robot, "scan_count")] = self.out.get((robot, "scan_count"), 0) + 1
        self.touching = None               # found when asked for (get of a contact flag)
        for robot in self.robots:
            tf = self.tick.sim.robots[robot].transform()
            pos, vel = readings[robot]
            prev = self.odom[robot]
            rate = (pos - prev[1]) / self.cfg["tick_s"] if prev is not None else np.zeros(2)
            o = self._odometry(robot, pos)
            yaw = float(np.arctan2(tf[1, 0], tf[0, 0]))     # as plant.sim.Simulation.state
            fields = (float(tf[0, 3]), float(tf[1, 3]), yaw, *o, float(pos[0]), float(pos[1]),
                      float(vel[0]), float(vel[1]),
                      float(rate[0]), float(rate[1]))
            for (field, _, _), value in zip(OUTPUTS, fields):
                self.out[(robot, field)] = value
            if robot not in self.scans and self.tick.sensors[robot].lidar is not None:
                self.scans[robot] = np.zeros(self.tick.sensors[robot].lidar.num_rays)

    def _odometry(self, robot: str, pos: np.ndarray) -> tuple[float, float, float]:
        """Dead reckoning from the encoder readings: the arc between two readings."""
        prev = self.odom[robot]
        if prev is None:
            pose = tuple(float(self.param(f"{robot}.{k}")) for k in ("x0", "y0", "yaw0"))
        else:
            drive = self.tick.spec.robot(robot).drive
            dl, dr = (pos - prev[1]) * drive.wheel_radius_m
            ds, dth = (dl + dr) / 2, (dr - dl) / drive.wheel_separation_m
            x, y, th = prev[0]
            pose = (x + ds * math.cos(th + dth / 2), y + ds * math.sin(th + dth / 2), th + dth)
        self.odom[robot] = (pose, pos.copy())
        return pose

    def _do_step(self, t: float, h: float) -> int:
        from bus.controller import Twist
        if self.state != "step":
            return self.fail(f"doStep in state {self.state}: initialize the FMU first")
        tick_s = self.cfg["tick_s"]
        n = round(h / tick_s)
        if n < 1 or abs(n * tick_s - h) > TICK_TOLERANCE_S * max(1.0, n):
            return self.fail(f"communication step {h!r} s is not a whole number of "
                             f"{tick_s * 1e3:g} ms control ticks: the plant steps whole ticks")
        if abs(t - self.time) > 1e-6:
            return self.fail(f"doStep from t = {t!r} s, but the plant is at t = {self.time!r} s")
        for _ in range(n):
            for name in self.robots:
                self.tick.drive(name, Twist(float(self.param(f"{name}.v")),
                                            float(self.param(f"{name}.w"))))
            finite = self.tick.step()
            if not finite:
                self.state = "terminated"
                return self.fail(f"the physics diverged at t = {self.time:.3f} s",
                                 ERROR)
            self.ticks += 1
            self._sense()
        return OK


def silence(spec) -> None:
    """Every sensor and motion noise of the world's robots off."""
    from plant.noise import NoiseConfig
    for r in spec.robots:
        s = r.sensors
        s.lidar_noise = s.camera_noise = s.encoder_noise = s.gps_noise = NoiseConfig()
        s.command_noise_std_radps = 0.0


def contacts(world, robots: list[str]) -> set[str]:
    """The robots with a solid touching anything but the floor (DART's last collision
    result: the tick's last physics step)."""
    out = set()
    result = world.getLastCollisionResult()
    for i in range(result.getNumContacts()):
        c = result.getContact(i)
        a = c.collisionObject1.getShapeFrame().getName()
        b = c.collisionObject2.getShapeFrame().getName()
        for robot in robots:
            mine = f"{robot}_"
            if a.startswith(mine) != b.startswith(mine):
                other = b if a.startswith(mine) else a
                if other not in ("floor", "floor_plane"):
                    out.add(robot)
    return out


def instantiate(fmi: int, resources: str, name: str, token: str) -> PlantInstance:
    """What the C shim calls for fmi2Instantiate / fmi3InstantiateCoSimulation."""
    return PlantInstance(int(fmi), resources, name, token)


__all__ = ["PlantInstance", "Var", "layout", "instantiate", "silence", "contacts"]
