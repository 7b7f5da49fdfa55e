"""Steps the world one control tick, in this process or in a physics process of its own.

With a physics process (``--physics-process``) and a mode whose commands for the step do
not wait for tick k's sensors (pipelined lockstep, fast), the step *overlaps* the
publishing: the plant publishes tick k between :meth:`Stepper.start` and
:meth:`Stepper.finish`, while the physics process steps to k + 1 (:class:`plant.tick.Tick`
tells its host when). Either way the bytes are the same.
"""
from __future__ import annotations

from .physics_process import PhysicsProcess
from .sensors import RobotSensors
from .sim import Simulation
from .world import WorldSpec


class Stepper:
    def __init__(self, spec: WorldSpec, sim: Simulation, physics: PhysicsProcess | None,
                 sensors: dict[str, RobotSensors], overlap: bool) -> None:
        self.spec = spec
        self.sim = sim
        self.physics = physics
        self.sensors = sensors
        self.overlap = overlap and physics is not None
        self.tick_ns = spec.tick_ns
        #: one robot: its sensors see the room alone (:meth:`shapes`), so a physics
        #: process need not read its parts' poses
        self._room_only = len(sim.robots) == 1
        #: the periods (ticks) of the sensors that cast rays (RobotSensors.needs_scene's
        #: topics), once for all robots: a tick asks a few numbers, not every robot
        self._scene_periods = sorted({s.periods[t] for s in sensors.values()
                                      for t in ("scan", "camera/image_raw") if t in s.periods})
        #: (sim.moves, rows, finite, whether the rows hold the velocities) of the last read
        #: of the world in this process: a tick checks its step (:meth:`finite`) and then
        #: publishes the same state (:meth:`rows`)
        self._read: tuple | None = None

    # ------------------------------------------------------------ the world's state
    def state(self, robot: str):
        if self.physics is None:
            return self.sim.state(robot)
        return self.physics.state(robot)

    def rows(self, velocities: bool = True):
        """Every robot's state as one (R, 26) array (:meth:`Simulation.state_rows`' layout:
        the values :meth:`state` gives, robot by robot, to the bit): read from DART in one
        pass, here or by the physics process (:meth:`PhysicsProcess.rows`). Without
        ``velocities`` (nobody reads them this tick) a dynamic world's body velocities may be
        NaN: DART then need not compute them."""
        if self.physics is None:
            return self._read_now(velocities)[1]
        return self.physics.rows()

    def shapes(self):
        """What the robots' sensors see now (the scene of a tick's lidars and cameras), built
        from the robots' parts' poses as one array (:meth:`Simulation.scene`). In a
        one-robot world that is the room alone (:meth:`Simulation.room_scene`): a sensor
        skips its own robot's parts, so the rays and pixels are the same, and the robot's
        parts need not be placed (in DART, a world transform per part) every time."""
        if self._room_only:
            return self.sim.room_scene()
        if self.physics is None:
            return self.sim.scene()
        return self.sim.scene(self.physics.parts())

    def finite(self) -> bool:
        if self.physics is not None:
            return self.physics.finite
        if self.sim.kin is not None:
            return self.sim.is_finite()
        return self._read_now(False)[2]

    def _read_now(self, velocities: bool = True) -> tuple:
        """The world's state in this process (:meth:`Simulation.read_state`): a dynamic
        world's read once while its clock stays (a step or a restored state moves it:
        ``sim.moves``), its velocities the first time they are asked for; a kinematic
        world's, arrays of its own, read every time."""
        read = self._read
        if self.sim.kin is not None:
            return (self.sim.moves, *self.sim.read_state(), True)
        if read is None or read[0] != self.sim.moves:
            read = self._read = (self.sim.moves, *self.sim.read_state(velocities), velocities)
        elif velocities and not read[3]:
            self.sim.fill_velocities(read[1])
            read = self._read = (*read[:3], True)
        return read

    # ------------------------------------------------------------ a tick
    def start(self) -> None:
        """Start the step to the next tick with the targets the commands set: in this
        process, the whole step; in a physics process, its start (:meth:`finish` waits for
        it), the plant free to publish meanwhile."""
        if self.physics is None:
            self.sim.step_tick()
            return
        tick = self.sim.time_ns // self.tick_ns + 1
        self.physics.start_step(self.sim.command_targets(),
                                not self._room_only and
                                any(tick % p == 0 for p in self._scene_periods))

    def finish(self) -> None:
        """The step started by :meth:`start` done: the world at the next tick."""
        if self.physics is not None:
            self.physics.finish_step()
            self.sim.advance()                            # the clock of the plant's own copy
