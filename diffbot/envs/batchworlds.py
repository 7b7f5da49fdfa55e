"""The worlds of a batch ticked as arrays (:mod:`diffbot.envs.kinbatch`), as their steppers
hold them: a kinematic batch's arrays (:mod:`plant.kinematic`: one call steps every robot),
or each world's DART (stepped world by world, read back as arrays)."""
from __future__ import annotations

import numpy as np

from bus.codec import yaw_of
from plant import kinematic
from plant.sim import rotation_to_quaternion

from .obsmath import truths


class Diverged(Exception):
    """Worlds (their indices in a step) no longer finite."""

    def __init__(self, worlds: list[int]) -> None:
        super().__init__(worlds)
        self.worlds = worlds


class Kinematic:
    """The worlds' robots as the kinematic batch's arrays (:mod:`plant.kinematic`): one
    call steps them all."""

    def __init__(self, sims: list) -> None:
        kins = list({id(s.kin): s.kin for s in sims}.values())    # (a world's rows: one)
        self.batch = kinematic.join(kins) if len(kins) > 1 else kins[0]

    def transforms(self, idx: np.ndarray) -> np.ndarray:
        return self.batch.transforms()[idx]

    def finish(self) -> None:
        """The step's end: a world no longer finite is an error (the worlds' clocks move
        when their state is written back: :meth:`ArrayTicks.flush`)."""
        b = self.batch
        if not b.finite():              # (not a number stays one: checked once a step)
            raise Diverged(np.flatnonzero(~(np.isfinite(b.pose).all(1)
                                            & np.isfinite(b.wheels).all(1))).tolist())

    def truth(self) -> np.ndarray:
        return truths(self.batch.pose)


class Dart:
    """The worlds' robots in their DART worlds, stepped world by world
    (:meth:`plant.tick.Tick.step`, as the message path steps them), read back as arrays:
    wheel angles each tick, poses where a lidar is due and at the step's end."""

    def __init__(self, sims: list, names: list[str]) -> None:
        self.sims = sims
        self.robots = [s.robots[n] for s, n in zip(sims, names)]
        self._targets = [s.drive.targets[s.drive.index[n]] for s, n in zip(sims, names)]
        self._tfs: dict[int, np.ndarray] = {}    # the robots' poses since the last tick
        self._worlds = list({id(s): s for s in sims}.values())   # (a world's rows: one)

    def step(self, targets: np.ndarray) -> None:
        """One tick of every world (:meth:`plant.tick.Tick.step` without its check, which
        :meth:`finish` makes once a step: not a number stays one)."""
        self._tfs.clear()
        for mine, row in zip(self._targets, targets):
            mine[:] = row                            # as Simulation.command_twist sets them
        for sim in self._worlds:
            sim.step_tick()

    def _tf(self, j: int) -> np.ndarray:
        """Robot j's base -> world, asked of DART once a tick (the lidar's and the truth's
        at a step's last tick: ~10 us each)."""
        tf = self._tfs.get(j)
        if tf is None:
            tf = self._tfs[j] = self.robots[j].transform()
        return tf

    def read_wheels(self, out: np.ndarray) -> None:
        """The wheel angles (W, 2) into ``out``."""
        for j, r in enumerate(self.robots):
            out[j, 0], out[j, 1] = r.wheels[0].getPosition(0), r.wheels[1].getPosition(0)

    def transforms(self, idx: np.ndarray) -> np.ndarray:
        return np.array([self._tf(j) for j in idx.tolist()])

    def finish(self) -> None:
        bad = [j for j, sim in enumerate(self.sims) if not sim.is_finite()]
        if bad:
            raise Diverged(bad)

    def truth(self) -> np.ndarray:
        """As the ``ground_truth`` message read back gives it (codec.pose_2d)."""
        out = np.empty((len(self.robots), 3))
        for j in range(len(self.robots)):
            tf = self._tf(j)
            qx, qy, qz, qw = rotation_to_quaternion(tf[:3, :3])
            out[j] = (float(tf[0, 3]), float(tf[1, 3]), yaw_of(qx, qy, qz, qw))
        return out


