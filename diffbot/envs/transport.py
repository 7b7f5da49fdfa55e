"""The two ways an environment runs the plant: in its own process, or over the bus.

Both offer the same three calls, and give the same messages to the bit:

* ``reset(seed, poses, observe)``: rebuild the world with that noise seed and start
  poses; ``observe(0, msgs)`` gets tick 0's messages;
* ``advance(n, command, observe, constant=False)``: n control ticks; at each tick t
  ``command(t, msgs)`` gives every robot's ``(v, w)``, the world steps, and
  ``observe(t + tick, msgs)`` gets the new tick's messages; ``constant``: the command is
  the same at every one of the n ticks (asked once: over the bus the member answers the
  first tick and holds the others, docs/PROTOCOL.md section 4, "Holding");
* ``close()``.

``msgs`` is ``{robot: {topic: latest message}}``, the latest sample of each topic stamped at
or before the tick (what a bus node's observation holds).

:class:`InProc` runs :mod:`plant.tick` directly. :class:`Bus` is a lockstep member of a
plant (one it starts on a private unix socket, or one at ``endpoint``) under sequential
coupling: the commands of tick t act at once, as in-process. See docs/learning.md.
"""
from __future__ import annotations

import itertools
import json
import logging
import os
import re
import shutil
import tempfile
import threading
import time
import weakref
from typing import Callable

from bus.keys import Keys
from bus.node import NodeRunner, Twist
from bus.protocol import info_max_hold
from bus.session import close_session, open_when_listening, zenoh_error
from plant.tick import Tick
from plant.world import WorldSpec

Command = Callable[[int, dict], dict]
Observe = Callable[[int, dict], None]

#: wall seconds the environment waits for the plant before it gives up
PLANT_TIMEOUT_S = 60.0

#: the names Zenoh's runtime gives its threads (it keeps them after its sessions close)
_ZENOH_THREAD = re.compile(r"(app|net|acc|rx|tx)-\d+$")
_fork = {"parent_ran_zenoh": False, "child": False}


def _zenoh_runtime_here() -> bool:
    """Whether this process runs Zenoh's runtime (its threads, by name, in /proc)."""
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return False
    for t in tasks:
        try:
            with open(f"/proc/self/task/{t}/comm") as f:
                if _ZENOH_THREAD.match(f.read().strip()):
                    return True
        except OSError:
            continue
    return False


def _before_fork() -> None:
    _fork["parent_ran_zenoh"] = _zenoh_runtime_here()


def _in_forked_child() -> None:
    _fork["child"] = _fork["parent_ran_zenoh"]


# A process forked from one that ran Zenoh (a bus environment used before make_vec's
# "async" workers, forked by default on Linux) inherits a runtime whose threads are gone:
# its first session hangs for good. Such a worker refuses to start instead (Bus._start).
os.register_at_fork(before=_before_fork, after_in_child=_in_forked_child)
FORKED_WORKER = ("this process was forked from one that runs Zenoh (a bus environment was "
                 "used in it before), and a forked Zenoh runtime hangs: start the workers "
                 "with the spawn context, gymnasium.make_vec(..., vectorization_mode=\"async\", "
                 "vector_kwargs={\"context\": \"spawn\"}) (docs/learning.md)")


class TransportError(RuntimeError):
    """The plant went away or did not answer."""


class InProc:
    """The plant's tick (:class:`plant.tick.Tick`) in this process (no Zenoh)."""

    def __init__(self, spec: WorldSpec, disabled: tuple[str, ...] = (),
                 inputs: dict[str, list[str]] | None = None) -> None:
        self.spec = spec
        self.disabled = tuple(disabled)
        self.tick_ns = spec.tick_ns
        self.tick: Tick | None = None
        # only what the env reads is built (a plant builds only what someone subscribes
        # to); a value's noise is a function of its tick, so every value is the same
        # (plant/noise.py)
        self.wanted = None if inputs is None else {
            r.name: frozenset(inputs.get(r.name, ())).__contains__ for r in spec.robots}

    @property
    def sim(self):
        return self.tick.sim if self.tick is not None else None

    def reset(self, seed: int, poses: dict, observe: Observe) -> None:
        # as the plant's sim/reset: the seed and poses are kept in the spec, the world rebuilt
        if self.tick is None:
            self.tick = Tick(self.spec, self.disabled)
        self.tick.reset(seed, poses)
        self._publish()
        observe(0, self.latest)

    def _publish(self) -> None:
        self.take(self.tick.messages(self.wanted))

    def take(self, messages) -> None:
        """File the tick's (robot, topic, message) as the latest of each topic (a new
        world at t = 0 starts empty)."""
        if self.tick.t_ns == 0:
            self.latest: dict[str, dict] = {name: {} for name in self.tick.sensors}
        for name, topic, msg in messages:
            if msg is not None:                  # (None: a topic the env does not read)
                self.latest[name][topic] = msg

    def advance(self, n: int, command: Command, observe: Observe,
                constant: bool = False) -> None:
        tick = self.tick
        cmds = None
        for _ in range(n):
            if cmds is None or not constant:
                cmds = command(tick.t_ns, self.latest)
            for name in tick.sim.robots:     # every robot, every tick, as the plant does
                v, w = cmds.get(name, (0.0, 0.0))
                tick.drive(name, Twist(v, w))
            tick.step()                      # (a diverged world is rebuilt, as the plant's)
            self._publish()
            observe(tick.t_ns, self.latest)

    def close(self) -> None:
        self.tick = None


# ------------------------------------------------------------------------------ bus
class _Job:
    """n ticks for the member thread: answer the tick it holds with ``command``, then
    for each new tick ``observe`` it and (but after the last) answer it."""

    def __init__(self, n: int, command: Command, observe: Observe,
                 new_world: bool = False, constant: bool = False) -> None:
        self.n, self.command, self.observe = n, command, observe
        self.new_world = new_world       # the world was reset since the member's last answer
        self.constant = constant         # one command for all n ticks: answered once, held
        self.done = threading.Event()
        self.t_end: int | None = None
        self.error: BaseException | None = None


def _zero(t_ns: int, msgs: dict) -> dict:
    return {}


def _ignore(t_ns: int, msgs: dict) -> None:
    pass


class _Inputs:
    """A robot's slot in the member: only what it reads (the member acts for all)."""
    check_inputs = False     # the environment sees exactly what the plant sent

    def __init__(self, inputs) -> None:
        self.inputs = list(inputs)

    def step(self, obs):     # not called: _Member._act answers for every robot
        return None


class _Member(NodeRunner):
    """The environment as a lockstep member: the standard node (joining, inputs filed by
    stamp, ACK trailer, FINAL, the plant watched), with one change: at each complete tick
    it hands every robot's observation to the environment's thread and answers with the
    commands it gets back (docs/PROTOCOL.md, section 4). A job whose command is constant
    is answered once, holding its other ticks ("Holding"): the plant steps them without
    a round trip each, and their commands are the same (the latest acts), up to the
    robots' ``cmd_timeout_s`` (a longer hold would let the plant stop them)."""

    def __init__(self, *a, **kw) -> None:
        super().__init__(*a, **kw)
        self.cv = threading.Condition()
        self.pending: _Job | None = None
        self.current: _Job | None = None
        self.closing = False

    @property
    def max_hold(self) -> int:
        """Ticks a command may stand after its own, still acting on the last of them: the
        bound of docs/PROTOCOL.md section 4, "Holding" (:func:`bus.protocol.info_max_hold`,
        from the plant's ``sim/info`` as :meth:`_apply_info` last took it)."""
        return info_max_hold(self.info) if self.info.get("robots") else 0

    def submit(self, job: _Job) -> None:
        with self.cv:
            self.pending = job
            self.cv.notify_all()

    def shut(self, thread: threading.Thread | None, grace_s: float = 3.0) -> None:
        """Leave the plant in order: the tick held is answered with FINAL (the plant ends a
        run whose members all finished, docs/PROTOCOL.md "Finishing", instead of holding
        time for a lost one), then the member stops."""
        with self.cv:
            self.closing = True
            self.cv.notify_all()
        if thread is not None:
            thread.join(grace_s)
        self.stop_event.set()

    def _take(self) -> _Job | None:
        with self.cv:
            while self.pending is None and not self.closing:
                self.cv.wait(0.2)
            job, self.pending = self.pending, None
            return job

    def _act(self, t_ns: int) -> bool:
        m = self.member
        msgs = {s.robot: m.take_observation(s, t_ns).msgs for s in self.slots}
        job = self.current
        if job is not None:
            try:
                job.observe(t_ns, msgs)
            except BaseException as exc:     # handed to the environment's thread
                job.error = exc
            job.n -= 1
            if job.n <= 0 or job.error is not None:
                job.t_end, self.current = t_ns, None
                job.done.set()
                job = None
        if m.holds(t_ns):                    # answered by the last answer's hold
            self._send(m.skip(t_ns), t_ns)
            return False
        if job is None:
            job = self.current = self._take()
            if job is not None and job.new_world:
                # as a controller's reset from inside step: the tick answered now is the
                # old world's, and the new one's ticks are no re-sends of the old one's
                self.reset_inputs()
        cmds = {}
        if job is not None:
            try:
                cmds = job.command(t_ns, msgs)
            except BaseException as exc:
                job.error, job.t_end, self.current = exc, t_ns, None
                job.done.set()
        for slot in self.slots:
            v, w = cmds.get(slot.robot, (0.0, 0.0))
            m.queue_output(Twist(v, w), t_ns, slot.robot)
        final = job is None and self.closing
        hold = (min(job.n - 1, self.max_hold)
                if job is not None and job.constant and self.current is job else 0)
        self._send(m.send_tick(t_ns, final=final, hold=hold), t_ns)
        return final


_names = itertools.count()


class Bus:
    """A lockstep member of a plant over Zenoh; starts that plant (lockstep, sequential
    coupling, on a unix socket of its own) unless ``endpoint`` names a running one."""

    def __init__(self, spec: WorldSpec, world: str, inputs: dict[str, list[str]],
                 disabled: tuple[str, ...] = (), overrides: tuple[str, ...] = (),
                 endpoint: str | None = None, namespace: str = "") -> None:
        self.spec = spec
        self.tick_ns = spec.tick_ns
        self.keys = Keys(namespace)
        self.log = logging.getLogger("diffbot.envs")
        self._args = (world, inputs, tuple(disabled), tuple(overrides), endpoint, namespace)
        self.endpoint = endpoint
        res = self._res = _Resources()
        # closed when the environment is, or garbage-collected, or at interpreter exit
        self._finalizer = weakref.finalize(self, res.close)

    def _start(self) -> None:
        """Start the plant (or join it) and the member: at the first reset, not at
        construction, so an environment made only for its spaces (make_vec's in the
        parent process) starts nothing and a forked worker inherits no Zenoh runtime."""
        world, inputs, disabled, overrides, endpoint, namespace = self._args
        spec, res = self.spec, self._res
        if _fork["child"]:                 # before anything is made: nothing to leave behind
            raise TransportError(FORKED_WORKER)
        try:
            if endpoint is None:
                res.tmpdir = tempfile.mkdtemp(prefix="diffbot-env-")
                endpoint = f"unixsock-stream/{res.tmpdir}/bus.sock"
                res.plant = _start_plant(world, overrides, disabled, endpoint, spec.seed,
                                         namespace, res.tmpdir)
            res.session = _open(endpoint, res.plant)
            name = f"gym_{os.getpid()}_{next(_names)}"
            robots = list(inputs)
            member = _Member(lambda r: _Inputs(inputs[r]), robots[0], name, res.session,
                             self.keys, self.log, wait_for_plant_s=PLANT_TIMEOUT_S,
                             robots=robots)
            info = member.info
            if info.get("mode") != "lockstep" or info.get("coupling") != "sequential":
                raise TransportError(
                    f"the plant at {endpoint} runs {info.get('mode')} mode, "
                    f"{info.get('coupling')} coupling: an environment needs lockstep with "
                    "sequential coupling (diffbot plant --mode lockstep --coupling sequential)")
            if abs(info.get("control_tick_s", 0) - spec.control_tick_s) > 1e-12:
                raise TransportError(f"the plant's control tick {info.get('control_tick_s')} s "
                                     f"is not the world's {spec.control_tick_s} s")
            res.member = member
            res.thread = threading.Thread(target=member.run, name=f"{name}-member",
                                          daemon=True)
            res.thread.start()
        except BaseException:
            self.close()
            raise
        self.endpoint = endpoint
        self._started = True

    @property
    def plant_log(self) -> str | None:
        return self._res.plant.log_path if self._res.plant is not None else None

    _started = False

    def _run(self, job: _Job) -> _Job:
        res = self._res
        if not self._started:
            self._start()
        if res.member is None:
            raise TransportError("the environment is closed")
        res.member.submit(job)
        while not job.done.wait(0.5):
            if not res.thread.is_alive():
                raise TransportError(self._gone())
        if job.error is not None:
            raise job.error
        return job

    def _gone(self) -> str:
        why = "the bus member stopped (the plant went away?)"
        if self._res.plant is not None:
            code = self._res.plant.poll()
            if code is not None:
                why = f"the plant exited with code {code}:\n{self._res.plant.tail()}"
        return why

    def reset(self, seed: int, poses: dict, observe: Observe) -> None:
        # Answer the tick held (old world) and stop at the next, so the tick the stale
        # answer below is stamped with is >= 1: the new world ignores it (PROTOCOL.md 7)
        # instead of taking it for its tick 0.
        self._run(_Job(1, _zero, _ignore))
        req = {"seed": int(seed), "poses": {r: [float(v) for v in p] for r, p in poses.items()}}
        self._query_reset(req)
        job = self._run(_Job(1, _zero, observe, new_world=True))
        if job.t_end != 0:
            raise TransportError(f"after sim/reset the plant published t={job.t_end} ns, "
                                 "not the new world's t=0")
        self.spec.seed = seed
        for name, pose in poses.items():
            self.spec.robot(name).pose = tuple(float(v) for v in pose)

    def _query_reset(self, req: dict) -> None:
        deadline = time.monotonic() + PLANT_TIMEOUT_S
        while time.monotonic() < deadline:
            for reply in self._res.session.get(self.keys.reset, payload=json.dumps(req).encode(),
                                               timeout=5.0):
                if reply.ok is not None:
                    return
                raise TransportError("sim/reset refused: "
                                     + reply.err.payload.to_bytes().decode("utf-8", "replace"))
        raise TransportError(f"no answer on {self.keys.reset}: {self._gone()}")

    def advance(self, n: int, command: Command, observe: Observe,
                constant: bool = False) -> None:
        self._run(_Job(n, command, observe, constant=constant))

    def close(self) -> None:
        self._finalizer()
        self._started = True     # (closed: never started again)


class _Resources:
    """What a :class:`Bus` holds, closed in order by a finalizer that does not keep the
    environment alive: the member, the plant it started, the session, the socket dir."""

    def __init__(self) -> None:
        self.plant = None
        self.session = None
        self.member: _Member | None = None
        self.thread: threading.Thread | None = None
        self.tmpdir: str | None = None

    def close(self) -> None:
        from diffbot.procs import stop
        if self.member is not None:
            self.member.shut(self.thread)
        if self.plant is not None:
            stop([self.plant], grace_s=3.0)
            self.plant.close_log()
        if self.thread is not None:
            self.thread.join(5.0)
        if self.session is not None:
            close_session(self.session, logging.getLogger("diffbot.envs"))
        if self.tmpdir is not None:
            shutil.rmtree(self.tmpdir, ignore_errors=True)
        self.member = self.plant = self.session = self.thread = self.tmpdir = None


def _start_plant(world: str, overrides, disabled, endpoint: str, seed: int, namespace: str,
                 tmpdir: str):
    from diffbot.procs import Child, diffbot_argv
    argv = ["plant", "--world", world, "--mode", "lockstep", "--coupling", "sequential",
            "--seed", str(int(seed)), "--endpoint", endpoint, "--log-level", "WARNING"]
    for o in overrides:
        argv += ["--set", o]
    if disabled:
        argv += ["--disable", ",".join(disabled)]
    if namespace:
        argv += ["--namespace", namespace]
    return Child("plant", diffbot_argv(*argv), os.path.join(tmpdir, "plant.log"),
                 die_with_parent=True).start()


def _open(endpoint: str, plant):
    """A client session to the plant's endpoint, once it listens."""
    deadline = time.monotonic() + PLANT_TIMEOUT_S

    def missed(exc: Exception) -> None:
        if plant is not None and plant.poll() is not None:
            raise TransportError(f"the plant exited with code {plant.poll()}:\n"
                                 f"{plant.tail()}") from None
        if time.monotonic() > deadline:
            raise TransportError(f"no plant at {endpoint}: {zenoh_error(exc)}") from None
    return open_when_listening(endpoint, missed, pause_s=0.05)
