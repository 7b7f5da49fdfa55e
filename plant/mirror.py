"""The plant's reading of its mirror world: the robots' state rows from the worker's state.

With a physics process (:mod:`plant.physics_process`) the plant keeps its own DART world
loaded with the worker's positions and velocities, and reads from it what its sensors need
when the worker did not. Those positions and velocities are in the shared slot already, so
the rows take the wheels' angles and speeds straight from it (the doubles DART would hand
back: it stores what ``setPositions``/``setVelocities`` were given) and ask DART only for
what it computes: each chassis' world transform and spatial velocity, two calls a robot
instead of four, gathered in one list each. The rows equal :meth:`Simulation.state_rows`'
to the bit (tests/plant/test_physics_process.py).
"""
from __future__ import annotations

import numpy as np

from .sim import Simulation, chassis_rows


class Mirror:
    """``sim`` as the plant's mirror of the worker's world: the skeletons' positions and
    velocities come from ``states`` (the two slots' state vectors, laid out as ``skeletons``
    says: (world index, offset in a slot, dofs) per moving skeleton: ``Layout.skeletons``),
    loaded on demand (:meth:`load`), and its robots' state rows read
    (:meth:`Simulation.state_rows`' layout, :meth:`rows`)."""

    def __init__(self, sim: Simulation, skeletons: list[tuple[int, int, int]],
                 states: list[np.ndarray]) -> None:
        at = {i: (offset, n) for i, offset, n in skeletons}
        world = sim.world
        # each slot's (skeleton, positions, velocities): views made once, not a tick
        self._loads = [[(world.getSkeleton(i), s[a:a + n], s[a + n:a + 2 * n])
                        for i, a, n in skeletons] for s in states]
        self._states = states
        index = {world.getSkeleton(i).getName(): i for i in at}
        self._chassis = [r.chassis for r in sim.robots.values()]
        pos, vel = [], []
        for r, wheels in zip(sim.robots.values(), sim._wheel_dofs):
            offset, n = at[index[r.skeleton.getName()]]
            dofs = np.arange(n)[wheels]
            pos.append(offset + dofs)
            vel.append(offset + n + dofs)
        self._pos = np.array(pos, dtype=np.intp).reshape(-1, 2)
        self._vel = np.array(vel, dtype=np.intp).reshape(-1, 2)

    def load(self, slot: int) -> None:
        """Slot ``slot``'s state into the skeletons: the world reads as the worker's did,
        every transform and velocity to the bit."""
        for sk, q, dq in self._loads[slot]:
            sk.setPositions(q)
            sk.setVelocities(dq)

    def rows(self, slot: int) -> np.ndarray:
        """The (R, 26) rows of the world now, slot ``slot`` loaded (:meth:`load`)."""
        state = self._states[slot]
        rows = chassis_rows(self._chassis)          # (as Simulation.read_state reads them)
        rows[:, 22:24], rows[:, 24:26] = state[self._pos], state[self._vel]
        return rows
