"""World files: load and validate a TOML world description.

A world file names the physics settings, the floor and walls, the furniture
(boxes, cylinders and spheres with colours and materials), friction per
material, and the robots with their start poses and drive limits. Every error
is reported as ``file:key: reason`` (:class:`WorldError`), so the command line
can print one line and exit 2.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field


from bus.cliargs import did_you_mean
from bus.keys import BadName, check_name

from .camera import CameraConfig
from .lidar import LidarConfig
from .noise import NoiseConfig, parse_noise
from .tomlfile import Table, WorldError, read_toml, shipped_or_path, tomllib

WORLDS_DIR = os.path.join(os.path.dirname(__file__), "worlds")
#: bounds of [world] control_tick_s and of the DART steps in one: beyond them a world file
#: would make one tick take hours (the fuzz test met control_tick_s = 3.5e16 s, which hung)
MAX_CONTROL_TICK_S = 1.0
MAX_STEPS_PER_TICK = 1000


# ---------------------------------------------------------------------------- spec
@dataclass
class Material:
    name: str
    friction: float


@dataclass
class ObjectSpec:
    name: str
    shape: str                  # box | cylinder | sphere
    size: tuple[float, ...]     # box: lx, ly, lz; cylinder: radius, height; sphere: radius
    pose: tuple[float, float, float, float]  # x, y, z (centre), yaw
    color: tuple[float, float, float]
    material: str
    static: bool = True
    mass_kg: float = 1.0


@dataclass
class DriveSpec:
    wheel_radius_m: float = 0.12
    wheel_separation_m: float = 0.36
    max_wheel_speed_radps: float = 12.0
    max_wheel_accel_radps2: float = 40.0
    max_linear_mps: float = 1.0
    max_angular_radps: float = 3.0
    max_linear_accel_mps2: float = 2.0
    max_angular_accel_radps2: float = 8.0
    max_wheel_torque_nm: float = 5.0
    cmd_timeout_s: float = 0.5


@dataclass
class SensorsSpec:
    """A robot's sensors and noise. Lidar and camera exist only if their table is given."""
    lidar: LidarConfig | None = None
    lidar_noise: NoiseConfig = field(default_factory=NoiseConfig)
    camera: CameraConfig | None = None
    camera_noise: NoiseConfig = field(default_factory=NoiseConfig)
    encoder_noise: NoiseConfig = field(default_factory=NoiseConfig)
    gps_noise: NoiseConfig = field(default_factory=NoiseConfig)
    #: motion noise: Gaussian standard deviation added to each commanded wheel speed, rad/s
    command_noise_std_radps: float = 0.0


@dataclass
class RobotSpec:
    name: str
    pose: tuple[float, float, float]        # x, y, yaw
    color: tuple[float, float, float] = (0.15, 0.35, 0.8)
    wheel_material: str = "rubber"
    drive: DriveSpec = field(default_factory=DriveSpec)
    chassis_mass_kg: float = 6.0
    wheel_mass_kg: float = 0.5
    # extra parts carried by the robot (e.g. the leader's green ball), poses relative to base
    parts: list[ObjectSpec] = field(default_factory=list)
    sensors: SensorsSpec = field(default_factory=SensorsSpec)


@dataclass
class WorldSpec:
    path: str
    name: str
    mode: str = "dynamic"                   # dynamic | kinematic
    physics_step_s: float = 0.001
    control_tick_s: float = 0.02
    gravity_mps2: float = 9.81
    collision_detector: str = "bullet"      # bullet | fcl | dart | ode
    contact_solver: str = "pgs"             # pgs (Coulomb limit exact) | dantzig
    seed: int = 0
    floor_size_m: tuple[float, float] = (10.0, 10.0)
    floor_color: tuple[float, float, float] = (0.78, 0.72, 0.62)
    floor_material: str = "floor"
    wall_height_m: float = 0.0              # 0 = no walls
    wall_thickness_m: float = 0.1
    wall_color: tuple[float, float, float] = (0.9, 0.9, 0.85)
    materials: dict[str, Material] = field(default_factory=dict)
    objects: list[ObjectSpec] = field(default_factory=list)
    robots: list[RobotSpec] = field(default_factory=list)

    @property
    def substeps(self) -> int:
        return int(round(self.control_tick_s / self.physics_step_s))

    @property
    def tick_ns(self) -> int:
        """The control tick in ns (every stamp is a multiple of it)."""
        return int(round(self.control_tick_s * 1e9))

    def robot(self, name: str) -> RobotSpec:
        for r in self.robots:
            if r.name == name:
                return r
        raise KeyError(name)


# ---------------------------------------------------------------------------- parse
def _parse_object(t: Table, materials: dict, default_material: str) -> ObjectSpec:
    name = t.string("name")
    shape = t.string("shape", choices=("box", "cylinder", "sphere"))
    if shape == "box":
        size = t.vector("size_m", 3, positive=True)
        height = size[2]
    elif shape == "cylinder":
        size = (t.number("radius_m", positive=True, required=True),
                t.number("height_m", positive=True, required=True))
        height = size[1]
    else:
        size = (t.number("radius_m", positive=True, required=True),)
        height = 2 * size[0]
    pose = t.vector("pose", (2, 3, 4), (0.0, 0.0))
    # [x, y], [x, y, yaw] or [x, y, z, yaw]; z defaults to resting on the floor
    if len(pose) == 2:
        x, y, z, yaw = pose[0], pose[1], height / 2, 0.0
    elif len(pose) == 3:
        x, y, z, yaw = pose[0], pose[1], height / 2, pose[2]
    else:
        x, y, z, yaw = pose
    color = t.vector("color", 3, (0.6, 0.6, 0.6), unit_range=True)
    material = t.string("material", default_material)
    if material not in materials:
        t.fail("material", f"unknown material {material!r} (defined: {', '.join(materials)})")
    static = t.boolean("static", True)
    mass = t.number("mass_kg", 1.0, positive=True)
    t.done()
    return ObjectSpec(name, shape, size, (x, y, z, yaw), color, material, static, mass)


def _config_from_table(t: Table, cls, skip=()) -> object:
    """A frozen sensor config dataclass from the same-named keys of a table."""
    kw = {}
    t.used.update(cls.__dataclass_fields__)      # all known keys (for typo suggestions)
    for name, f in cls.__dataclass_fields__.items():
        if name in skip or not t.has(name):
            continue
        if f.type in ("int", int):
            kw[name] = t.integer(name, f.default)
        else:
            kw[name] = t.number(name, f.default)
    try:
        return cls(**kw)
    except ValueError as exc:
        t.fail("", str(exc))


def _noise(t: Table, sensor: str, max_range: float | None = None) -> NoiseConfig:
    raw = t.raw("noise")
    if raw is None:
        return NoiseConfig()
    try:
        return parse_noise(raw, sensor, max_range=max_range, where=f"{t.path}:{t.key('noise')}")
    except ValueError as exc:
        raise WorldError(str(exc)) from None


def _parse_sensors(robot: Table) -> SensorsSpec:
    s = SensorsSpec()
    if robot.has("lidar"):
        t = robot.table("lidar")
        lidar = _config_from_table(t, LidarConfig)      # checked even when disabled
        if t.boolean("enabled", True):
            s.lidar = lidar
            s.lidar_noise = _noise(t, "lidar", lidar.max_range_m)
        t.raw("noise")
        t.done()
    if robot.has("camera"):
        t = robot.table("camera")
        camera = _config_from_table(t, CameraConfig)
        if t.boolean("enabled", True):
            s.camera = camera
            s.camera_noise = _noise(t, "camera")
        t.raw("noise")
        t.done()
    for key, sensor, attr in (("encoders", "position", "encoder_noise"),
                              ("gps", "gps", "gps_noise")):
        if robot.has(key):
            t = robot.table(key)
            setattr(s, attr, _noise(t, sensor))
            t.done()
    if robot.has("motion"):
        t = robot.table("motion")
        s.command_noise_std_radps = t.number("command_noise_std_radps", 0.0, nonneg=True)
        t.done()
    return s


def _parse_drive(t: Table) -> DriveSpec:
    d = DriveSpec()
    for f in DriveSpec.__dataclass_fields__:
        setattr(d, f, t.number(f, getattr(d, f), positive=True))
    t.done()
    return d


def parse_world(data: dict, path: str) -> WorldSpec:
    top = Table(path, "", data)
    w = top.table("world")
    spec = WorldSpec(path=path, name=w.string("name", os.path.splitext(os.path.basename(path))[0]))
    _parse_world_table(w, spec)

    mats = top.table("materials")
    spec.materials = {"floor": Material("floor", 1.0), "rubber": Material("rubber", 1.0),
                      "default": Material("default", 0.6)}
    for name in list(mats.data):
        m = mats.table(name)
        spec.materials[name] = Material(name, m.number("friction", nonneg=True, required=True))
        m.done()
    mats.done()

    fl = top.table("floor")
    spec.floor_size_m = fl.vector("size_m", 2, (10.0, 10.0), positive=True)
    spec.floor_color = fl.vector("color", 3, spec.floor_color, unit_range=True)
    spec.floor_material = fl.string("material", "floor")
    if spec.floor_material not in spec.materials:
        fl.fail("material", f"unknown material {spec.floor_material!r}")
    fl.done()

    wl = top.table("walls")
    spec.wall_height_m = wl.number("height_m", 0.0, nonneg=True)
    spec.wall_thickness_m = wl.number("thickness_m", 0.1, positive=True)
    spec.wall_color = wl.vector("color", 3, spec.wall_color, unit_range=True)
    wl.done()

    names: set[str] = set()
    for t in top.tables("objects"):
        obj = _parse_object(t, spec.materials, "default")
        if obj.name in names:
            t.fail("name", f"duplicate name {obj.name!r}")
        names.add(obj.name)
        spec.objects.append(obj)

    for t in top.tables("robots"):
        name = t.string("name")
        try:
            check_name(name, "robot name")
        except BadName as exc:
            t.fail("name", str(exc))
        if any(r.name == name for r in spec.robots):
            t.fail("name", f"duplicate robot {name!r}")
        pose = t.vector("pose", 3, (0.0, 0.0, 0.0))
        r = RobotSpec(name=name, pose=pose)
        r.color = t.vector("color", 3, r.color, unit_range=True)
        r.wheel_material = t.string("wheel_material", "rubber")
        if r.wheel_material not in spec.materials:
            t.fail("wheel_material", f"unknown material {r.wheel_material!r}")
        r.chassis_mass_kg = t.number("chassis_mass_kg", r.chassis_mass_kg, positive=True)
        r.wheel_mass_kg = t.number("wheel_mass_kg", r.wheel_mass_kg, positive=True)
        r.drive = _parse_drive(t.table("drive"))
        r.sensors = _parse_sensors(t)
        for pt in t.tables("parts"):
            r.parts.append(_parse_object(pt, spec.materials, "default"))
        t.done()
        spec.robots.append(r)
    _check_robot_overlap(spec, top)
    top.done()
    return spec


def _parse_world_table(w: Table, spec: WorldSpec) -> None:
    """The ``[world]`` table into ``spec``: mode, steps, gravity, solvers, seed."""
    spec.mode = w.string("mode", "dynamic", choices=("dynamic", "kinematic"))
    spec.physics_step_s = w.number("physics_step_s", 0.001, positive=True)
    spec.control_tick_s = w.number("control_tick_s", 0.02, positive=True)
    if spec.control_tick_s > MAX_CONTROL_TICK_S:
        w.fail("control_tick_s", f"{spec.control_tick_s:g} s is longer than a control tick can "
                                 f"be (at most {MAX_CONTROL_TICK_S:g} s)")
    ratio = spec.control_tick_s / spec.physics_step_s
    if not math.isfinite(ratio) or abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        w.fail("control_tick_s", f"must be a whole multiple of physics_step_s "
                                 f"({spec.physics_step_s:g} s), got {spec.control_tick_s:g} s")
    if round(ratio) > MAX_STEPS_PER_TICK:
        w.fail("physics_step_s", f"{spec.physics_step_s:g} s makes {round(ratio)} physics "
                                 f"steps a control tick (at most {MAX_STEPS_PER_TICK})")
    if spec.physics_step_s > 0.01:
        w.fail("physics_step_s", f"{spec.physics_step_s:g} s is too coarse for contact "
                                 "(use at most 0.01 s)")
    spec.gravity_mps2 = w.number("gravity_mps2", 9.81, nonneg=True)
    spec.collision_detector = w.string("collision_detector", "bullet",
                                       choices=("bullet", "fcl", "dart", "ode"))
    spec.contact_solver = w.string("contact_solver", "pgs", choices=("pgs", "dantzig"))
    spec.seed = w.integer("seed", 0)
    w.done()


ROBOT_RADIUS_M = 0.30  # conservative footprint radius of the default robot


def _check_robot_overlap(spec: WorldSpec, top: Table) -> None:
    for i, a in enumerate(spec.robots):
        for b in spec.robots[i + 1:]:
            d = math.hypot(a.pose[0] - b.pose[0], a.pose[1] - b.pose[1])
            if d < 2 * ROBOT_RADIUS_M:
                raise WorldError(f"{top.path}:robots: robots {a.name!r} and {b.name!r} overlap "
                                 f"(start {d:.2f} m apart, need {2 * ROBOT_RADIUS_M:.2f} m)")


def resolve_world_path(name_or_path: str) -> str:
    """A path as given, or the name of a shipped world (``living_room``, ``empty``)."""
    return shipped_or_path(name_or_path, WORLDS_DIR, "world file", "shipped worlds")


def load_world(name_or_path: str, overrides: list[str] | tuple[str, ...] = ()) -> WorldSpec:
    """Load and validate a world file, after applying ``KEY=VALUE`` overrides (see
    :func:`apply_override`)."""
    path = resolve_world_path(name_or_path)
    data = read_toml(path)
    data = _extend(data, path, seen=(os.path.abspath(path),))
    touched = [(item, apply_override(data, item, path)) for item in overrides]
    try:
        return parse_world(data, path)
    except WorldError as exc:
        raise _blame_override(exc, path, touched) from None


def _blame_override(exc: WorldError, path: str, touched: list[tuple[str, str]]) -> WorldError:
    """A value that came from ``--set KEY=VALUE`` is the option's fault, not the file's:
    ``--set world.physics_stepp_s=0.002: world.physics_stepp_s: unknown key ...``."""
    msg = str(exc)
    if not msg.startswith(f"{path}:"):
        return exc
    where, _, reason = msg[len(path) + 1:].partition(": ")
    for item, keypath in touched:
        if where == keypath or where.startswith((keypath + ".", keypath + "[")):
            return WorldError(f"--set {_shown(item)}: {where}: {reason}")
    return exc


def _extend(data: dict, path: str, seen: tuple[str, ...]) -> dict:
    """``[world] extends = "living_room"``: start from another world file (a shipped name or
    a path relative to this file). This file's tables override the base's key by key;
    its ``objects`` are added to the base's; its ``robots``, if any, replace the base's."""
    world = data.get("world")
    base_name = world.get("extends") if isinstance(world, dict) else None
    if base_name is None:
        return data
    if not isinstance(base_name, str):
        raise WorldError(f"{path}:world.extends: expected a world name or path")
    rel = os.path.join(os.path.dirname(path), base_name)
    try:
        base_path = resolve_world_path(rel if os.path.exists(rel) else base_name)
    except WorldError as exc:
        raise WorldError(f"{path}:world.extends: {exc}") from None
    if os.path.abspath(base_path) in seen:
        raise WorldError(f"{path}:world.extends: {base_name!r} extends itself")
    try:
        with open(base_path, "rb") as f:
            base = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise WorldError(f"{path}:world.extends: cannot load {base_path}: {exc}") from None
    base = _extend(base, base_path, seen + (os.path.abspath(base_path),))
    out = dict(base)
    for key, value in data.items():
        if key == "objects":
            if not isinstance(value, list):
                raise WorldError(f"{path}:objects: expected an array of tables ([[objects]]), "
                                 f"got {type(value).__name__}")
            out["objects"] = list(base.get("objects", [])) + value
        elif key == "robots":
            out["robots"] = value
        elif isinstance(value, dict) and isinstance(base.get(key), dict):
            out[key] = {**base[key], **value}
        else:
            out[key] = value
    out["world"] = {k: v for k, v in out["world"].items() if k != "extends"}
    return out


def _shown(item: str) -> str:
    """An override as the user typed it, quoted if it holds newlines or other controls."""
    return item if item.isprintable() else repr(item)


def apply_override(data: dict, item: str, path: str = "<world>") -> str:
    """Set one value of a parsed world file from ``dotted.key=TOML value``.

    Robots are addressed by name: ``robots.robot1.encoders.noise={webots_noise = 0.2}``,
    ``world.mode="kinematic"``, ``materials.floor.friction=0.4``. Missing tables are
    created; the result is validated like the file itself. Returns the key's path as the
    validator names it (``robots[0].encoders.noise``), to blame errors on the option.
    """
    key, sep, value = item.partition("=")
    parts = [p for p in key.strip().split(".") if p]
    if not sep or not parts:
        raise WorldError(f"--set {_shown(item)}: expected KEY=VALUE")
    try:
        val = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        val = value.strip()               # a bare word is a string
    node = data
    where: list[str] = []
    i = 0
    while i < len(parts) - 1:
        p = parts[i]
        if p == "robots" and isinstance(node.get("robots"), list):
            name = parts[i + 1]
            match = [j for j, r in enumerate(node["robots"])
                     if isinstance(r, dict) and r.get("name") == name]
            if not match:
                names = [r.get("name") for r in node["robots"] if isinstance(r, dict)]
                raise WorldError(f"--set {_shown(item)}: no robot named {name!r}"
                                 f"{did_you_mean(name, [n for n in names if isinstance(n, str)])}"
                                 f" in {path}")
            node = node["robots"][match[0]]
            where.append(f"robots[{match[0]}]")
            i += 2
            continue
        nxt = node.setdefault(p, {})
        if not isinstance(nxt, dict):
            raise WorldError(f"--set {_shown(item)}: {'.'.join(parts[:i + 1])} is not a table "
                             f"in {path}")
        node = nxt
        where.append(p)
        i += 1
    node[parts[-1]] = val
    where.append(parts[-1])
    return ".".join(where).replace(".[", "[")
