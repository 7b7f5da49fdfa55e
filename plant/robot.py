"""The study's differential-drive robot as a DART skeleton.

Body: a box chassis whose origin is the midpoint of the wheel axle (``base_link``,
at wheel-radius height); two wheels of radius r whose contact points are d apart,
on revolute joints about +y driven by torque-limited velocity servos (their
positions are the encoders); a passive, frictionless caster sphere at the rear.
The chassis' centre of mass sits 8 cm behind the axle, toward the caster, so the
robot does not tip onto its nose when it brakes hard.

Dynamic mode: a free joint, contact and friction decide the motion (slip
included). Kinematic mode: a planar joint servoed to the ideal unicycle velocity;
the wheels spin freely at their commanded speeds, walls still stop the chassis.
"""
from __future__ import annotations

import dartpy as dart
import numpy as np

from .shapes import pose_matrix
from .world import ObjectSpec, RobotSpec, WorldSpec

D = dart.dynamics

CHASSIS_SIZE_M = (0.40, 0.26, 0.10)
CHASSIS_OFFSET_X_M = -0.05           # box centre behind the axle
COM_OFFSET_X_M = -0.08               # centre of mass toward the caster
CASTER_RADIUS_M = 0.05
CASTER_X_M = -0.20
WHEEL_WIDTH_M = 0.04
WHEEL_COLOR = (0.08, 0.08, 0.08)
CASTER_COLOR = (0.6, 0.6, 0.6)


def isometry(m: np.ndarray) -> dart.math.Isometry3:
    t = dart.math.Isometry3()
    t.set_matrix(np.asarray(m, dtype=float))
    return t


def add_shape(body, shape, tf=None, color=None, friction=None, collide=True, name=None,
              visual=True):
    """A shape node on ``body``: a visual aspect if ``visual``, collision + friction if
    ``collide``."""
    sn = body.createShapeNode(shape, name) if name else body.createShapeNode(shape)
    if tf is not None:
        sn.setRelativeTransform(isometry(tf))
    if visual:
        va = sn.createVisualAspect()
        if color is not None:
            va.setColor(np.asarray(color, dtype=float))
    if collide:
        sn.createCollisionAspect()
        da = sn.createDynamicsAspect()
        if friction is not None:
            da.setFrictionCoeff(float(friction))
    return sn


def dart_shape(kind: str, size) -> "D.Shape":
    if kind == "box":
        return D.BoxShape(np.asarray(size, dtype=float))
    if kind == "cylinder":
        return D.CylinderShape(float(size[0]), float(size[1]))
    return D.SphereShape(float(size[0]))


def inertia(mass: float, moment_of, com=(0.0, 0.0, 0.0)) -> "D.Inertia":
    i = D.Inertia()
    i.setMass(mass)
    i.setLocalCOM(np.asarray(com, dtype=float))
    i.setMoment(moment_of.computeInertia(mass))
    return i


class Robot:
    """Handles to one robot's skeleton in a DART world."""

    def __init__(self, spec: RobotSpec, world: WorldSpec) -> None:
        self.spec = spec
        self.kinematic = world.mode == "kinematic"
        drive = spec.drive
        r, d = drive.wheel_radius_m, drive.wheel_separation_m
        mu_wheel = world.materials[spec.wheel_material].friction
        sk = D.Skeleton(spec.name)
        x, y, yaw = spec.pose
        if self.kinematic:
            # never stepped (plant/kinematic.py moves a kinematic robot): its shapes only,
            # on a planar joint at the axle's height
            props = D.PlanarJointProperties()
            props.mName = "base_planar"
            props.mT_ParentBodyToJoint = isometry(pose_matrix(0, 0, r))
            self.root, chassis = sk.createPlanarJointAndBodyNodePair(None, props)
            self.root.setXYPlane()
            self.root.setPositions(np.array([x, y, yaw]))
        else:
            self.root, chassis = sk.createFreeJointAndBodyNodePair()
            q = np.zeros(6)
            q[2] = yaw                      # rotation vector about z
            q[3:] = (x, y, r + 1e-4)        # a hair above the floor, settles at once
            self.root.setPositions(q)
        chassis.setName("chassis")
        box = D.BoxShape(np.array(CHASSIS_SIZE_M))
        add_shape(chassis, box, pose_matrix(CHASSIS_OFFSET_X_M, 0, 0.0), spec.color, 0.3,
                  name=f"{spec.name}_chassis")
        chassis.setInertia(inertia(spec.chassis_mass_kg, box, (COM_OFFSET_X_M, 0, 0)))
        # Passive caster: a frictionless sphere touching the floor behind the axle.
        add_shape(chassis, D.SphereShape(CASTER_RADIUS_M),
                  pose_matrix(CASTER_X_M, 0, CASTER_RADIUS_M - r), CASTER_COLOR, 0.0,
                  collide=not self.kinematic, name=f"{spec.name}_caster")
        for part in spec.parts:
            px, py, pz, pyaw = part.pose
            add_shape(chassis, dart_shape(part.shape, part.size), pose_matrix(px, py, pz, yaw=pyaw),
                      part.color, world.materials[part.material].friction,
                      name=f"{spec.name}_{part.name}")
        self.chassis = chassis
        self.wheels = []
        for side, wy in (("left", d / 2), ("right", -d / 2)):
            props = D.RevoluteJointProperties()
            props.mName = f"{side}_wheel_joint"
            props.mAxis = np.array([0.0, 1.0, 0.0])
            props.mT_ParentBodyToJoint = isometry(pose_matrix(0, wy, 0))
            joint, wheel = sk.createRevoluteJointAndBodyNodePair(chassis, props)
            wheel.setName(f"{side}_wheel")
            cyl = D.CylinderShape(r, WHEEL_WIDTH_M)
            # The cylinder is for looks (its axis is local z: turn it onto y); the
            # sphere collides, which keeps the contact point exact on any detector.
            add_shape(wheel, cyl, pose_matrix(roll=np.pi / 2), WHEEL_COLOR, collide=False,
                      name=f"{spec.name}_{side}_wheel_visual")
            add_shape(wheel, D.SphereShape(r), None, None, mu_wheel, collide=not self.kinematic,
                      name=f"{spec.name}_{side}_wheel")
            wheel.setInertia(inertia(spec.wheel_mass_kg, cyl))
            joint.setActuatorType(D.ActuatorType.SERVO)
            tau = drive.max_wheel_torque_nm if not self.kinematic else 1e3
            joint.setForceLowerLimit(0, -tau)
            joint.setForceUpperLimit(0, tau)
            self.wheels.append(joint)
        self.skeleton = sk

    def apply(self, wl: float, wr: float) -> None:
        """Set the wheels' speed commands (rad/s; DART's ``step()`` zeroes them after every
        step, ``step(False)`` keeps them)."""
        self.wheels[0].setCommand(0, wl)
        self.wheels[1].setCommand(0, wr)

    def encoders(self) -> tuple[np.ndarray, np.ndarray]:
        """Wheel angles (rad) and speeds (rad/s), left then right."""
        return (np.array([self.wheels[0].getPosition(0), self.wheels[1].getPosition(0)]),
                np.array([self.wheels[0].getVelocity(0), self.wheels[1].getVelocity(0)]))

    def transform(self) -> np.ndarray:
        """base_link -> world, 4x4."""
        return self.chassis.getWorldTransform().matrix()

    def body_velocity(self, tf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear and angular velocity of base_link expressed in base_link."""
        rot = tf[:3, :3]
        return (rot.T @ np.asarray(self.chassis.getLinearVelocity()),
                rot.T @ np.asarray(self.chassis.getAngularVelocity()))


def floor_is_plane(world: WorldSpec) -> bool:
    """Whether the floor collides as the plane z = 0 rather than as its box: where walls
    keep everything on the floor (so its edges can never be reached) and the detector is
    Bullet, whose sphere-plane test is ~10 % of a swarm's step cheaper than sphere-box
    (GJK) and moves the robots the same to a fraction of a millimetre (tests/plant/test_physics.py)."""
    return world.wall_height_m > 0 and world.collision_detector == "bullet"


def room_skeleton(objects: list[ObjectSpec], world: WorldSpec) -> "D.Skeleton":
    """Every static object as a shape of ONE welded body: a skeleton does not collide with
    itself, so the furniture resting on the floor costs no contact checks."""
    sk = D.Skeleton("room")
    _, body = sk.createWeldJointAndBodyNodePair()
    body.setName("room")
    plane = floor_is_plane(world)
    for obj in objects:
        x, y, z, yaw = obj.pose
        friction = world.materials[obj.material].friction
        as_plane = plane and obj.name == "floor"
        add_shape(body, dart_shape(obj.shape, obj.size), pose_matrix(x, y, z, yaw=yaw),
                  obj.color, friction, collide=not as_plane, name=obj.name)
        if as_plane:
            add_shape(body, D.PlaneShape(np.array([0.0, 0.0, 1.0]), 0.0), friction=friction,
                      name="floor_plane", visual=False)
    sk.setMobile(False)
    return sk


def movable_object(obj: ObjectSpec, world: WorldSpec) -> "D.Skeleton":
    """A free body (``static = false`` in the world file)."""
    sk = D.Skeleton(obj.name)
    joint, body = sk.createFreeJointAndBodyNodePair()
    x, y, z, yaw = obj.pose
    shape = dart_shape(obj.shape, obj.size)
    add_shape(body, shape, None, obj.color, world.materials[obj.material].friction, name=obj.name)
    body.setInertia(inertia(obj.mass_kg, shape))
    q = np.zeros(6)
    q[2] = yaw
    q[3:] = (x, y, z)
    joint.setPositions(q)
    return sk
