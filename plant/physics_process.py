"""DART in a process of its own: the plant publishes tick k while the physics steps to k + 1.

``diffbot plant --physics-process`` (scenario key ``physics_process``). DART holds the
GIL while it steps, so in one process the physics and the plant's sensors, encoding and
puts take turns on one core; here they run side by side on two. The worker steps and
hands back the bare state of its world: each moving skeleton's positions and velocities
(its generalised coordinates, a few doubles a robot). The plant keeps its own
:class:`~plant.sim.Simulation` of the same world as a *mirror*: it can load those vectors
into its skeletons and read what its sensors need (every robot's state row, the parts'
poses for a scene) from its own DART world (:class:`plant.mirror.Mirror`: the wheels'
values straight from the slot, the chassis' by the DART calls
:meth:`Simulation.read_state` makes). DART computes a body's transform and velocity from
its skeleton's positions and velocities alone, so the values are the same to the bit
(tests/plant/test_physics_process.py).

Who reads them is decided tick by tick, by who would otherwise wait: the plant raises a
flag in the shared block while it waits for the step. A worker that finds the flag down
when its step is done (the plant still publishing) reads the rows (and the parts' poses,
if the plant asked for them) itself and leaves them beside the state; one that finds it
up (the plant idle, the physics the slower side) answers at once and the plant reads its
mirror, its work overlapping the next step. Either way the values are the same.

Hand-over: one shared memory block (a memfd both map) holds the wheel-speed targets of the
next step, written by the plant, the flag, the worker's CPU seconds so far (written after
each step: what its steps cost, beside DART's alone), and two slots (state, rows, parts)
written by the worker: tick k's go into slot k % 2, so the plant reads tick k's while the
worker writes k + 1's. A socket pair carries one byte each way a tick (the request names the slot
and whether a scene is due; the answer, whether the robots' state is finite and whether the
rows were read) and wakes the side that waits; the rare requests (build, close) and an
error's traceback go as length-framed pickles. The worker exits when the plant closes the
socket, and is killed with the plant (PDEATHSIG).
"""
from __future__ import annotations

import ctypes
import mmap
import os
import signal
import socket
import subprocess
import sys
import time
import traceback
from multiprocessing.connection import Connection

import numpy as np

from .memory import keep_freed_memory
from .mirror import Mirror
from .sim import STATE_COLS, RobotState, Simulation
from .world import WorldSpec

CLOSE_TIMEOUT_S = 5.0
#: one-byte requests and answers on the socket besides a step's (:func:`_step_request`,
#: :func:`_answer_byte`)
BUILD, CLOSE, ERROR = b"b", b"c", b"e"
#: the plant's flag: up (1) while it waits for the step: then the worker leaves the reading
#: to it; ALWAYS_* hold it down or up for good (tests, or to measure one side)
ADAPTIVE, ALWAYS_WORKER, ALWAYS_PLANT = None, False, True


def _step_request(slot: int, parts: bool) -> bytes:
    """Step into ``slot`` (0, 1); ``parts``: a scene is due there."""
    return bytes((48 + slot + 2 * parts,))


def _answer_byte(finite: bool, read: bool) -> bytes:
    """The robots' state finite; ``read``: the rows (and parts) read by the worker."""
    return bytes((48 + finite + 2 * read,))


class PhysicsError(RuntimeError):
    """The physics process failed (its traceback is the message) or is gone."""


class Layout:
    """Where a world's state lies in the shared block: the robots' wheel-speed targets
    ((R, 2) doubles), the plant's flag, the worker's CPU seconds, then two slots, each of
    every moving skeleton's positions and velocities (world order; the room's skeleton has
    none), the robots' state rows (R, 26) and the parts' poses (P, 4, 4). The same in the plant and in the
    worker: both build the world from the same spec."""

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
        self.n_parts = len(sim.part_transforms())
        self.state_len = at
        self.slot_len = at + STATE_COLS * self.n_robots + 16 * self.n_parts
        self.n_doubles = 2 * self.n_robots + 2 + 2 * self.slot_len
        self.nbytes = 8 * self.n_doubles

    def key(self) -> tuple:
        return self.n_robots, self.n_parts, tuple(self.skeletons)

    def views(self, buf) -> tuple[np.ndarray, np.ndarray, tuple]:
        """(the targets (R, 2), the flag and the worker's CPU seconds (2,), the two slots)
        over the shared block ``buf``; a slot: (state, rows (R, 26), parts (P, 4, 4))."""
        a = np.frombuffer(buf, dtype=np.float64, count=self.n_doubles)
        t = 2 * self.n_robots
        slots, at = [], t + 2
        for _ in range(2):
            state = a[at:at + self.state_len]
            rows = a[at + self.state_len:at + self.state_len + STATE_COLS * self.n_robots]
            parts = a[at + self.state_len + rows.size:at + self.slot_len]
            slots.append((state, rows.reshape(-1, STATE_COLS), parts.reshape(-1, 4, 4)))
            at += self.slot_len
        return a[:t].reshape(-1, 2), a[t:t + 2], tuple(slots)


def store_state(sim: Simulation, layout: Layout, slot: np.ndarray) -> bool:
    """``sim``'s moving skeletons' positions and velocities into ``slot``; whether the
    robots' are all finite (:meth:`Simulation.is_finite`'s answer)."""
    world, got = sim.world, []
    for i, _, _ in layout.skeletons:
        sk = world.getSkeleton(i)
        got += (sk.getPositions(), sk.getVelocities())
    if got:                                   # (one copy: a third less than one a vector)
        slot[:layout.state_len] = np.concatenate(got)
    return bool(np.isfinite(slot[layout.robot_cols]).all())


def shared_block(nbytes: int) -> tuple[int, mmap.mmap]:
    """An anonymous shared memory file (its fd, for the worker) and its mapping here."""
    fd = os.memfd_create("diffbot-physics", os.MFD_CLOEXEC)
    try:
        os.ftruncate(fd, nbytes)
        return fd, mmap.mmap(fd, nbytes)
    except BaseException:
        os.close(fd)
        raise


#: the environment variable that keeps the worker and the plant's thread on cores of their
#: own (:func:`split_cpus`); off by default
PIN_ENV = "DIFFBOT_PIN_PHYSICS"


def split_cpus() -> tuple[set[int], set[int]] | None:
    """(the plant's CPUs, the worker's) when ``DIFFBOT_PIN_PHYSICS=1`` is set: the CPUs this
    thread may run on, one (not the one it runs on now) for the worker and the rest for the
    plant's thread; None unset or with fewer than two. When every core is busy, a woken
    process tends to be queued on its waker's core: the worker, woken by the plant, took the
    plant's core and the two took turns (the plant's thread waited ~0.35 ms a control tick
    in the run queue in a composed square on a loaded 2-core machine, against ~0.05 ms
    without a physics process). Kept apart, each waits only for others' work. It is a
    choice for one run on a machine of its own: a process cannot see where other runs put
    theirs, so runs side by side (a sweep, parallel tests) could all pin their workers to
    the same core."""
    if os.environ.get(PIN_ENV, "") != "1":
        return None
    try:
        allowed = os.sched_getaffinity(0)
        with open("/proc/thread-self/stat") as f:          # field 39: the CPU it ran on
            here = int(f.read().rsplit(")", 1)[1].split()[36])
    except (AttributeError, OSError, ValueError, IndexError):
        return None
    if len(allowed) < 2:
        return None
    worker = max(c for c in allowed if c != here)
    return allowed - {worker}, {worker}


class PhysicsProcess:
    """The plant's handle on its physics process. The world's present state reads through
    :meth:`rows`, :meth:`state` and :meth:`parts`: the worker's reading if it made one,
    else ``mirror`` (the plant's own :class:`Simulation` of the same world) loaded with the
    worker's state (:meth:`sync`) and read. ``reader``: :data:`ADAPTIVE` (who reads is who
    would otherwise wait), :data:`ALWAYS_WORKER` or :data:`ALWAYS_PLANT`."""

    def __init__(self, spec: WorldSpec, mirror: Simulation, reader: bool | None = ADAPTIVE
                 ) -> None:
        self.reader = reader
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
        cpus = split_cpus()
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "plant.physics_process", str(theirs.fileno()),
                 str(fd), str(os.getpid()),
                 ",".join(map(str, sorted(cpus[1]))) if cpus else "-"],
                pass_fds=(theirs.fileno(), fd), stdin=subprocess.DEVNULL)
        finally:
            theirs.close()
            os.close(fd)
        #: this thread's CPUs before it was kept off the worker's (given back at close)
        self._cpus = None
        if cpus is not None:
            try:
                self._cpus = os.sched_getaffinity(0)
                os.sched_setaffinity(0, cpus[0])
            except OSError:
                self._cpus = None
        self.conn = Connection(mine.detach())
        self._fd = self.conn.fileno()
        self.layout = layout
        self.targets, self.flag, self.slots = layout.views(self._mm)
        self.flag[0] = 1.0 if self.reader is ALWAYS_PLANT else 0.0
        self.pending = False
        self.finite = True
        self._slot = 0                        # the slot of the world's present state
        self._stale = True                    # the mirror is behind it
        #: whether the worker read the present tick's rows (and the parts' poses, if asked)
        self.read_by_worker = self._with_parts = self._asked = False

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
        self.mirror_index = {name: i for i, name in enumerate(mirror.robots)}
        self.mirror_reads = Mirror(mirror, self.layout.skeletons,
                                   [slot[0] for slot in self.slots])
        self._send(BUILD)
        self.conn.send(("build", spec))
        self._slot, self._stale = 0, True
        self.finite, self.read_by_worker = self._answer()
        self._with_parts = self.read_by_worker

    def start_step(self, targets: np.ndarray, with_parts: bool = False) -> None:
        """Step one control tick with these (R, 2) wheel speed set-points (robots in
        world-file order), and return at once (:meth:`finish_step` waits for it);
        ``with_parts``: a scene is due at the next tick (the worker, if it reads, reads
        the parts' poses too)."""
        if self.pending:
            raise RuntimeError("a step is under way: finish_step first")
        self.targets[:] = targets
        self._send(_step_request(1 - self._slot, with_parts))
        self.pending, self._asked = True, with_parts

    def finish_step(self) -> None:
        """Wait for the step started last (the flag up meanwhile, where adaptive): the
        world's state is the new slot's, :attr:`finite` whether the robots' is finite."""
        self.pending = False
        if self.reader is ADAPTIVE:
            self.flag[0] = 1.0
            try:
                self.finite, self.read_by_worker = self._answer()
            finally:
                self.flag[0] = 0.0
        else:
            self.finite, self.read_by_worker = self._answer()
        self._slot, self._stale, self._with_parts = 1 - self._slot, True, self._asked

    def sync(self) -> None:
        """The mirror at the worker's state of the present tick (once a tick; safe while
        the next step runs: that one writes the other slot)."""
        if self._stale:
            self.mirror_reads.load(self._slot)
            self._stale = False

    def rows(self) -> np.ndarray:
        """Every robot's state row now (:meth:`Simulation.state_rows`)."""
        if self.read_by_worker:
            return self.slots[self._slot][1].copy()
        self.sync()
        return self.mirror_reads.rows(self._slot)

    def state(self, robot: str):
        """``robot``'s :class:`~plant.sim.RobotState` now (:meth:`Simulation.state`)."""
        if self.read_by_worker:
            return state_from_row(self.slots[self._slot][1][self.mirror_index[robot]])
        self.sync()
        return self.mirror.state(robot)

    def parts(self) -> np.ndarray:
        """The robots' parts' poses now (:meth:`Simulation.part_transforms`)."""
        if self.read_by_worker and self._with_parts:
            return self.slots[self._slot][2].copy()
        self.sync()
        return self.mirror.part_transforms()

    def cpu_s(self) -> float | None:
        """The worker's CPU seconds (user + system, its own clock) as of its last answer,
        None once closed: what its steps cost, beside DART's alone, however loaded the
        machine (the wall clock is not)."""
        return None if self.flag is None else float(self.flag[1])

    def _send(self, request: bytes) -> None:
        try:
            os.write(self._fd, request)
        except OSError as exc:
            raise self._gone(exc) from None

    def _answer(self) -> tuple[bool, bool]:
        """(finite, read by the worker) of the answer to the last request."""
        try:
            got = os.read(self._fd, 1)
            if got == ERROR:
                raise PhysicsError(f"the physics process failed:\n{self.conn.recv()}")
        except (EOFError, OSError) as exc:
            raise self._gone(exc) from None
        if len(got) != 1 or got not in b"0123":
            raise self._gone(EOFError("no answer" if not got else f"answered {got!r}"))
        code = got[0] - ord("0")
        return bool(code & 1), bool(code & 2)

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
        # (views of the block: let go)
        self.targets = self.flag = self.slots = self.mirror_reads = None
        if self._cpus is not None:
            try:
                os.sched_setaffinity(0, self._cpus)
            except OSError:
                pass
            self._cpus = None
        try:
            self._mm.close()
        except BufferError:                  # a view still held elsewhere: goes with it
            pass

    def close(self) -> None:
        """Stop the process (it is waited for; killed if it does not go)."""
        self._stop()


def state_from_row(row: np.ndarray) -> RobotState:
    """The :class:`RobotState` a state row holds (what ``Simulation.state`` gives)."""
    tf = row[:16].reshape(4, 4).copy()
    return RobotState(tf, float(np.arctan2(tf[1, 0], tf[0, 0])), row[16:19].copy(),
                      row[19:22].copy(), row[22:24].copy(), row[24:26].copy())


def read_into(sim: Simulation, slot: tuple, with_parts: bool) -> None:
    """The worker's reading of its world into ``slot``: the rows, and the parts' poses."""
    slot[1][:] = sim.state_rows()
    if with_parts:
        slot[2][:] = sim.part_transforms()


def serve(conn: Connection, block: mmap.mmap) -> int:
    """The worker's loop: build, step and store the state on request until closed (and
    read the rows where the plant is not waiting: its flag down)."""
    fd = conn.fileno()
    sim: Simulation | None = None
    layout = targets = flag = slots = None
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
                targets, flag, slots = layout.views(block)
                finite = store_state(sim, layout, slots[0][0])
                flag[1] = time.process_time()
                read = not flag[0]
                if read:
                    read_into(sim, slots[0], True)
            elif len(request) == 1 and request in b"0123":
                code = request[0] - ord("0")
                slot = slots[code & 1]
                sim.drive.targets[:] = targets
                sim.step_tick()
                finite = store_state(sim, layout, slot[0])
                read = not flag[0]            # the plant busy yet: the reading is ours
                if read:
                    read_into(sim, slot, bool(code & 2))
                flag[1] = time.process_time()
            else:
                raise ValueError(f"unknown request {request!r}")
            os.write(fd, _answer_byte(finite, read))
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
    if argv[3] != "-":                                # a core of our own (split_cpus)
        try:
            os.sched_setaffinity(0, {int(c) for c in argv[3].split(",")})
        except OSError:
            pass
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
