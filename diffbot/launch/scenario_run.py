"""A scenario's run: its processes, started in order, supervised, stopped (:class:`ScenarioRun`).

Each process is its own OS process in its own session (process group), so the run decides
the order of shutdown: on Ctrl-C, SIGTERM, the end of the run or a failure, it sends SIGINT
to every child, waits, then SIGKILLs what is left, by PID (at the plant's normal end, the
nodes first have a moment to end by themselves on its sim/end). A required process that dies
ends the run with a non-zero exit code and its last stderr lines; an optional one may die
alone. A process marked ``ends_run`` that exits 0 ends the run normally. A process that is
still there but has lost its bus lease (stopped with SIGSTOP, or wedged) counts as dead: the
run watches ``sim/alive/*`` and /proc. When nodes exit 3 because the plant went away, the
report names the plant. Lockstep members may instead be composed into the plant's process
(``compose``). Where the processes run is data the run takes: a
:class:`diffbot.launch.placement.Placement` (``placement=``) names the processes that run as Ray
tasks on other nodes; ``diffbot run`` (diffbot/launch/launcher.py) is the command line.
"""
from __future__ import annotations

import os
import queue
import shlex
import signal
import sys
import time
from dataclasses import dataclass, field

import zenoh

from bus.jsonio import read_json
from bus.keys import Keys
from bus.runtime import EXIT_PLANT_GONE
from bus.session import BusConfigError, open_session

from ..runner import procs
from .observer import OBSERVER, OBSERVER_LEASE_MS
from .placement import Placement, set_option, tls_config
from ..runner.procs import diffbot_argv
from .scenario import ScenarioSpec, expand

STOP_GRACE_S = 1.5
#: after the plant ended the run (exit 0), how long its nodes have to end by themselves on
#: its sim/end before they are asked to stop (they take a fraction of a second)
END_GRACE_S = 3.0
#: a child whose bus token is gone but whose process still runs is taken as hung after this
WEDGED_S = 3.0
#: how long a process that did not stop in time is given to write its stacks (SIGUSR1)
DUMP_S = 0.3
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130

ROS2_BRIDGE = "ros2_bridge"  # the --ros2 process (bridges/ros2.py)
RECORDER = "recorder"       # the --record process (bridges/record.py); see ScenarioRun's recorder section
RECORDER_JOIN_S = 30.0
VIEW = "view"               # the --view process (bridges/view.py): optional, never in lockstep
RECORDER_GRACE_S = 10.0
#: how long a recorder may take to end by itself after the plant's sim/end (its own bound,
#: bridges.record.END_MAX_S, 5 s, and a second)
RECORDER_END_S = 6.0


class Child(procs.Child):
    """A scenario's process: a :class:`procs.Child` and what its death means for the run.
    It gets SIGTERM from the kernel if the launcher dies without stopping it (SIGKILL, OOM):
    a run never leaves a plant or a node behind."""

    def __init__(self, name: str, argv: list[str], required: bool = True,
                 ends_run: bool = False, interactive: bool = False, log_path: str = "") -> None:
        super().__init__(name, argv, log_path, interactive=interactive, die_with_parent=True)
        self.required = required
        self.ends_run = ends_run


@dataclass
class ScenarioRun:
    spec: ScenarioSpec
    out: str
    mode: str
    seed: int
    endpoint: str
    namespace: str = ""
    zenoh_config: str | None = None
    duration_s: float | None = None
    timeout_s: float = 900.0
    coupling: str = "sequential"    # lockstep coupling (docs/PROTOCOL.md)
    physics_process: bool = False   # --physics-process: DART in a process of its own
    compose: bool = False           # --compose: lockstep members hosted in the plant's process
    composed: list[str] = field(default_factory=list)   # (the members that were)
    record: str | None = None       # --record FILE.mcap (see the recorder section)
    recorder: Child | None = None
    ros2: bool = False              # --ros2: the ROS 2 bridge (bridges/ros2.py), free running
    view_port: int | None = None    # --view [--view-port P]: serve the run to Foxglove
    view_host: str = "127.0.0.1"
    placement: Placement | None = None   # --place: processes on Ray nodes (diffbot/launch/placement.py)
    children: list[Child] = field(default_factory=list)
    reason: str = ""
    failed: Child | None = None
    #: the run ended normally: the plant or a required process exited 0 (:meth:`supervise`)
    finished: bool = False
    #: bus liveliness of the processes (sim/alive/<name>): name -> wall time its token went,
    #: None while it is there (kept by the supervising thread from :attr:`alive_events`)
    gone: dict[str, float | None] = field(default_factory=dict)
    #: (name, wall time its token went or None if it came), queued by :meth:`on_alive` on
    #: Zenoh's thread
    alive_events: queue.SimpleQueue = field(default_factory=queue.SimpleQueue)

    def bus_args(self) -> list[str]:
        a = ["--endpoint", self.endpoint]
        if self.namespace:
            a += ["--namespace", self.namespace]
        if self.zenoh_config:
            a += ["--zenoh-config", self.zenoh_config]
        return a

    def build(self) -> None:
        logs = os.path.join(self.out, "logs")
        os.makedirs(logs, exist_ok=True)
        # `diffbot run sim --mode lockstep --ros2`: the bridge holds the ticks for the user's
        # ROS 2 node, and when that node leaves the run ends
        drives = self.ros2 and self.spec.ros2_drives and self.mode == "lockstep"
        expect = [p.name for p in self.spec.processes if p.sync] + self._recorder_expect() \
            + ([ROS2_BRIDGE] if drives else [])
        def own(p) -> list[str]:
            """A member's command line, bus options aside."""
            return [*p.command, "--name", p.name, "--stats", os.path.join(logs, f"{p.name}.json")]
        self.composed = [p.name for p in self.spec.processes if self.compose and composable(p)]
        plant = diffbot_argv("plant", "--world", self.spec.world, "--mode", self.mode,
                             "--coupling", self.coupling, "--seed", str(self.seed), "--stats",
                             os.path.join(logs, "plant.json"), *self.spec.plant_args,
                             *self.bus_args())
        if expect:
            plant += ["--expect", ",".join(expect)]
        enders = [p.name for p in self.spec.processes if p.ends_run and p.sync] \
            + ([ROS2_BRIDGE] if drives else [])
        if enders and self.mode == "lockstep":
            plant += ["--end-with", ",".join(enders)]
        if self.duration_s is not None:
            plant += ["--duration", repr(self.duration_s)]
        if self.mode == "lockstep" and self.composed:
            # composed members are there at once: the plant must not tick before the
            # observer and the recorder listen (process members start only once they do)
            plant += ["--wait-for", ",".join([OBSERVER] + ([RECORDER] if self.record else []))]
        if self.physics_process and "--physics-process" not in plant:
            plant.append("--physics-process")
        for p in self.spec.processes:
            if p.name in self.composed:
                plant += ["--compose", shlex.join(own(p))]
        self.children.append(Child("plant", plant, log_path=os.path.join(logs, "plant.log")))
        self._add_recorder(logs)
        if self.ros2:
            # a bus node like the others, but not a lockstep member: ROS 2 nodes (teleop,
            # rviz) follow /clock; a scenario's own `["ros2", "--lockstep"]` process holds ticks
            self.children.append(Child(ROS2_BRIDGE, diffbot_argv(
                "ros2", "--name", ROS2_BRIDGE, "--stats", os.path.join(logs, f"{ROS2_BRIDGE}.json"),
                *(["--lockstep"] if drives else []), *self.bus_args()), required=drives,
                ends_run=drives, log_path=os.path.join(logs, f"{ROS2_BRIDGE}.log")))
        if self.view_port is not None:
            # Not a lockstep member, not expected by the plant: it watches, it never holds.
            argv = diffbot_argv("view", "--port", str(self.view_port), "--host", self.view_host,
                                "--name", VIEW, "--stats", os.path.join(logs, f"{VIEW}.json"),
                                *self.bus_args())
            self.children.append(Child(VIEW, argv, required=False,
                                       log_path=os.path.join(logs, f"{VIEW}.log")))
        for p in self.spec.processes:
            if p.name in self.composed:
                continue
            argv = diffbot_argv(*own(p), *self.bus_args()) if p.exec is None else expand(
                p.exec, {"name": p.name, "bus": self.bus_args(), "endpoint": self.endpoint,
                         "namespace": self.namespace, "python": sys.executable,
                         "out": self.out})
            self.children.append(Child(p.name, argv, p.required, p.ends_run, p.interactive,
                                       log_path=os.path.join(logs, f"{p.name}.log")))
        if self.placement is not None:
            self._place(self.placement)

    def process_names(self) -> list[str]:
        """The run's processes (composed ones too), as ``--place`` names them."""
        return ["plant", *([RECORDER] if self.record else []),
                *([ROS2_BRIDGE] if self.ros2 else []),
                *([VIEW] if self.view_port is not None else []),
                *(p.name for p in self.spec.processes)]

    def _place(self, placement: Placement) -> None:
        """The processes the placement names run as Ray tasks on their nodes; with its
        ``tls``, every process gets the shipped TLS config of its role."""
        if placement.tls:
            for c in self.children:
                set_option(c.argv, "--zenoh-config", tls_config(role(c)))
        self.children = [placement.child(c, self.out, self.timeout_s + 60.0)
                         for c in self.children]
        if self.recorder is not None:
            self.recorder = next(c for c in self.children if c.name == RECORDER)

    def open_observer(self):
        """The launcher's own session: the observer that the analysis reads. A placed run
        tries again while the plant's task is still starting (a Ray worker may take
        seconds) and the plant has not failed."""
        deadline = time.monotonic() + (self.placement.observer_join_s
                                       if self.placement is not None else 0.0)
        while True:
            try:
                return open_session("observer", self.endpoint, self.zenoh_config,
                                    lease_ms=OBSERVER_LEASE_MS)
            except BusConfigError:
                if (self.placement is None or time.monotonic() > deadline
                        or self.children[0].poll() is not None):
                    raise

    def stop_all(self) -> None:
        """SIGINT the nodes, then the plant (so nodes do not see it vanish), then SIGKILL
        by PID whatever is left after the grace period, the recorder last. After a plant
        that ended the run (exit 0) the nodes first get :data:`END_GRACE_S` to end by
        themselves. A placed run then waits for its tasks to report
        (:meth:`Placement.wait_tasks`)."""
        try:
            plant = self.children[0]
            nodes = [c for c in self.children[1:] if c is not self.recorder]
            if self.finished and plant.poll() is None:
                # A required node's exit was seen first: the plant is ending the run too
                # (its enders left, or it said sim/end and is still on its way out, or, when
                # placed, its task's report trails the node's). SIGINT now would race those
                # ends: a node asked to stop as it exits dies of the signal (a placed square
                # path said -2 after a run that ended 0).
                procs.wait_all([plant], END_GRACE_S)
            if plant.poll() == 0:
                # The run's normal end: every node got the plant's sim/end and ends by
                # itself. A stop request meanwhile races that end; a placed node's Ray task
                # cancelled as it returns loses the node's exit code (summary.json said -2
                # for an odometry node that had ended 0). The view stays until stopped.
                procs.wait_all([c for c in nodes if c.name != VIEW], END_GRACE_S)
            # STOP_GRACE_S in all: the nodes up to half of it, the plant the other half or
            # what they left, if more (it ends its tick, logs, says sim/end: ~0.2 s, more
            # on a loaded machine, where a fixed half once cut it off and lost its
            # statistics); the half at least, counted from its own SIGINT, as this thread
            # may have been held up on the way (a busy machine, the plots' imports)
            t0 = time.monotonic()
            deadline = t0 + STOP_GRACE_S
            for c in nodes:
                c.signal(signal.SIGINT)
            procs.wait_all(nodes, STOP_GRACE_S / 2)
            asked = time.monotonic()
            plant.signal(signal.SIGINT)
            procs.wait_all([plant, *nodes], max(STOP_GRACE_S / 2, deadline - time.monotonic()))
            self._stop_recorder()
            left = [c.name for c in self.children if c.running()]
            if left:
                self._dump_stacks()
            procs.stop(self.children, 0.0, signal.SIGKILL)
            if left:            # (what a killed plant's missing statistics come from)
                now = time.monotonic()
                print(f"diffbot run: {', '.join(left)} did not stop in time; killed (SIGKILL; "
                      f"the nodes were asked to stop {now - t0:.2f} s before, "
                      f"the plant {now - asked:.2f} s before)", file=sys.stderr)
            if self.placement is not None:
                self.placement.wait_tasks(self.children, self.out)
        finally:
            if self.placement is not None:
                self.placement.close()

    def _dump_stacks(self) -> None:
        """Before a process that did not stop in time is killed: its threads' stacks into
        its log (SIGUSR1: every diffbot process registers :mod:`faulthandler` for it,
        bus/process.py), which is what tells where it hung. Not for another program (any
        program may be a scenario process), to which SIGUSR1 may mean something else."""
        ours = [c for c in self.children if c.running() and c.argv[:3] == diffbot_argv()]
        for c in ours:
            c.signal(signal.SIGUSR1)
        if ours:
            time.sleep(DUMP_S)

    def on_alive(self, sample) -> None:
        """Liveliness callback (Zenoh's thread): a process's ``sim/alive/<name>`` token came or
        went; only queued, :meth:`supervise` files it."""
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        self.alive_events.put((name, None if sample.kind == zenoh.SampleKind.PUT
                               else time.monotonic()))

    def _take_alive_events(self) -> None:
        while True:
            try:
                name, went = self.alive_events.get_nowait()
            except queue.Empty:
                return
            self.gone[name] = went

    def unresponsive(self, c: Child) -> bool:
        """A process that is there but lost its bus lease: stopped (SIGSTOP) or wedged."""
        went = self.gone.get(c.name)
        if went is None or c.poll() is not None:
            return False
        return c.stopped() or time.monotonic() - went > WEDGED_S

    def supervise(self, stop_flag: list) -> int:
        start = time.monotonic()
        while True:
            if stop_flag:
                self.reason = f"interrupted ({stop_flag[0]})"
                return EXIT_INTERRUPTED
            self._take_alive_events()
            for c in self.children:
                code = c.poll()
                if code is None:
                    if self.unresponsive(c):
                        what = ("stopped (SIGSTOP?)" if c.stopped()
                                else f"not answering for {WEDGED_S:.0f} s")
                        if c.name == "plant" or c.required:
                            self.failed = c
                            self.reason = (f"{c.name} stopped responding: its process is "
                                           f"{what} and lost its bus lease")
                            return EXIT_FAILED
                        print(f"diffbot run: {c.name} (optional) stopped responding; "
                              "killing it", file=sys.stderr)
                        c.signal(signal.SIGKILL)
                    continue
                if c.name == "plant" or c.required:
                    if code == 0:
                        self.reason = f"{c.name} finished"
                        self.finished = True
                        return 0
                    self.failed = c
                    self.reason = f"{c.name} {c.describe_exit()}"
                    if c.name == "plant":     # e.g. a lockstep member lost: which, when
                        why = read_json(os.path.join(self.out, "logs", "plant.json"))
                        if why.get("end_reason"):
                            self.reason += f": {why['end_reason']}"
                    if code == EXIT_PLANT_GONE and c.name != "plant":
                        self._blame_plant(c)
                    return EXIT_FAILED
            if time.monotonic() - start > self.timeout_s:
                self.reason = f"wall-clock timeout after {self.timeout_s:.0f} s"
                return EXIT_FAILED
            time.sleep(0.02)

    def _blame_plant(self, node: Child) -> None:
        """A node exited 3 (it lost the plant): if the plant died or froze, name the plant."""
        plant = self.children[0]
        deadline = time.monotonic() + 0.5
        while plant.poll() is None and not plant.stopped() and time.monotonic() < deadline:
            time.sleep(0.02)
        if plant.poll() is not None:
            self.failed = plant
            self.reason = f"plant {plant.describe_exit()} ({node.name} lost it)"
        elif plant.stopped():
            self.failed = plant
            self.reason = (f"plant stopped responding: its process is stopped (SIGSTOP?) "
                           f"and lost its bus lease ({node.name} lost it)")
        else:
            self.reason += " (it lost the plant)"

    # ------------------------------------------------------------ recorder (--record)
    # An optional extra process, started right after the plant and before every other
    # node; it declares sim/alive/recorder once subscribed. In lockstep the plant cannot
    # tick before the nodes join, and they start only once that token is seen; in
    # realtime/fast the plant --expects it too. It is stopped last, after the plant,
    # with time to close its file.
    def _recorder_expect(self) -> list[str]:
        return [RECORDER] if self.record and self.mode != "lockstep" else []

    def _add_recorder(self, logs: str) -> None:
        if self.record:
            argv = diffbot_argv("record", os.path.abspath(self.record), "--name", RECORDER,
                                "--stats", os.path.join(logs, f"{RECORDER}.json"),
                                *self.bus_args())
            self.recorder = Child(RECORDER, argv, required=False,
                                  log_path=os.path.join(logs, f"{RECORDER}.log"))
            self.children.append(self.recorder)

    def start_recorder(self, env: dict, session, stop_flag: list) -> bool:
        """Start the recorder, then the view (--view), each waited for until it is on the
        bus (so the whole run is recorded and watched, and neither one's start-up competes
        with the first ticks); False (and ``failed``) if one does not come."""
        view = next((c for c in self.children if c.name == VIEW), None)
        return all(self._start_waited(c, env, session, stop_flag)
                   for c in (self.recorder, view) if c is not None)

    def _start_waited(self, child: Child, env: dict, session, stop_flag: list) -> bool:
        child.start(env)
        key = Keys(self.namespace).alive(child.name)
        deadline = time.monotonic() + RECORDER_JOIN_S
        while time.monotonic() < deadline and child.poll() is None and not stop_flag:
            if any(r.ok is not None for r in session.liveliness().get(key, timeout=0.5)):
                return True
            time.sleep(0.05)
        if not stop_flag:
            self.failed = child
            self.reason = (f"{child.name} failed with exit code {child.exit_code}"
                           if child.exit_code is not None
                           else f"{child.name} did not start within {RECORDER_JOIN_S:.0f} s")
        return False

    def _stop_recorder(self) -> None:
        """After a plant that ended in order (exit 0: it published sim/end) the recorder is
        given the time to end by itself (bridges/record.py: at sim/end, once the bus is quiet
        and no member is left), so one behind on a loaded machine still writes the run's
        last ticks; then SIGINT (it closes the file with what it has)."""
        if self.recorder is not None:
            if self.children[0].poll() == 0:
                procs.wait_all([self.recorder], RECORDER_END_S)
            self.recorder.signal(signal.SIGINT)
            procs.wait_all([self.recorder], RECORDER_GRACE_S)


def role(child: Child) -> str:
    """The role a process's shipped TLS config is named for (diffbot/launch/configs/<role>_tls.json5)."""
    if child.name in ("plant", RECORDER, VIEW):
        return child.name
    if child.name == ROS2_BRIDGE or "ros2" in child.argv[3:4]:
        return "bridge"
    return "node"


def composable(p) -> bool:
    """Whether a scenario process can run composed into the plant: a lockstep member whose
    command makes a Python member (diffbot.cli.member_main), not interactive, and not kept
    a process (``compose = false``)."""
    from .members import member_main
    if not (p.sync and p.compose and not p.interactive) or p.exec is not None:
        return False
    try:
        member_main(p.command)
    except ValueError:
        return False
    return True


def run_stats(run: ScenarioRun) -> dict[str, dict]:
    """Each process's (and composed member's) --stats file, by name ({} if it wrote none)."""
    names = [c.name for c in run.children] + run.composed
    return {n: read_json(os.path.join(run.out, "logs", f"{n}.json")) for n in names}


def published_counts(stats: dict[str, dict]) -> dict[str, int]:
    """Messages put on each key, as the processes count what they published."""
    counts: dict[str, int] = {}
    for st in stats.values():
        for key, n in st.get("published", {}).items():
            counts[key] = counts.get(key, 0) + n
    return counts


def summarize(run: ScenarioRun, wall: float, code: int, stats: dict | None = None) -> dict:
    """summary.json of ``run``; ``stats``: its processes' (:func:`run_stats`), if read."""
    stats = run_stats(run) if stats is None else stats
    plant = stats["plant"]
    counts = published_counts(stats)
    return {
        "scenario": run.spec.name, "world": run.spec.world, "mode": run.mode, "seed": run.seed,
        "coupling": plant.get("coupling", run.coupling),
        "actuation_delay_ticks": plant.get("actuation_delay_ticks"),
        "node_input_delay_ticks": plant.get("node_input_delay_ticks"),
        "sim_time_s": plant.get("sim_time_s"), "wall_time_s": wall,
        "plant_wall_time_s": plant.get("wall_time_s"),
        "real_time_factor": plant.get("real_time_factor"),
        # where the plant's wall time went per tick (ms): publishing, waiting for the
        # nodes, physics (with a physics process: the part publishing did not hide)
        "plant_per_tick_ms": plant.get("per_tick_ms"),
        # CPU ms a tick over the loop: the plant's process and its physics process's
        "cpu_per_tick_ms": plant.get("cpu_per_tick_ms"),
        "physics_process": plant.get("physics_process", False),
        # A run that ended in the plant (duration reached, the ending node finished) says so.
        "end_reason": (f"plant: {plant['end_reason']}"
                       if code == 0 and plant.get("end_reason", "stopped") != "stopped"
                       else run.reason),
        "exit_code": code,
        "exit_codes": {**{c.name: c.exit_code for c in run.children},
                       **{n: stats[n].get("exit_code") for n in run.composed}},
        "composed": list(run.composed),
        "message_counts": dict(sorted(counts.items())),
        "rejected": {name: st.get("rejected", {}) for name, st in stats.items()},
    }
