"""The front half of a tick as arrays: every robot's command through its drive limiter and
its motion noise into its wheel-speed targets, in one kernel call per world
(plant/kernels/drive.c's plant_drive_commands).

A host files each robot's command for the tick (:meth:`WorldDrive.twist`,
:meth:`WorldDrive.wheels_to`; a robot told to stand still is a twist (0, 0); one not
commanded keeps its targets and its limiter as they were), and the step runs them all
(:meth:`WorldDrive.run`, at the tick the commands act from). The model's part is each
robot's limits and motion-noise std (:func:`limits_of`, :func:`motion_std`); the state
(the limiters' v, w and wheel speeds, the commands filed, the targets, the motion noise's
keys) lies in the core's :class:`~plant.core.data.Data` as (worlds, robots, ...) arrays,
and a world's :class:`WorldDrive` is a view of its rows. A :class:`plant.sim.Simulation`
driven directly owns a one-world set until a :class:`plant.tick.Tick` binds its core's.

:func:`reference_commands` is the same in Python, robot by robot
(:class:`plant.drive.DriveLimiter` and the motion noise's normals, as the plant computed
them before the arrays): the oracle the tests compare the kernel with, to the bit.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .. import kernels
from ..drive import DriveLimiter
from ..noise import normals
from ..world import RobotSpec

#: what a robot's command is this tick: none (its targets and limiter as they were), a
#: twist (v m/s, w rad/s), wheel speeds (left, right rad/s)
KEEP, TWIST, WHEELS = 0, 1, 2


def limits_of(robots: Sequence[RobotSpec], dt: float) -> np.ndarray:
    """(R, 8) each robot's drive limits as the kernel reads them: the speed limits (m/s,
    rad/s), the accelerations times the tick ``dt`` (the most v and w change in a tick),
    wheel radius and separation, the wheel speed limit, the wheel acceleration times ``dt``
    (products as :class:`~plant.drive.DriveLimiter` forms them, so the same bits)."""
    rows = [(d.max_linear_mps, d.max_angular_radps, d.max_linear_accel_mps2 * dt,
             d.max_angular_accel_radps2 * dt, d.wheel_radius_m, d.wheel_separation_m,
             d.max_wheel_speed_radps, d.max_wheel_accel_radps2 * dt)
            for d in (r.drive for r in robots)]
    return _frozen(np.array(rows, float).reshape(len(rows), 8))


def motion_std(robots: Sequence[RobotSpec]) -> np.ndarray:
    """(R,) each robot's motion noise std, rad/s on each wheel's target (0: none)."""
    return _frozen(np.array([r.sensors.command_noise_std_radps for r in robots], float))


def state_arrays(worlds: int, robots: int) -> dict[str, np.ndarray]:
    """The front half's state of ``worlds`` worlds of ``robots`` robots, at rest: the
    limiters' ``v``, ``w`` (W, R) and ``wheels`` (W, R, 2), the commands' ``kind`` (W, R)
    and values ``cmd`` (W, R, 2), the ``targets`` (W, R, 2), the motion noise's ``keys``
    (W, R) uint64."""
    W, R = worlds, robots
    return {"v": np.zeros((W, R)), "w": np.zeros((W, R)), "wheels": np.zeros((W, R, 2)),
            "kind": np.zeros((W, R), np.int64), "cmd": np.zeros((W, R, 2)),
            "targets": np.zeros((W, R, 2)), "keys": np.zeros((W, R), np.uint64)}


#: the state a limiter carries from tick to tick (what a world's saved state holds)
LIMITER = ("v", "w", "wheels", "targets")


class WorldDrive:
    """One world's front half: its robots' rows of the state arrays (views, changed in
    place) with the model's ``limits`` and ``std``, and its kernel call (the addresses
    taken once). ``names``: the robots, in the arrays' order."""

    def __init__(self, names: Sequence[str], limits: np.ndarray, std: np.ndarray,
                 rows: dict[str, np.ndarray]) -> None:
        R = len(names)
        self.names = tuple(names)
        self.index = {n: i for i, n in enumerate(self.names)}
        assert limits.shape == (R, 8) and std.shape == (R,)
        self.limits, self.std = limits, std
        self.v, self.w, self.wheels = rows["v"], rows["w"], rows["wheels"]
        self.kind, self.cmd, self.targets = rows["kind"], rows["cmd"], rows["targets"]
        self.keys = rows["keys"]
        self._tick = np.zeros(1, np.int64)
        self._call = kernels.drive_commands_call(
            1, R, self._tick, limits, std, self.keys, self.kind, self.cmd, self.v, self.w,
            self.wheels, self.targets)
        self._filed = False                 # some command filed since the last run
        #: the commands' arrays as flat memoryviews: a value filed costs a third of
        #: numpy's item assignment
        self._kinds = memoryview(self.kind)
        self._cmds = memoryview(self.cmd.reshape(-1))     # (a view: the rows are contiguous)

    @classmethod
    def alone(cls, robots: Sequence[RobotSpec], dt: float) -> "WorldDrive":
        """A world's front half with arrays of its own (a Simulation not in a core)."""
        rows = {k: a[0] for k, a in state_arrays(1, len(robots)).items()}
        return cls([r.name for r in robots], limits_of(robots, dt), motion_std(robots), rows)

    # ------------------------------------------------------------ a tick's commands
    def twist(self, i: int, v: float, w: float) -> None:
        """Robot ``i``'s command this tick: the body speeds (v m/s, w rad/s)."""
        self._kinds[i] = TWIST
        self._cmds[2 * i], self._cmds[2 * i + 1] = float(v), float(w)
        self._filed = True

    def twists(self, rows: np.ndarray, values: np.ndarray) -> None:
        """:meth:`twist` of ``values[j]`` (v, w) for each robot ``rows[j]``, in one
        assignment per array."""
        self.kind[rows] = TWIST
        self.cmd[rows] = values
        self._filed = True

    def wheels_to(self, i: int, left: float, right: float) -> None:
        """Robot ``i``'s command this tick: the wheel speeds (rad/s)."""
        self._kinds[i] = WHEELS
        self._cmds[2 * i], self._cmds[2 * i + 1] = float(left), float(right)
        self._filed = True

    def run(self, tick: int) -> np.ndarray:
        """The commands filed, through the limiters and the motion noise of ``tick`` (the
        tick they act from), into the targets (returned: (R, 2), the arrays' own) in one
        kernel call; nothing filed, nothing changes."""
        if self._filed:
            self._tick[0] = tick
            self._call()
            self._filed = False
        return self.targets

    # ------------------------------------------------------------ state
    def reset(self) -> None:
        """Every limiter at rest, the targets zero, no command filed."""
        for a in (self.v, self.w, self.wheels, self.kind, self.cmd, self.targets):
            a[...] = 0
        self._filed = False

    def load(self, other: "WorldDrive") -> None:
        """``other``'s state (the same robots) into these arrays: the limiters, targets,
        keys and the commands filed."""
        assert other.names == self.names
        for k in LIMITER + ("kind", "cmd", "keys"):
            getattr(self, k)[...] = getattr(other, k)
        self._filed = other._filed

    def limiter(self, i: int) -> tuple[float, float, tuple[float, float]]:
        """Robot ``i``'s limiter: (v, w, (left, right)) it ramps from."""
        return float(self.v[i]), float(self.w[i]), tuple(self.wheels[i].tolist())

    def set_limiter(self, i: int, v: float, w: float, wheels) -> None:
        self.v[i], self.w[i] = v, w
        self.wheels[i] = wheels


def world_drive(model, data, w: int) -> WorldDrive:
    """World ``w``'s front half in ``data`` (made the first time)."""
    got = data.drives[w]
    if got is None:
        got = data.drives[w] = WorldDrive(model.robots, model.drive_limits, model.motion_std,
                                          {k: a[w] for k, a in data.drive.items()})
    return got


def reference_commands(limiters: Sequence[DriveLimiter], kind: np.ndarray, cmd: np.ndarray,
                       std: np.ndarray, keys: np.ndarray, tick: int, dt: float,
                       targets: np.ndarray) -> None:
    """:meth:`WorldDrive.run` robot by robot in Python, the oracle: each commanded robot's
    limiter (``limiters[i]``: :meth:`~plant.drive.DriveLimiter.from_twist` or
    :meth:`~plant.drive.DriveLimiter.from_wheels` of ``cmd[i]`` over ``dt``), then its
    motion noise: ``std[i]`` times the two normals of ``keys[i]`` at ``tick`` added, unless
    the wheels are (0, 0); into ``targets[i]``. ``kind`` is zeroed."""
    for i, lim in enumerate(limiters):
        k = int(kind[i])
        if k == KEEP:
            continue
        a, b = float(cmd[i, 0]), float(cmd[i, 1])
        wheels = lim.from_twist(a, b, dt) if k == TWIST else lim.from_wheels(a, b, dt)
        s = float(std[i])
        if s > 0.0 and wheels != (0.0, 0.0):
            n = normals(keys[i:i + 1], tick, 2)[0] * s
            wheels = (wheels[0] + n[0], wheels[1] + n[1])
        targets[i] = wheels
        kind[i] = KEEP


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a
