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
from .sensors import RobotSensors, Wanted, scan_all
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
                  state: Callable[[str], RobotState], shapes: Callable[[], list],
                  wanted: dict[str, Wanted] | None = None, encoded: bool = False
                  ) -> Iterator[tuple[str, str, object]]:
    """(robot, topic, message) of every sensor due at time ``t_ns``, robot by robot in a
    fixed order (the order the plant publishes them in). ``state(robot)`` gives a robot's
    true state, ``shapes()`` the world's solids (called only when a lidar or camera is due).

    ``wanted`` (robot -> ``wanted(topic)``, the plant's "does anyone read it"): a due topic
    nobody reads comes as ``(robot, topic, None)``, not built (no ray cast, no frame
    rendered) but its noise drawn, so every other value is what it would have been (None:
    every topic is built). ``encoded``: the messages' CDR bytes instead of the messages
    (:meth:`RobotSensors.messages`)."""
    tick = t_ns // tick_ns
    want = wanted or {}
    scene = None
    if any(s.needs_scene(tick, want.get(name)) for name, s in sensors.items()):
        scene = Scene(shapes())
    states = {name: state(name) for name in sensors}
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
