"""Steps the world one control tick, in this process or in a physics process of its own.

With a physics process (``--physics-process``) and a mode whose commands for the step do
not wait for tick k's sensors (pipelined lockstep, fast), the stepper *overlaps*: it
publishes tick k while the physics process steps to k + 1. Either way the bytes are the
same; the plant's loop only asks "publish this tick's sensors" and "step", and the stepper
decides when the publishing happens.
"""
from __future__ import annotations

import time
from typing import Callable

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
        self._index = {name: i for i, name in enumerate(sim.robots)}
        #: one robot: its sensors see the room alone (:meth:`shapes`), so a physics
        #: process need not send its parts' poses
        self._room_only = len(sim.robots) == 1
        self._published = False           # this tick's sensors went out

    # ------------------------------------------------------------ the world's state
    def state(self, robot: str):
        if self.physics is None:
            return self.sim.state(robot)
        return self.physics.state(self._index[robot])

    def shapes(self):
        """What the robots' sensors see now (the scene of a tick's lidars and cameras). In a
        one-robot world that is the room alone (:meth:`Simulation.room_scene`): a sensor
        skips its own robot's parts, so the rays and pixels are the same, and the robot's
        parts need not be placed (in DART, a world transform per part) every time."""
        if self._room_only:
            return self.sim.room_scene()
        if self.physics is None:
            return self.sim.shapes()
        assert self.physics.parts is not None, "a scene is due but the snapshot has no parts"
        return self.sim.shapes(self.physics.parts)

    def finite(self) -> bool:
        return self.sim.is_finite() if self.physics is None else self.physics.finite

    # ------------------------------------------------------------ a tick
    def begin_tick(self, publish: Callable[[], None]) -> float:
        """A new tick: publish its sensors now unless the step will (overlap). Seconds spent."""
        self._published = False
        return 0.0 if self.overlap else self.publish_pending(publish)

    def publish_pending(self, publish: Callable[[], None]) -> float:
        """Publish this tick's sensors if they have not gone out yet (the run ends at a tick
        whose sensors an overlapping step would have published). Seconds spent."""
        if self._published:
            return 0.0
        c0 = time.perf_counter()
        publish()
        self._published = True
        return time.perf_counter() - c0

    def step(self, publish: Callable[[], None]) -> tuple[float, float]:
        """Step to the next tick with the targets the commands set, publishing this tick's
        sensors meanwhile if they are still due. (publish s, physics s not hidden by it)."""
        c0 = time.perf_counter()
        if self.physics is None:                          # (never overlaps: published)
            self.sim.step_tick()
            publish_s = 0.0
        else:
            tick = self.sim.time_ns // self.tick_ns + 1
            self.physics.start_step([r.targets for r in self.sim.robots.values()],
                                    not self._room_only and
                                    any(s.needs_scene(tick) for s in self.sensors.values()))
            publish_s = self.publish_pending(publish)     # while the physics process steps
            self.physics.finish_step()
            self.sim.advance()                            # the clock of the plant's own copy
        return publish_s, time.perf_counter() - c0 - publish_s
