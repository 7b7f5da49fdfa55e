"""What the plant does at one control tick, without a bus: shared by the plant node
(:mod:`plant.node`) and the in-process Gymnasium environments (:mod:`diffbot.envs`), so
both produce the same messages, bit for bit, from the same seed and commands.

A lockstep plant's tick k (sequential coupling) is::

    msgs = tick_messages(sim, sensors, ...)    # sensors due at t_k, noise drawn in order
    ... publish msgs, then sim/clock; wait for the members' commands stamped t_k ...
    sim.command_twist(robot, v, w)             # for every robot (zero if it has none)
    sim.step_tick()                            # to t_{k+1}

Anything that changes the order in which the noise streams are drawn, the sensors due at
a tick, or a message's values changes both sides at once; ``tests/test_envs_identity.py``
checks that the two transports still agree to the bit.
"""
from __future__ import annotations

from typing import Callable, Iterator

from .raycast import Scene
from .sensors import RobotSensors, scan_all
from .sim import RobotState, Simulation
from .world import WorldSpec


def build_world(spec: WorldSpec, seed: int, disabled=()) -> tuple[Simulation, dict[str, RobotSensors]]:
    """A fresh world and its robots' sensors (noise streams seeded from ``seed``), with the
    sensors named in ``disabled`` ("lidar", "camera") taken off every robot."""
    for r in spec.robots:
        if "lidar" in disabled:
            r.sensors.lidar = None
        if "camera" in disabled:
            r.sensors.camera = None
    sim = Simulation(spec)
    sensors = {r.name: RobotSensors(r, spec.control_tick_s, seed) for r in spec.robots}
    return sim, sensors


def tick_messages(t_ns: int, tick_ns: int, sensors: dict[str, RobotSensors],
                  state: Callable[[str], RobotState], shapes: Callable[[], list]
                  ) -> Iterator[tuple[str, str, object]]:
    """(robot, topic, message) of every sensor due at time ``t_ns``, robot by robot in a
    fixed order (the order the plant publishes them in). ``state(robot)`` gives a robot's
    true state, ``shapes()`` the world's solids (called only when a lidar or camera is due)."""
    tick = t_ns // tick_ns
    scene = None
    if any(s.needs_scene(tick) for s in sensors.values()):
        scene = Scene(shapes())
    states = {name: state(name) for name in sensors}
    scans = scan_all(sensors, states, tick, scene) if scene is not None else {}
    for name, s in sensors.items():
        for topic, msg in s.messages(tick, t_ns, states[name], scene, scans.get(name)):
            yield name, topic, msg
