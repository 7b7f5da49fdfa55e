"""The controller contract: what a controller object is, and the values it sees and returns.

A controller is any object with ``step(observation) -> command``; every other hook is
optional and has the default :class:`Controller` lists. The runtime
(:mod:`bus.runtime`) reads the hooks only through the functions below, so the defaults
live in one place.
"""
from __future__ import annotations

import copy
import inspect
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

WHEEL_JOINTS = ("left_wheel_joint", "right_wheel_joint")


@dataclass
class Twist:
    """Body velocity command: forward speed (m/s), yaw rate (rad/s, counter-clockwise)."""
    linear: float = 0.0
    angular: float = 0.0


@dataclass
class WheelSpeeds:
    """Wheel angular velocity command (rad/s, positive drives the robot forward)."""
    left: float = 0.0
    right: float = 0.0


@dataclass
class Observation:
    """What a controller sees at one tick: sim time and the latest message per input."""
    t_ns: int
    robot: str
    msgs: dict[str, Any] = field(default_factory=dict)

    @property
    def t(self) -> float:
        """Simulated time, s."""
        return self.t_ns * 1e-9

    def __getitem__(self, topic: str):
        return self.msgs.get(topic)

    def get(self, topic: str, default=None):
        return self.msgs.get(topic, default)


@runtime_checkable
class Controller(Protocol):
    """Every hook of a controller; only ``step`` is required, the rest default as shown.

    * ``inputs = []`` — topics of its robot it reads (names of :data:`bus.keys.TOPICS`).
    * ``sync = True`` — holds the simulation in lockstep.
    * ``check_inputs = True`` — inputs with non-finite or absurd numbers, or wrong joint
      names, are rejected before it sees them (False: it validates its own).
    * ``done = False`` — set True to stop the robot and exit 0.
    * ``name`` — the node's default name prefix (default: the class name, lower case).
    * ``configure(info, robot)`` — called once with the plant's ``sim/info`` (default: none).
    * ``topics = {}`` — extra bus-wide topics it reads or writes beside its robot's
      (``{"fmu/<instance>/<variable>": bus.keys.Topic}``; messages without a header are
      stamped by their attachment).
    * ``on_session(session, keys)`` — called once with the open Zenoh session, e.g. to
      declare a queryable (default: none). A composed controller gets the plant's
      session: what it subscribes to there comes from other processes, while other
      composed members' outputs reach it only as its inputs.
    * ``stop_command()`` — what stops the robot (default ``Twist(0, 0)``).
    * ``close()`` — called once when the node stops (default: none).
    * ``stats()`` — its own counters, added to the node's ``--stats`` JSON (default: none).
    * ``step(obs)`` returns a :class:`Twist` (``cmd_vel``), :class:`WheelSpeeds`
      (``wheel_cmd``), a dict ``{topic: message}`` of outputs (a Twist or WheelSpeeds value
      in it, under any key, is the command), or None.
    * ``step_many(observations)`` — a controller for many robots: one object drives every
      robot of its node (never copied per robot; a factory is called once, with no
      argument), and each tick the node calls ``step_many({robot: Observation})`` once with
      every robot it still drives instead of ``step`` per robot; it returns ``{robot:
      command}`` (each what ``step`` may return; a robot left out gets nothing that tick).
      ``configure`` is called once per robot, the other hooks once; ``done`` stops them all.
    """

    def step(self, obs: Observation) -> Twist | WheelSpeeds | dict | None: ...


def steps_many(ctrl) -> bool:
    """Whether ``ctrl`` (an object or a factory) drives many robots in one call."""
    return callable(getattr(ctrl, "step_many", None))


def distinct(ctrls) -> list:
    """Each controller object once, in order (a controller for many robots stands in
    several slots: its ``close``, ``stats`` and ``on_session`` run once)."""
    seen: dict[int, Any] = {}
    for ctrl in ctrls:
        seen.setdefault(id(ctrl), ctrl)
    return list(seen.values())


def inputs_of(ctrl) -> list[str]:
    return list(getattr(ctrl, "inputs", ()))


def syncs(ctrl) -> bool:
    return bool(getattr(ctrl, "sync", True))


def checks_inputs(ctrl) -> bool:
    return bool(getattr(ctrl, "check_inputs", True))


def is_done(ctrl) -> bool:
    return bool(getattr(ctrl, "done", False))


def configure(ctrl, info: dict, robot: str) -> None:
    hook = getattr(ctrl, "configure", None)
    if hook is not None:
        hook(info, robot)


def extra_topics(ctrl) -> dict:
    return dict(getattr(ctrl, "topics", {}))


def on_session(ctrl, session, keys) -> None:
    hook = getattr(ctrl, "on_session", None)
    if hook is not None:
        hook(session, keys)


def close(ctrl) -> None:
    """The node stops: let the controller free what it holds (an FMU instance, a thread)."""
    hook = getattr(ctrl, "close", None)
    if callable(hook):
        hook()


def own_stats(ctrl) -> dict:
    """The controller's own counters for the node's ``--stats`` (default: none): entries
    added to the node's JSON, a ``rejected`` dict added to the node's counts."""
    hook = getattr(ctrl, "stats", None)
    return dict(hook()) if callable(hook) else {}


def stop_command(ctrl):
    stop = getattr(ctrl, "stop_command", None)
    return stop() if callable(stop) else Twist(0.0, 0.0)


def default_name(controller) -> str:
    """The node-name prefix of a controller object or factory."""
    return getattr(controller, "name", None) or (
        controller if isinstance(controller, type) else type(controller)).__name__.lower()


def make_controllers(controller, robots: list[str]) -> list:
    """One controller object per robot. ``controller`` is either an object with ``step``
    (one robot: used as it is; several: one deep copy per robot, made before any runs) or
    a factory: a class or callable, called once per robot with the robot name if it takes
    a parameter, else with none. A controller for many robots (``step_many``) is one
    object for all of them: the object itself, or its factory called once with no argument."""
    if steps_many(controller):
        one = controller() if isinstance(controller, type) else controller
        return [one] * len(robots)
    if hasattr(controller, "step") and not isinstance(controller, type):
        if len(robots) == 1:
            return [controller]
        try:
            return [copy.deepcopy(controller) for _ in robots]
        except Exception as exc:
            raise ValueError(f"{type(controller).__name__} cannot drive several robots: it "
                             f"cannot be copied ({exc}); pass a factory instead") from None
    if not callable(controller):
        raise ValueError(f"{controller!r} is neither a controller (an object with step) "
                         "nor a factory of controllers")
    try:
        takes_robot = bool(inspect.signature(controller).parameters)
    except (TypeError, ValueError):
        takes_robot = False
    return [controller(r) if takes_robot else controller() for r in robots]
