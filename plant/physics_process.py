"""DART in a process of its own: the plant publishes tick k while the physics steps to k + 1.

``diffbot plant --physics-process`` (scenario key ``physics_process``). DART holds the
GIL while it steps, so in one process the physics and the plant's sensors, encoding and
puts take turns on one core; here they run side by side on two. The plant keeps its own
:class:`~plant.sim.Simulation` for everything but stepping (the robots' drive limits,
motion noise and commanded wheel speeds, the world's description) and reads the robots'
states and the parts its sensors see from the snapshot the worker sends after each tick.
The worker runs the same code on the same world, so the motion is the same bit for bit
(tests/plant/test_physics_process.py).

Between the two, a socket pair carries pickles: ``("build", spec)``, ``("step",
wheel_targets, with_parts)``, ``("close",)``; each build and step is answered with a
snapshot ``(state_rows, part_tfs or None, finite)``, or ``("error", text)``. The worker
exits when the plant closes the socket, and is killed with the plant (PDEATHSIG).
"""
from __future__ import annotations

import ctypes
import os
import signal
import socket
import subprocess
import sys
import traceback
from multiprocessing.connection import Connection

import numpy as np

from .memory import keep_freed_memory
from .sim import RobotState, Simulation
from .world import WorldSpec

#: a robot's row in a snapshot: base_link pose (16, row-major 4x4), body linear and
#: angular velocity (3 + 3), wheel angles and speeds (2 + 2)
STATE_COLS = 26
CLOSE_TIMEOUT_S = 5.0


class PhysicsError(RuntimeError):
    """The physics process failed (its traceback is the message) or is gone."""


def snapshot(sim: Simulation, with_parts: bool):
    """(state rows (R, STATE_COLS), part poses (P, 4, 4) or None, all finite) of ``sim``."""
    rows = sim.state_rows()
    # every position and velocity of a robot's skeleton shows in its row (pose, body
    # velocities, wheels), so a finite check of the rows is Simulation.is_finite's, cheaper
    return rows, (sim.part_transforms() if with_parts else None), bool(np.isfinite(rows).all())


def state_from_row(row: np.ndarray) -> RobotState:
    """The :class:`RobotState` a snapshot row holds (what ``Simulation.state`` gave)."""
    tf = row[:16].reshape(4, 4).copy()
    return RobotState(tf, float(np.arctan2(tf[1, 0], tf[0, 0])), row[16:19].copy(),
                      row[19:22].copy(), row[22:24].copy(), row[24:26].copy())


class PhysicsProcess:
    """The plant's handle on its physics process."""

    def __init__(self, spec: WorldSpec) -> None:
        mine, theirs = socket.socketpair()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "plant.physics_process", str(theirs.fileno()),
             str(os.getpid())], pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL)
        theirs.close()
        self.conn = Connection(mine.detach())
        self.pending = False
        self.rows: np.ndarray | None = None
        self.parts: np.ndarray | None = None
        self.finite = True
        try:
            self.build(spec)
        except BaseException:
            self.close()
            raise

    def build(self, spec: WorldSpec) -> None:
        """(Re)build the world there; the snapshot of its start (parts included) follows."""
        if self.pending:
            self.finish_step()
        self._send(("build", spec))
        self._take(self._recv())

    def start_step(self, wheel_targets: list[tuple[float, float]], with_parts: bool) -> None:
        """Step one control tick with these wheel speed set-points (robots in world-file
        order), and return at once; ``with_parts``: send the parts' poses too."""
        self._send(("step", wheel_targets, with_parts))
        self.pending = True

    def finish_step(self) -> None:
        """Wait for the tick started last and take its snapshot."""
        self.pending = False
        self._take(self._recv())

    def state(self, index: int) -> RobotState:
        return state_from_row(self.rows[index])

    def _take(self, snap) -> None:
        self.rows, self.parts, self.finite = snap

    def _send(self, msg) -> None:
        try:
            self.conn.send(msg)
        except OSError as exc:
            raise self._gone(exc) from None

    def _recv(self):
        try:
            msg = self.conn.recv()
        except (EOFError, OSError) as exc:
            raise self._gone(exc) from None
        if len(msg) == 2 and msg[0] == "error":
            raise PhysicsError(f"the physics process failed:\n{msg[1]}")
        return msg

    def _gone(self, exc: BaseException) -> PhysicsError:
        try:
            code = self.proc.wait(1.0)
        except subprocess.TimeoutExpired:
            code = None
        how = ("still running" if code is None else f"killed by signal {-code}" if code < 0
               else f"exit status {code}")
        return PhysicsError(f"the physics process is gone ({how})"
                            + (f": {exc}" if str(exc) else ""))

    def close(self) -> None:
        """Stop the process (it is waited for; killed if it does not go)."""
        try:
            self.conn.send(("close",))
        except OSError:
            pass
        self.conn.close()
        try:
            self.proc.wait(CLOSE_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def serve(conn: Connection) -> int:
    """The worker's loop: build, step and snapshot on request until closed."""
    sim: Simulation | None = None
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return 0                                  # the plant is gone
        try:
            if msg[0] == "close":
                return 0
            if msg[0] == "build":
                sim = Simulation(msg[1])
                conn.send(snapshot(sim, True))
            elif msg[0] == "step":
                _, targets, with_parts = msg
                sim.drive.targets[:] = targets
                sim.step_tick()
                conn.send(snapshot(sim, with_parts))
            else:
                raise ValueError(f"unknown request {msg[0]!r}")
        except OSError:                              # the plant went while we answered
            return 0
        except Exception:                            # told to the plant, which raises it
            try:
                conn.send(("error", traceback.format_exc()))
            except OSError:
                pass
            return 1


def main(argv: list[str]) -> int:
    fd, parent = int(argv[0]), int(argv[1])
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # the plant stops us (Ctrl-C hits both)
    try:                                              # die with the plant, even on SIGKILL
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:
        return 0
    keep_freed_memory()
    return serve(Connection(fd))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
