"""A world's control tick, without a bus: :class:`Tick`, the one object that steps a world.

The plant node (:mod:`plant.process`, with members over the bus or composed into its
process), the in-process Gymnasium environments (:mod:`diffbot.envs`) and the plant FMU
all drive it, so they produce the same messages, bit for bit, from the same seed and
commands. Tick k is::

    for robot, topic, msg in tick.messages():  # sensors due at t_k, with their noise
        ...                                    # publish; sim/clock; the members answer t_k
    tick.drive(robot, command)                 # for every robot (None: stand still)
    tick.step()                                # to t_{k+1} (a diverged world is rebuilt)

A host that publishes the messages asks the tick when: :meth:`Tick.begin` says whether to
publish now, :meth:`Tick.start_step` whether to publish while the physics process steps
(overlap), :meth:`Tick.finish_step` ends the step; the sensors of a tick go out once.

Every host's messages come from the world's core (:mod:`plant.core`: every robot's
per-tick messages in one kernel call); :func:`tick_messages` and
:class:`plant.sensors.RobotSensors` make the same messages robot by robot, the oracle the
tests compare the core with. A reading's noise is a function of (seed, robot, stream,
tick, index) (:mod:`plant.noise`), so no order of calls changes it. Anything that changes
the sensors due at a tick or a message's values changes every host at once;
``tests/envs/test_envs_identity.py`` checks that the in-process and bus transports still
agree to the bit.
"""
from __future__ import annotations

from typing import Callable, Iterator, Sequence

import numpy as np

from bus.controller import Twist, WheelSpeeds

from . import core, kinematic
from . import lidar as lid
from .physics_process import PhysicsProcess
from .raycast import Scene
from .sensors import RobotSensors, Wanted, scan_all
from .sim import RobotState, Simulation
from .stepper import Stepper
from .world import WorldSpec


class Tick:
    """One world's tick: the sensors due at t_k (built only where wanted), the robots'
    commands for t_k, the physics step to t_{k+1}, the rebuild of a
    diverged world, reset. ``disabled``: sensors taken off every robot ("lidar",
    "camera"); ``physics_process``: DART in a process of its own (:mod:`plant.stepper`;
    not for a kinematic world, whose step, one C call for every robot, costs less than
    handing it to another process and reading every robot's state back),
    publishing overlapping the step where ``overlap`` (the mode's commands for the step do
    not wait for tick k's sensors)."""

    _twist_rows: tuple | None = None      # (drive, names, their rows): drive_twists'

    def __init__(self, spec: WorldSpec, disabled: tuple[str, ...] = (),
                 physics_process: bool = False, overlap: bool = False) -> None:
        self.spec = spec
        self.disabled = tuple(disabled)
        self.tick_ns = spec.tick_ns
        self.physics_process = physics_process and spec.mode != "kinematic"
        self.overlap = overlap
        self.physics: PhysicsProcess | None = None
        self._owed = False                # this tick's sensors are still to be published
        #: the world's core (:mod:`plant.core`), made with the world
        self.model: core.Model | None = None
        self.build()

    def build(self) -> None:
        """(Re)build the world at t = 0 with the spec's seed and start poses (a kinematic
        world in this process restarts in place: :meth:`plant.sim.Simulation.restart`)."""
        old = getattr(self, "sim", None)
        reuse = old if old is not None and old.kin is not None and not self.physics_process else None
        self.sim, self.sensors = build_world(self.spec, self.spec.seed, self.disabled, reuse)
        if self.physics_process:
            if self.physics is None:         # (the plant's own world: its mirror)
                self.physics = PhysicsProcess(self.spec, self.sim)
            else:
                self.physics.build(self.spec, self.sim)
        self.stepper = Stepper(self.spec, self.sim, self.physics, self.sensors,
                               overlap=self.overlap)
        self._owed = True                 # (the new world's t = 0)
        if self.model is None:            # (a reset moves the robots, not their sensors)
            self.model = core.Model([self.spec])
            self.data = core.Data(self.model)
        self.data.set_streams(0, self.sensors)
        self.sim.use_drive(core.world_drive(self.model, self.data, 0))

    def reset(self, seed: int | None = None, poses: dict | None = None) -> None:
        """As ``sim/reset``: keep ``seed`` and the start ``poses`` ({robot: (x, y, yaw)}) in
        the spec and rebuild the world at t = 0."""
        if seed is not None:
            self.spec.seed = int(seed)
        for name, pose in (poses or {}).items():
            self.spec.robot(name).pose = tuple(float(v) for v in pose)
        self.build()

    @property
    def t_ns(self) -> int:
        return self.sim.time_ns

    def messages(self, wanted: dict[str, Wanted] | None = None, encoded: bool = False,
                 cast: tuple | None = None) -> Iterator[tuple[str, str, object]]:
        """(robot, topic, message) of every sensor due now, in the plant's order, made by
        the core for every robot at once (:func:`plant.core.sense`; ``None`` for a topic
        nobody wants). ``encoded``: CDR bytes (the plant publishes them), else the
        messages (:mod:`bus.codec`'s: the in-process environments and the plant FMU read
        them). ``cast``: the tick's lidars cast already (:func:`messages_of`)."""
        self.observe()
        return iter(self._sense(wanted, encoded, cast))

    def messages_read(self, wanted: dict[str, Wanted]) -> tuple[int, list]:
        """The encoded messages due now that someone reads, each with its place among the
        due ones, and how many were due (:func:`plant.core.sense_read`): a host that
        publishes skips no message one by one. The robots' velocities are read from the
        world only where a ground_truth is made."""
        self.observe(core.reads_truth(self.model, self.data, 0,
                                      self.sim.time_ns // self.tick_ns, wanted))
        return core.sense_read(self.model, self.data, 0, self.sim.time_ns,
                               self.stepper.shapes, wanted)

    def observe(self, velocities: bool = True) -> None:
        """Every robot's true state now into the core's arrays (:func:`plant.core.observe`;
        without ``velocities``, a dynamic world's speeds may be left out)."""
        core.observe(self.model, self.data, 0, self.stepper, velocities)

    def _sense(self, wanted, encoded: bool, cast: tuple | None) -> list:
        """:meth:`messages` of the state :meth:`observe` read."""
        return core.sense(self.model, self.data, 0, self.sim.time_ns, self.stepper.shapes,
                          wanted, encoded, cast)

    def prefetch(self) -> None:
        """Draw the next tick's sensor noise ahead where it is drawn in numpy (off a
        member's critical path): the same values as drawn when due."""
        nxt = self.sim.time_ns // self.tick_ns + 1
        for sensors in self.sensors.values():
            sensors.prefetch(nxt)

    def drive(self, robot: str, command: Twist | WheelSpeeds | None) -> None:
        """The command that acts on ``robot`` from now to the next tick (None: stand still),
        filed into the core's arrays: the step's start runs every robot's through its drive
        limiter and motion noise in one call (:meth:`plant.sim.Simulation.command_targets`).
        A robot given no command keeps its wheel targets; the last command filed for a
        robot in a tick is the one that acts."""
        d = self.sim.drive
        if command is None:
            d.twist(d.index[robot], 0.0, 0.0)
        elif isinstance(command, Twist):
            d.twist(d.index[robot], command.linear, command.angular)
        else:
            d.wheels_to(d.index[robot], command.left, command.right)

    def drive_twists(self, names: tuple, values: np.ndarray) -> None:
        """:meth:`drive` of ``Twist(*values[j])`` for each robot ``names[j]``, filed into the
        core's command arrays at once (the rows of ``names`` asked once per drive)."""
        d = self.sim.drive
        rows = self._twist_rows
        if rows is None or rows[0] is not d or rows[1] is not names:
            rows = self._twist_rows = (d, names, np.array([d.index[n] for n in names]))
        d.twists(rows[2], values)

    def begin(self) -> bool:
        """A new tick: whether the host publishes its sensors now (not if the step will,
        overlapping: :meth:`start_step` says so then)."""
        self._owed = True
        return not self.stepper.overlap and self.publish_due()

    def publish_due(self) -> bool:
        """Whether this tick's sensors are still to be published (the run ends at a tick
        whose sensors an overlapping step would have published). True once a tick: the
        host publishes them when told."""
        owed, self._owed = self._owed, False
        return owed

    def start_step(self) -> bool:
        """Start the step to the next tick with the commands driven; whether the host
        publishes this tick's sensors now, while the physics process steps. Then
        :meth:`finish_step`."""
        self.stepper.start()
        return self.stepper.overlap and self.publish_due()

    def finish_step(self) -> bool:
        """The step done; a diverged world is rebuilt at t = 0 (False)."""
        self.stepper.finish()
        if self.stepper.finite():
            return True
        self.build()
        return False

    def step(self) -> bool:
        """Step to the next tick with the commands driven, for a host that publishes
        nothing while it steps; a diverged world is rebuilt at t = 0 (False)."""
        self.start_step()
        return self.finish_step()

    def close(self) -> None:
        if self.physics is not None:
            self.physics.close()
            self.physics = None


def step_ticks(ticks: Sequence[Tick]) -> None:
    """``tick.step()`` of several worlds (a batched environment's), each to the bit as
    alone: kinematic worlds (:mod:`plant.kinematic`, no physics process) all in one call."""
    kin = [t for t in ticks if t.sim.kin is not None and t.physics is None]
    if len(kin) < 2:
        kin = []
    else:
        batch = kinematic.join([t.sim.kin for t in kin])
        batch.step(np.concatenate([t.sim.command_targets() for t in kin]))
        finite = batch.finite()
        for t in kin:
            t.sim.advance()
            if not (finite or t.stepper.finite()):
                t.build()
    stepped = {id(t) for t in kin}
    for t in ticks:
        if id(t) not in stepped:
            t.step()


def messages_of(ticks: Sequence[Tick], wanted: Sequence[dict[str, Wanted] | None]
                ) -> list[list[tuple[str, str, object]]]:
    """``list(tick.messages(wanted))`` of several worlds, the same messages, with every
    world's lidars due now cast in one call (:func:`plant.lidar.scan_worlds`, robots
    carrying the same lidar together, at the poses each world's core read)."""
    scenes, groups = [], {}
    wanted = [settled(t.sensors, t.t_ns // t.tick_ns, want) for t, want in zip(ticks, wanted)]
    for t in ticks:
        t.observe()
    for k, (t, want) in enumerate(zip(ticks, wanted)):
        tick, w = t.t_ns // t.tick_ns, want or {}
        scene = None
        if any(s.needs_scene(tick, w.get(name)) for name, s in t.sensors.items()):
            scene = Scene.from_shapes(t.stepper.shapes())
        scenes.append(scene)
        if scene is None:
            continue
        for i, (name, s) in enumerate(t.sensors.items()):
            if s.lidar_due(tick) and (want is None or want[name]("scan")):
                groups.setdefault(s.lidar, []).append((k, i, name, t.data.tf[0, i]))
    scans: list[dict] = [{} for _ in ticks]
    for cfg, rows in groups.items():
        idx = sorted({k for k, *_ in rows})
        at = {k: i for i, k in enumerate(idx)}
        ranges = lid.scan_worlds(cfg, [scenes[k] for k in idx], [tf for *_, tf in rows],
                                 [name for _, _, name, _ in rows], [at[k] for k, *_ in rows])
        for (k, i, _, _), r in zip(rows, ranges):
            scans[k][i] = r
    return [t._sense(want, False, (scene, sc))
            for t, want, scene, sc in zip(ticks, wanted, scenes, scans)]


def build_world(spec: WorldSpec, seed: int, disabled=(), restart: Simulation | None = None
                ) -> tuple[Simulation, dict[str, RobotSensors]]:
    """A fresh world and its robots' sensors (noise streams seeded from ``seed``), with the
    sensors named in ``disabled`` ("lidar", "camera") taken off every robot; ``restart``: a
    kinematic world of this spec, restarted instead of built anew."""
    for r in spec.robots:
        if "lidar" in disabled:
            r.sensors.lidar = None
        if "camera" in disabled:
            r.sensors.camera = None
    if restart is not None:
        restart.restart()
        sim = restart
    else:
        sim = Simulation(spec)
    sensors = {r.name: RobotSensors(r, spec.control_tick_s, seed) for r in spec.robots}
    return sim, sensors


def settled(sensors: dict[str, RobotSensors], tick: int, wanted: dict[str, Wanted] | None
            ) -> dict[str, Wanted] | None:
    """``wanted`` asked once for each robot's topics due at ``tick``, the answers kept for
    the tick. The plant's answers change when a reader comes or goes (Zenoh's matching
    listener, on another thread): asked twice, "is the scan read?" said no when the scene
    was decided and yes when the scan was built, and the plant died casting rays into no
    scene (a TypeError, when a ROS 2 bridge came up at that moment)."""
    if wanted is None:
        return None
    return {name: frozenset(t for t in s.due(tick) if w(t)).__contains__
            for name, s in sensors.items() if (w := wanted.get(name)) is not None}


def tick_messages(t_ns: int, tick_ns: int, sensors: dict[str, RobotSensors],
                  state: Callable[[str], RobotState], shapes: Callable[[], list | Scene],
                  wanted: dict[str, Wanted] | None = None, encoded: bool = False,
                  cast: tuple | None = None) -> Iterator[tuple[str, str, object]]:
    """(robot, topic, message) of every sensor due at time ``t_ns``, robot by robot in a
    fixed order (the order the plant publishes them in): the per-message path, kept as the
    oracle of the core (:func:`plant.core.sense`), which the hosts use; the tests compare
    the two message by message. ``state(robot)`` gives a robot's true state, ``shapes()``
    the world's solids or their Scene (called only when a lidar or a camera is due).

    ``wanted`` (robot -> ``wanted(topic)``, the plant's "does anyone read it"): a due topic
    nobody reads comes as ``(robot, topic, None)``, not built (no ray cast, no frame
    rendered, no noise drawn; every other value is what it would have been) (None:
    every topic is built; each asked once a tick, :func:`settled`). ``encoded``: the
    messages' CDR bytes instead of the messages (:meth:`RobotSensors.messages`).
    ``cast``: (scene, {robot: noise-free ranges}) of this tick, made already
    (:func:`messages_of`)."""
    tick = t_ns // tick_ns
    if cast is None:                       # (a cast's caller settled them already)
        wanted = settled(sensors, tick, wanted)
    want = wanted or {}
    states = {name: state(name) for name in sensors}
    if cast is not None:
        scene, scans = cast
    else:
        scene = None
        if any(s.needs_scene(tick, want.get(name)) for name, s in sensors.items()):
            scene = Scene.from_shapes(shapes())
        scans = scan_all(sensors, states, tick, scene, wanted) if scene is not None else {}
    for name, s in sensors.items():
        built = iter(s.messages(tick, t_ns, states[name], scene, scans.get(name),
                                want.get(name), encoded))
        nxt = next(built, None)
        for topic in s.due(tick):                     # the messages' order
            if nxt is not None and nxt[0] == topic:
                yield name, topic, nxt[1]
                nxt = next(built, None)
            else:
                yield name, topic, None
