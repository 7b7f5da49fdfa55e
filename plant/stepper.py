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
        #: one robot: its sensors see the room alone (:meth:`shapes`)
        self._room_only = len(sim.robots) == 1

    # ------------------------------------------------------------ the world's state
    # With a physics process, ``sim`` is its mirror (:class:`plant.physics_process.
    # PhysicsProcess`): loaded with the worker's state on the first read of a tick, then
    # read as if it had stepped here.
    def state(self, robot: str):
        if self.physics is not None:
            self.physics.sync()
        return self.sim.state(robot)

    def rows(self):
        """Every robot's state as one (R, 26) array (:meth:`Simulation.state_rows`' layout:
        the values :meth:`state` gives, robot by robot, to the bit), read from DART in one
        pass."""
        if self.physics is not None:
            self.physics.sync()
        return self.sim.state_rows()

    def shapes(self):
        """What the robots' sensors see now (the scene of a tick's lidars and cameras), built
        from the robots' parts' poses as one array (:meth:`Simulation.scene`). In a
        one-robot world that is the room alone (:meth:`Simulation.room_scene`): a sensor
        skips its own robot's parts, so the rays and pixels are the same, and the robot's
        parts need not be placed (in DART, a world transform per part) every time."""
        if self._room_only:
            return self.sim.room_scene()
        if self.physics is not None:
            self.physics.sync()
        return self.sim.scene()

    def finite(self) -> bool:
        return self.sim.is_finite() if self.physics is None else self.physics.finite

    # ------------------------------------------------------------ a tick
    def start(self) -> None:
        """Start the step to the next tick with the targets the commands set: in this
        process, the whole step; in a physics process, its start (:meth:`finish` waits for
        it), the plant free to publish meanwhile. The mirror is loaded with the present
        tick's state then, while the worker steps, off the physics' path."""
        if self.physics is None:
            self.sim.step_tick()
            return
        self.physics.start_step(self.sim.command_targets())
        self.physics.sync()

    def finish(self) -> None:
        """The step started by :meth:`start` done: the world at the next tick."""
        if self.physics is not None:
            self.physics.finish_step()
            self.sim.advance()                            # the clock of the plant's own copy
