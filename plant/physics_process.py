"""DART in a process of its own: the plant publishes tick k while the physics steps to k + 1.

``diffbot plant --physics-process`` (scenario key ``physics_process``). DART holds the
GIL while it steps, so in one process the physics and the plant's sensors, encoding and
puts take turns on one core; here they run side by side on two. The worker steps and
hands back the bare state of its world: each moving skeleton's positions and velocities
(its generalised coordinates, a few doubles a robot). The plant keeps its own
:class:`~plant.sim.Simulation` of the same world as a *mirror*: it loads those vectors
into its skeletons and reads everything its sensors need (poses, body velocities, wheels,
the parts' poses for a scene) from its own DART world, by the very code that reads it
without a physics process. DART computes a body's transform and velocity from its
skeleton's positions and velocities alone, so the values are the same to the bit
(tests/plant/test_physics_process.py). The reading, which costs more than the vectors, is
the plant's, done while the worker steps, rather than the worker's, done between two
steps.

Hand-over: one shared memory block (a memfd both map) holds the wheel-speed targets of the
next step, written by the plant, and two state slots, written by the worker: the state of
tick k goes into slot k % 2, so the plant reads tick k's while the worker writes k + 1's.
A socket pair carries one byte each way a tick (the request names the slot; the answer
says whether the robots' state is finite) and wakes the side that waits; the rare requests
(build, close) and an error's traceback go as length-framed pickles. The worker exits when
the plant closes the socket, and is killed with the plant (PDEATHSIG).
"""
from __future__ import annotations

import ctypes
import mmap
import os
import signal
import socket
import subprocess
import sys
import traceback
from multiprocessing.connection import Connection

import numpy as np

from .memory import keep_freed_memory
from .sim import Simulation
from .world import WorldSpec

CLOSE_TIMEOUT_S = 5.0
#: one-byte requests and answers on the socket (a step's request is the slot's digit)
BUILD, CLOSE, ERROR, FINITE, DIVERGED, SLOTS = b"b", b"c", b"e", b"1", b"0", (b"0", b"1")


class PhysicsError(RuntimeError):
    """The physics process failed (its traceback is the message) or is gone."""


class Layout:
    """Where a world's state lies in the shared block: the robots' wheel-speed targets
    ((R, 2) doubles), then two slots of every moving skeleton's positions and velocities
    (world order; the room's skeleton has none). The same in the plant and in the worker:
    both build the world from the same spec."""

    def __init__(self, sim: Simulation) -> None:
        world = sim.world
        robots = {r.skeleton.getName() for r in sim.robots.values()}
        self.skeletons = []                   # (world index, offset in a slot, dofs)
        robot_cols, at = [], 0
        for i in range(world.getNumSkeletons()):
            sk = world.getSkeleton(i)
            n = sk.getNumDofs()
            if n == 0:
                continue
            self.skeletons.append((i, at, n))
            if sk.getName() in robots:        # what Simulation.is_finite checks
                robot_cols.extend(range(at, at + 2 * n))
            at += 2 * n
        self.robot_cols = np.array(robot_cols, dtype=np.intp)
        self.n_robots = len(sim.robots)
        self.slot_len = at
        self.nbytes = max(8, 8 * (2 * self.n_robots + 2 * at))

    def key(self) -> tuple:
        return self.n_robots, tuple(self.skeletons)

    def views(self, buf) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """(the targets (R, 2), the two state slots) over the shared block ``buf``."""
        a = np.frombuffer(buf, dtype=np.float64, count=2 * self.n_robots + 2 * self.slot_len)
        t = 2 * self.n_robots
        return (a[:t].reshape(-1, 2),
                (a[t:t + self.slot_len], a[t + self.slot_len:]))


def store_state(sim: Simulation, layout: Layout, slot: np.ndarray) -> bool:
    """``sim``'s moving skeletons' positions and velocities into ``slot``; whether the
    robots' are all finite (:meth:`Simulation.is_finite`'s answer)."""
    world = sim.world
    for i, at, n in layout.skeletons:
        sk = world.getSkeleton(i)
        slot[at:at + n] = sk.getPositions()
        slot[at + n:at + 2 * n] = sk.getVelocities()
    return bool(np.isfinite(slot[layout.robot_cols]).all())


def load_state(sim: Simulation, layout: Layout, slot: np.ndarray) -> None:
    """``slot`` (:func:`store_state`'s) into ``sim``'s skeletons: its world reads as the
    stored one's, every transform and velocity to the bit."""
    world = sim.world
    for i, at, n in layout.skeletons:
        sk = world.getSkeleton(i)
        sk.setPositions(slot[at:at + n])
        sk.setVelocities(slot[at + n:at + 2 * n])


def shared_block(nbytes: int) -> tuple[int, mmap.mmap]:
    """An anonymous shared memory file (its fd, for the worker) and its mapping here."""
    fd = os.memfd_create("diffbot-physics", os.MFD_CLOEXEC)
    try:
        os.ftruncate(fd, nbytes)
        return fd, mmap.mmap(fd, nbytes)
    except BaseException:
        os.close(fd)
        raise


class PhysicsProcess:
    """The plant's handle on its physics process, keeping ``mirror`` (the plant's own
    :class:`Simulation` of the same world) at the worker's state: :meth:`sync`."""

    def __init__(self, spec: WorldSpec, mirror: Simulation) -> None:
        if spec.mode == "kinematic":
            raise ValueError("a kinematic world is stepped in the plant's process: "
                             "no physics process for it")
        self.proc: subprocess.Popen | None = None
        self.conn: Connection | None = None
        self._spawn(Layout(mirror))
        try:
            self.build(spec, mirror)
        except BaseException:
            self.close()
            raise

    def _spawn(self, layout: Layout) -> None:
        mine, theirs = socket.socketpair()
        fd, self._mm = shared_block(layout.nbytes)
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "plant.physics_process", str(theirs.fileno()),
                 str(fd), str(os.getpid())], pass_fds=(theirs.fileno(), fd),
                stdin=subprocess.DEVNULL)
        finally:
            theirs.close()
            os.close(fd)
        self.conn = Connection(mine.detach())
        self._fd = self.conn.fileno()
        self.layout = layout
        self.targets, self.slots = layout.views(self._mm)
        self.pending = False
        self.finite = True
        self._slot = 0                        # the slot of the world's present state
        self._stale = True                    # the mirror is behind it

    def build(self, spec: WorldSpec, mirror: Simulation) -> None:
        """(Re)build the world there at t = 0; ``mirror``: the plant's fresh copy of it,
        kept at the worker's state from now on (a world of other skeletons than the last:
        a new worker)."""
        if self.pending:
            self.finish_step()
        layout = Layout(mirror)
        if layout.key() != self.layout.key():
            self._stop()
            self._spawn(layout)
        self.mirror = mirror
        self._send(BUILD)
        self.conn.send(("build", spec))
        self.finite = self._answer() == FINITE
        self._slot, self._stale = 0, True

    def start_step(self, targets: np.ndarray) -> None:
        """Step one control tick with these (R, 2) wheel speed set-points (robots in
        world-file order), and return at once (:meth:`finish_step` waits for it)."""
        if self.pending:
            raise RuntimeError("a step is under way: finish_step first")
        self.targets[:] = targets
        self._send(SLOTS[1 - self._slot])
        self.pending = True

    def finish_step(self) -> None:
        """Wait for the step started last: the world's state is the new slot's (loaded
        into the mirror by :meth:`sync`), :attr:`finite` whether the robots' is finite."""
        self.pending = False
        answer = self._answer()
        self.finite = answer == FINITE
        self._slot, self._stale = 1 - self._slot, True

    def sync(self) -> None:
        """The mirror at the worker's state of the present tick (once a tick; safe while
        the next step runs: that one writes the other slot)."""
        if self._stale:
            load_state(self.mirror, self.layout, self.slots[self._slot])
            self._stale = False

    def _send(self, request: bytes) -> None:
        try:
            os.write(self._fd, request)
        except OSError as exc:
            raise self._gone(exc) from None

    def _answer(self) -> bytes:
        try:
            got = os.read(self._fd, 1)
            if got == ERROR:
                raise PhysicsError(f"the physics process failed:\n{self.conn.recv()}")
        except (EOFError, OSError) as exc:
            raise self._gone(exc) from None
        if got not in (FINITE, DIVERGED):
            raise self._gone(EOFError("no answer" if not got else f"answered {got!r}"))
        return got

    def _gone(self, exc: BaseException) -> PhysicsError:
        try:
            code = self.proc.wait(1.0)
        except subprocess.TimeoutExpired:
            code = None
        how = ("still running" if code is None else f"killed by signal {-code}" if code < 0
               else f"exit status {code}")
        return PhysicsError(f"the physics process is gone ({how})"
                            + (f": {exc}" if str(exc) else ""))

    def _stop(self) -> None:
        if self.conn is None:
            return
        try:
            os.write(self._fd, CLOSE)
        except OSError:
            pass
        self.conn.close()
        self.conn = None
        try:
            self.proc.wait(CLOSE_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.targets = self.slots = None     # (views of the block: let it go)
        try:
            self._mm.close()
        except BufferError:                  # a view still held elsewhere: goes with it
            pass

    def close(self) -> None:
        """Stop the process (it is waited for; killed if it does not go)."""
        self._stop()


def serve(conn: Connection, block: mmap.mmap) -> int:
    """The worker's loop: build, step and store the state on request until closed."""
    fd = conn.fileno()
    sim: Simulation | None = None
    layout = targets = slots = None
    while True:
        try:
            request = os.read(fd, 1)
        except OSError:
            return 0
        if request in (b"", CLOSE):            # closed, or the plant is gone
            return 0
        try:
            if request == BUILD:
                _, spec = conn.recv()
                sim = Simulation(spec)
                layout = Layout(sim)
                if layout.nbytes > len(block):
                    raise ValueError(f"the world's state needs {layout.nbytes} bytes, the "
                                     f"shared block has {len(block)}")
                targets, slots = layout.views(block)
                answer = store_state(sim, layout, slots[0])
            elif request in SLOTS:
                sim.drive.targets[:] = targets
                sim.step_tick()
                answer = store_state(sim, layout, slots[SLOTS.index(request)])
            else:
                raise ValueError(f"unknown request {request!r}")
            os.write(fd, FINITE if answer else DIVERGED)
        except OSError:                        # the plant went while we answered
            return 0
        except Exception:                      # told to the plant, which raises it
            try:
                os.write(fd, ERROR)
                conn.send(traceback.format_exc())
            except OSError:
                pass
            return 1


def main(argv: list[str]) -> int:
    fd, shm, parent = int(argv[0]), int(argv[1]), int(argv[2])
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # the plant stops us (Ctrl-C hits both)
    try:                                              # die with the plant, even on SIGKILL
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:
        return 0
    keep_freed_memory()
    block = mmap.mmap(shm, os.fstat(shm).st_size)
    os.close(shm)
    return serve(Connection(fd), block)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
