"""The physics world: builds DART from a :class:`~plant.world.WorldSpec` and steps it.

No bus here: :mod:`plant.process` drives a :class:`Simulation` and publishes what it reads.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import dartpy as dart
import numpy as np

from .core.drive import WorldDrive
from .dart_rows import STATE_COLS, chassis_rows, fill_velocities, finite as _finite, read_rows
from .kinematic import Kinematics
from .robot import Robot, movable_object, room_skeleton
from .shapes import Shape, pose_matrix
from .noise import NoiseConfig, NoiseModel, stream_key
from .raycast import Scene, ShapeList
from .world import ObjectSpec, WorldSpec

FLOOR_THICKNESS_M = 0.1
__all__ = ["STATE_COLS", "chassis_rows", "RobotState", "Simulation", "rotation_to_quaternion"]

#: Bullet is ~15 % faster per step than DART's default FCL here, with the same contact
#: results for the sphere wheels (docs/sensors.md, "Friction and contacts"; docs/benchmarks.md).
DETECTORS = {
    "bullet": dart.collision.BulletCollisionDetector,
    "fcl": dart.collision.FCLCollisionDetector,
    "dart": dart.collision.DARTCollisionDetector,
    "ode": dart.collision.OdeCollisionDetector,
}


def _dofs(index: list[int]) -> slice | list[int]:
    """Indices into a skeleton's vectors, as a slice where they follow one another (a
    slice of an array is a view: cheaper than picking the values by a list)."""
    if index == list(range(index[0], index[0] + len(index))):
        return slice(index[0], index[0] + len(index))
    return index


@dataclass
class RobotState:
    """What the plant knows about one robot after a tick (true values, no noise)."""
    tf: np.ndarray            # base_link -> world, 4x4
    yaw: float                # rad
    v_body: np.ndarray        # m/s in base_link
    w_body: np.ndarray        # rad/s in base_link
    enc_pos: np.ndarray       # left, right wheel angle, rad
    enc_vel: np.ndarray       # left, right wheel speed, rad/s

    @property
    def xyz(self) -> np.ndarray:
        return self.tf[:3, 3]

    @property
    def quaternion(self) -> tuple[float, float, float, float]:
        """(x, y, z, w) of the base_link orientation."""
        return rotation_to_quaternion(self.tf[:3, :3])


def rotation_to_quaternion(m: np.ndarray) -> tuple[float, float, float, float]:
    # Python floats: the same IEEE double arithmetic (and correctly rounded sqrt) as numpy's
    # scalars, several times cheaper a call (the swarm's plant makes 24 a tick)
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(m)[:3, :3].tolist()
    tr = m00 + m11 + m22
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        return ((m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, 0.25 * s)
    i = int(np.argmax([m[0, 0], m[1, 1], m[2, 2]]))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k]) * 2
    q = [0.0, 0.0, 0.0, 0.0]
    q[i] = 0.25 * s
    q[j] = (m[j, i] + m[i, j]) / s
    q[k] = (m[k, i] + m[i, k]) / s
    q[3] = (m[k, j] - m[j, k]) / s
    return tuple(q)  # type: ignore[return-value]


def _visible_parts(robot: Robot, owner: str) -> list[tuple]:
    """(shape node, kind, size, colour, name, owner) of what a sensor sees of a robot:
    its visual shapes (the wheels' collision spheres are left out)."""
    out = []
    for body in robot.skeleton.getBodyNodes():
        for i in range(body.getNumShapeNodes()):
            sn = body.getShapeNode(i)
            shape = sn.getShape()
            kind = {"BoxShape": "box", "CylinderShape": "cylinder",
                    "SphereShape": "sphere"}.get(type(shape).__name__)
            if kind is None or (kind == "sphere" and sn.getName().endswith("_wheel")):
                continue
            if kind == "box":
                size = tuple(float(v) for v in np.asarray(shape.getSize()))
            elif kind == "cylinder":
                size = (shape.getRadius(), shape.getHeight())
            else:
                size = (shape.getRadius(),)
            color = tuple(float(c) for c in np.asarray(sn.getVisualAspect().getRGBA())[:3]) \
                if sn.hasVisualAspect() else (0.5, 0.5, 0.5)
            out.append((sn, kind, size, color, sn.getName(), owner))
    return out


def _sensor_mounts(r) -> dict:
    """Where a robot's lidar and camera sit on it (their config, mount poses included)."""
    from dataclasses import asdict
    sens = r.sensors
    return {"lidar": asdict(sens.lidar) if sens.lidar is not None else None,
            "camera": asdict(sens.camera) if sens.camera is not None else None}


def room_objects(spec: WorldSpec) -> list[ObjectSpec]:
    """Floor and walls as static boxes (the floor's top face is z = 0)."""
    lx, ly = spec.floor_size_m
    out = [ObjectSpec("floor", "box", (lx, ly, FLOOR_THICKNESS_M), (0, 0, -FLOOR_THICKNESS_M / 2, 0),
                      spec.floor_color, spec.floor_material)]
    h, t = spec.wall_height_m, spec.wall_thickness_m
    if h > 0:
        for name, x, y, sx, sy in (("wall_front", lx / 2 + t / 2, 0, t, ly + 2 * t),
                                   ("wall_back", -lx / 2 - t / 2, 0, t, ly + 2 * t),
                                   ("wall_left", 0, ly / 2 + t / 2, lx, t),
                                   ("wall_right", 0, -ly / 2 - t / 2, lx, t)):
            out.append(ObjectSpec(name, "box", (sx, sy, h), (x, y, h / 2, 0), spec.wall_color,
                                  "default"))
    return out


class Simulation:
    """One DART world with its robots; rebuild it (``Simulation(spec)``) to reset."""

    def __init__(self, spec: WorldSpec) -> None:
        self.spec = spec
        self._substeps = spec.substeps      # (a property of the spec: computed each call)
        w = dart.simulation.World()
        w.setTimeStep(spec.physics_step_s)
        w.setGravity(np.array([0.0, 0.0, -spec.gravity_mps2]))
        w.getConstraintSolver().setCollisionDetector(DETECTORS[spec.collision_detector]())
        self.world = w
        self.objects = room_objects(spec) + list(spec.objects)
        w.addSkeleton(room_skeleton([o for o in self.objects if o.static], spec))
        for obj in self.objects:
            if not obj.static:
                w.addSkeleton(movable_object(obj, spec))
        self.robots: dict[str, Robot] = {}
        for rs in spec.robots:
            robot = Robot(rs, spec)
            w.addSkeleton(robot.skeleton)
            self.robots[rs.name] = robot
        #: the robots' drive limiters, commands and wheel-speed targets, as arrays (its own
        #: until a Tick binds its core's: :meth:`use_drive`)
        self.drive = WorldDrive.alone(spec.robots, spec.control_tick_s)
        self._steps = 0
        self._static_shapes = [self._shape_of(o) for o in self.objects if o.static]
        self._robot_parts = [part for name, r in self.robots.items()
                             for part in _visible_parts(r, name)]
        self._part_nodes = [part[0] for part in self._robot_parts]     # (part_transforms)
        self._movable_shapes = [self._shape_of(o) for o in self.objects if not o.static]
        #: each robot's wheel dofs (left, right) in its skeleton's vectors (state_rows)
        self._wheel_dofs = [_dofs([w.getIndexInSkeleton(0) for w in r.wheels])
                            for r in self.robots.values()]
        #: +1 whenever the world's state may have moved through this object (a step, a
        #: clock restored with a saved state): a state read at the same count is still now
        self.moves = 0
        #: the kinematic world's robots (plant.kinematic), None in a dynamic world
        self.kin = Kinematics(spec) if spec.mode == "kinematic" else None
        if self.kin is not None:
            self._part_owner, self._part_rel = self._parts_on_base()
        self._scene_template = None
        self._scene_template = Scene(list(self.shapes()))     # built once per world
        self._room: Scene | None = None                         # room_scene()
        self._set_contact_solver(spec.contact_solver)
        self._motion_streams()

    def _parts_on_base(self) -> tuple[np.ndarray, np.ndarray]:
        """A kinematic world's visible parts: each one's robot (index) and pose on its
        base_link, read with every robot at the origin (so they do not depend on the
        start poses: a restarted world has the same as a new one)."""
        index = {name: i for i, name in enumerate(self.robots)}
        for r in self.robots.values():
            r.root.setPositions(np.zeros(3))
        rel = np.array([np.linalg.inv(self.robots[p[5]].transform()) @ p[0].getWorldTransform().matrix()
                        for p in self._robot_parts]).reshape(-1, 4, 4)
        for r in self.robots.values():
            r.root.setPositions(np.array(r.spec.pose, float))
        return np.array([index[p[5]] for p in self._robot_parts], np.int64), rel

    def restart(self) -> None:
        """A kinematic world back at t = 0 with the spec's seed and start poses, as a new
        ``Simulation(spec)`` would be, without building its DART world again (what a batched
        environment's resets cost most)."""
        assert self.kin is not None, "only a kinematic world restarts in place"
        self.kin.restart(self.spec)
        self.drive.reset()
        self._steps = 0
        self.moves += 1
        self._motion_streams()

    def _motion_streams(self) -> None:
        """Each robot's motion noise stream (:func:`plant.noise.stream_key` of the seed,
        the robot and "motion"), drawn through a model of std 1 (the normals)."""
        self.motion_noise = {r.name: NoiseModel(NoiseConfig(std=1.0),
                                                stream_key(self.spec.seed, r.name, "motion"))
                             for r in self.spec.robots}
        self.drive.keys[:] = [self.motion_noise[n].key for n in self.drive.names]

    def _set_contact_solver(self, name: str) -> None:
        """PGS honours the Coulomb friction limit; DART's default Dantzig solver over-grips
        under hard acceleration (docs/sensors.md, "Friction and contacts"). PGS is only
        reachable as the stock secondary solver, so the two are swapped."""
        cs = self.world.getConstraintSolver()
        if name == "pgs" and cs.getBoxedLcpSolver().getType() != "PgsBoxedLcpSolver":
            primary, secondary = cs.getBoxedLcpSolver(), cs.getSecondaryBoxedLcpSolver()
            cs.setSecondaryBoxedLcpSolver(None)
            cs.setBoxedLcpSolver(secondary)
            cs.setSecondaryBoxedLcpSolver(primary)

    # ------------------------------------------------------------------ time
    @property
    def steps(self) -> int:
        """Physics steps since t = 0: the world's clock. Only the world moves it
        (:meth:`advance`, :meth:`restore_clock`, a restart); everyone else reads it."""
        return self._steps

    @property
    def time_ns(self) -> int:
        """Simulated time in integer ns (counted in steps, so it never drifts)."""
        return self._steps * int(round(self.spec.physics_step_s * 1e9))

    def advance(self, ticks: int = 1) -> None:
        """The clock ``ticks`` control ticks on: the world was stepped elsewhere (a physics
        process, a batch's kernel) or is stepped here (:meth:`step_tick`)."""
        self._steps += int(ticks) * self._substeps
        self.moves += 1

    def restore_clock(self, steps: int) -> None:
        """The clock set back to a saved state's (an FMU's restored state)."""
        self._steps = int(steps)
        self.moves += 1

    def step_tick(self) -> None:
        """Advance one control tick (``substeps`` physics steps) with the commands filed
        (:meth:`command_targets`) or, for a robot given none, its targets as they were.

        ``world.step(False)`` keeps the motor commands (``step()`` zeroes them), so a
        dynamic robot's wheel commands are set once a tick, not once a step: the same
        values, the same motion bit for bit, a tenth of the dartpy calls. A kinematic
        world is not DART's to step: its robots move by :mod:`plant.kinematic`."""
        targets = self.command_targets()
        if self.kin is not None:
            self.kin.step(targets)
        else:
            for r, (wl, wr) in zip(self.robots.values(), targets.tolist()):
                r.apply(wl, wr)
            for _ in range(self._substeps):
                self.world.step(False)
        self.advance()

    # ------------------------------------------------------------------ commands
    def command_twist(self, robot: str, v_mps: float, w_radps: float) -> None:
        """Drive ``robot`` at (v m/s, w rad/s) from now: through its limiter and motion
        noise into its targets at once (:meth:`plant.tick.Tick.drive` files every robot's
        command and runs them together when the step starts)."""
        self.drive.twist(self.drive.index[robot], v_mps, w_radps)
        self.command_targets()

    def command_wheels(self, robot: str, wl: float, wr: float) -> None:
        """Drive ``robot``'s wheels at (left, right) rad/s from now, as :meth:`command_twist`."""
        self.drive.wheels_to(self.drive.index[robot], wl, wr)
        self.command_targets()

    def command_targets(self) -> np.ndarray:
        """The commands filed (:attr:`drive`) through each robot's drive limiter and its
        motion noise (the normals of its motion stream at this tick, the tick the commands
        act from, times its std; none for a robot commanded to stand, wheels (0, 0)) into
        the wheel-speed targets, every robot in one kernel call
        (:meth:`plant.core.drive.WorldDrive.run`): the (R, 2) targets, the arrays' own."""
        return self.drive.run(self._steps // self._substeps)

    def use_drive(self, drive: WorldDrive) -> None:
        """Keep the robots' drive state in ``drive`` (a core's rows for this world), its
        present state copied in: the arrays' one owner from now on."""
        if drive is not self.drive:
            drive.load(self.drive)
            self.drive = drive

    # ------------------------------------------------------------------ state
    def state(self, robot: str) -> RobotState:
        if self.kin is not None:
            return self.kin_state(self.kin, self.kin.names.index(robot))
        r = self.robots[robot]
        tf = r.transform()
        v, w = r.body_velocity(tf)
        pos, vel = r.encoders()
        yaw = float(np.arctan2(tf[1, 0], tf[0, 0]))
        return RobotState(tf, yaw, v, w, pos, vel)

    def state_rows(self) -> np.ndarray:
        """Every robot's :meth:`state` as one (R, 26) array, in :attr:`robots` order: the
        base_link pose (4x4, row-major), body linear and angular velocity (3 + 3), wheel
        angles and speeds (2 + 2), the same values to the bit (:meth:`read_state`)."""
        return self.read_state()[0]

    def read_state(self, velocities: bool = True) -> tuple[np.ndarray, bool]:
        """(:meth:`state_rows`, :meth:`is_finite`) of the world now, read in one pass (the
        plant checks a step's result and publishes the same state a moment later:
        :class:`plant.stepper.Stepper` keeps it while :attr:`moves` stays the same). A
        dynamic world's rows are read straight from DART (:func:`plant.dart_rows.read_rows`:
        no :class:`RobotState` a robot, no yaw); without ``velocities`` their body
        velocities are NaN until :meth:`fill_velocities` reads them."""
        if self.kin is not None:               # (its arrays are read anew every time)
            rows = np.empty((len(self.robots), STATE_COLS))
            for i, name in enumerate(self.robots):
                st = self.state(name)
                rows[i, :16] = st.tf.ravel()
                rows[i, 16:19], rows[i, 19:22] = st.v_body, st.w_body
                rows[i, 22:24], rows[i, 24:26] = st.enc_pos, st.enc_vel
            return rows, self.kin.finite()
        return read_rows(list(self.robots.values()), self._wheel_dofs, velocities)

    def fill_velocities(self, rows: np.ndarray) -> None:
        """The body velocities of a dynamic world's ``rows`` read without them, now."""
        fill_velocities(list(self.robots.values()), rows)

    @staticmethod
    def kin_state(kin: Kinematics, i: int) -> RobotState:
        """Robot ``i`` of a kinematic world, as :meth:`state` gives it."""
        x, y, yaw = kin.pose[i].tolist()
        c, s = math.cos(yaw), math.sin(yaw)
        tf = np.array([[c, -s, 0.0, x], [s, c, 0.0, y], [0.0, 0.0, 1.0, float(kin.radius[i])],
                       [0.0, 0.0, 0.0, 1.0]])
        v, w = kin.vel[i].tolist()
        return RobotState(tf, math.atan2(s, c), np.array([v, 0.0, 0.0]), np.array([0.0, 0.0, w]),
                          kin.wheels[i].copy(), kin.speeds[i].copy())

    def is_finite(self) -> bool:
        """Whether every robot's positions and velocities are finite (a tick's check comes
        with the state it then publishes: :meth:`read_state`)."""
        if self.kin is not None:
            return self.kin.finite()
        return all(_finite(r.skeleton.getPositions(), r.skeleton.getVelocities())
                   for r in self.robots.values())

    # ------------------------------------------------------------------ geometry for sensors
    @staticmethod
    def _shape_of(o: ObjectSpec, parent: np.ndarray | None = None, owner: str = "") -> Shape:
        x, y, z, yaw = o.pose
        tf = pose_matrix(x, y, z, yaw=yaw)
        return Shape(o.shape, tuple(o.size), tf if parent is None else parent @ tf, o.color,
                     o.name, owner)

    def part_transforms(self) -> np.ndarray:
        """(P, 4, 4) world poses of the robots' visible parts, in :meth:`shapes` order."""
        if self.kin is not None:
            return np.matmul(self.kin.transforms()[self._part_owner], self._part_rel)
        # the world transforms (as state_rows reads them), stacked in one call: a fifth
        # cheaper than copying each into its place (24 robots' 96 parts: ~170 us, not ~215)
        return np.array([sn.getTransform().matrix() for sn in self._part_nodes]
                        ).reshape(-1, 4, 4)

    def scene(self, part_tfs: np.ndarray | None = None) -> Scene:
        """What the sensors see now, as one :class:`~plant.raycast.Scene`: the world's scene
        stacked once with the robots' parts at ``part_tfs`` ((P, 4, 4), from
        :meth:`part_transforms` if not given: a physics process's), the still shapes and
        the movable objects where the world file puts them. Built from the arrays, no
        :class:`~plant.shapes.Shape` a part (:meth:`shapes` has the same values as objects)."""
        if part_tfs is None:
            part_tfs = self.part_transforms()
        poses = np.asarray(part_tfs, dtype=float).reshape(-1, 4, 4)
        if len(poses) != len(self._robot_parts):
            raise ValueError(f"{len(poses)} part poses for the {len(self._robot_parts)} "
                             "visible parts of the robots")
        return Scene.placed(self._scene_template, len(self._static_shapes), poses)

    def scene_layout(self) -> tuple:
        """How :meth:`scene` lays the world out, for those who cast it call after call
        (read-only, the world's own arrays): (the scene as built once, the row of the robots'
        first part in it, their count (the parts follow in :meth:`part_transforms`' order),
        each part's robot (index) and pose on its base_link in a kinematic world, whose
        :meth:`part_transforms` is ``transforms[robot] @ pose``, else None and None)."""
        owner, rel = (self._part_owner, self._part_rel) if self.kin is not None else (None, None)
        return (self._scene_template, len(self._static_shapes), len(self._robot_parts),
                owner, rel)

    def shapes(self, part_tfs: np.ndarray | None = None) -> ShapeList:
        """Every solid of the world in world coordinates, robots included (their parts at
        ``part_tfs``, from :meth:`part_transforms`, if given: a physics process's), as
        objects: for those who draw or list them (the sensors' tick uses :meth:`scene`).

        A :class:`~plant.raycast.ShapeList`: a :class:`~plant.raycast.Scene` of it shares
        the arrays of the world's still shapes, stacked once, and stacks only the poses of
        the moving ones (the robots' parts, then the movable objects)."""
        if part_tfs is None:
            part_tfs = self.part_transforms()
        moving = [Shape.placed(kind, size, np.asarray(tf, dtype=float).reshape(4, 4), color, name,
                               owner)
                  for (sn, kind, size, color, name, owner), tf in zip(self._robot_parts, part_tfs)]
        moving += self._movable_shapes
        poses = np.array([s.pose for s in moving], dtype=float).reshape(-1, 4, 4)
        return ShapeList(self._static_shapes + moving, self._scene_template,
                         len(self._static_shapes), poses)

    def room_scene(self) -> Scene:
        """The world without its robots, as one :class:`~plant.raycast.Scene`, built once:
        the still shapes and the movable objects where the world file puts them
        (:meth:`scene` never moves them either). What a one-robot world's sensors see:
        a lidar or a camera skips its own robot's parts."""
        if self._room is None:
            self._room = Scene(list(self._static_shapes) + list(self._movable_shapes))
        return self._room

    def body_visuals(self, robot: str) -> list[dict]:
        """What a robot looks like, in its base_link frame: each visual shape (chassis,
        wheels, caster, carried parts) with its size, colour and pose (position m,
        orientation quaternion x, y, z, w). For viewers (``diffbot view``)."""
        base_inv = np.linalg.inv(self.robots[robot].transform())
        out = []
        for sn, kind, size, color, name, owner in self._robot_parts:
            if owner != robot:
                continue
            rel = base_inv @ sn.getWorldTransform().matrix()
            out.append({"name": name, "shape": kind, "size": [float(v) for v in size],
                        "position": [float(v) for v in rel[:3, 3]],
                        "orientation": [float(v) for v in rotation_to_quaternion(rel[:3, :3])],
                        "color": [float(c) for c in color]})
        return out

    def describe(self) -> dict:
        """The world as the plant understood it (served on ``sim/info``)."""
        s = self.spec
        return {
            "world": s.name, "world_file": s.path, "mode_physics": s.mode,
            "physics_step_s": s.physics_step_s, "control_tick_s": s.control_tick_s,
            "floor_size_m": list(s.floor_size_m), "wall_height_m": s.wall_height_m,
            "objects": [{"name": o.name, "shape": o.shape, "size": list(o.size),
                         "pose": list(o.pose), "color": list(o.color), "material": o.material}
                        for o in self.objects],
            "robots": {r.name: {"pose": list(r.pose), "color": list(r.color),
                                "wheel_radius_m": r.drive.wheel_radius_m,
                                "wheel_separation_m": r.drive.wheel_separation_m,
                                "drive": dict(r.drive.__dict__),
                                "joints": ["left_wheel_joint", "right_wheel_joint"],
                                "parts": [p.name for p in r.parts],
                                "body": self.body_visuals(r.name),
                                "sensors": _sensor_mounts(r)}
                       for r in s.robots},
            "materials": {m.name: m.friction for m in s.materials.values()},
        }
