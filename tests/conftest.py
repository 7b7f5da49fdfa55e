"""Shared fixtures: a private bus endpoint per test and processes that are always cleaned up."""
from __future__ import annotations

import contextlib
import fcntl
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import pytest
from hypothesis import settings

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: scheduling noise on a loaded 2-core CI machine, added to a wall-clock promise where the
#: time itself is the contract (detection within the lease, a plant that does not pause,
#: realtime pacing); never a speed check (speed is ``diffbot bench``'s)
SLACK_S = 0.5
#: under CI (the variable CI set, as .ci/run and every CI service do) a missing tool or
#: build fails its test instead of skipping it: a run must not pass with fewer checks
CI = bool(os.environ.get("CI"))
#: the runs the tests start draw no figures (`diffbot run --no-plots`: matplotlib's import
#: and drawing are about a second of CPU a run, most of a short run's own); a test that
#: checks a figure asks for it with `--plots`
os.environ.setdefault("DIFFBOT_PLOTS", "0")

# Hypothesis: under CI derandomised (a failure replays as it is) with a third of the
# examples; on a developer's machine random, the full count, so the search goes on run
# after run. HYPOTHESIS_PROFILE=dev|ci chooses either anywhere.
settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
settings.register_profile("dev", deadline=None)
HYPOTHESIS_PROFILE = os.environ.get("HYPOTHESIS_PROFILE", "ci" if CI else "dev")
settings.load_profile(HYPOTHESIS_PROFILE)


def examples(n: int) -> int:
    """``max_examples`` for a property that asks for ``n`` on a developer's machine."""
    return max(20, n // 3) if HYPOTHESIS_PROFILE == "ci" else n


# ---------------------------------------------------------------- parallel runs (xdist)
# `make test` runs the suite on two pytest-xdist workers (`-n 2 --dist loadgroup`; pytest
# below 9.2, where that groups: tests/house/test_suite_contract.py). Three
# rules keep that as reliable as one worker:
# - the tests of a file stay on one worker (their module and session fixtures run once), a
#   file's ``xdist_group`` mark putting it with the other files of the same group (the
#   Ray cluster's tests; the ROS 2 tests, whose DDS domains are numbered per worker; the
#   files that share a session run);
# - a test marked ``serial`` runs with no other test beside it but ``background`` ones
#   (below): the other worker waits between two of its tests until it is done. For what
#   a second worker would disturb: wall-clock promises (a realtime plant's pace, detection
#   within a lease, exits within a grace), system-wide state (multicast memberships, the
#   default port). The serial tests with no group of their own are one group ("serial"),
#   so they run one after the other on one worker, which keeps its turn from one to the
#   next: the other worker waits once for all of them, not once for each (and each time
#   for the test it had in hand);
# - every other test holds a shared lock while it runs, so a serial one waits for it;
# - except a ``background`` test (a whole group of them, handed out right after the serial
#   group): it has no wall-clock bound of its own, takes no lock, and every process it
#   starts runs at a low CPU priority (BACKGROUND_NICE, in a session and so a scheduler
#   autogroup of its own), so it fills the cores the serial tests leave idle (~70 % of
#   two: /proc/stat) and yields most of them whenever a serial test's processes want them.
# Without xdist (plain `pytest`, `make test-fast`) the locks and the order do nothing (a
# background test's processes still run niced).
_LOCK_DIR = "DIFFBOT_TEST_LOCK_DIR"


#: Stable-Baselines3 makes a log folder for every model it trains (SB3-<time> in the
#: system's temporary folder unless SB3_LOGDIR names one): the suite's go into one folder
#: of its own, removed at the end
_SB3_LOGDIR = "SB3_LOGDIR"


def pytest_configure(config):
    if hasattr(config, "workerinput"):
        return                                  # (the workers inherit what is set here)
    if getattr(config.option, "numprocesses", None):
        os.environ[_LOCK_DIR] = tempfile.mkdtemp(prefix="dbt-lock-")
    if _SB3_LOGDIR not in os.environ:
        os.environ[_SB3_LOGDIR] = tempfile.mkdtemp(prefix="dbt-sb3-")
        config._diffbot_sb3_logdir = os.environ[_SB3_LOGDIR]


def pytest_unconfigure(config):
    if hasattr(config, "workerinput"):
        return
    for d in (os.environ.get(_LOCK_DIR), getattr(config, "_diffbot_sb3_logdir", None)):
        if d:
            shutil.rmtree(d, ignore_errors=True)


#: a test's expected share of a run, to hand out the longest groups first (seconds, rough:
#: a multi-process test takes 1-25 s, an in-process one mostly well under 0.1 s)
_COST_SLOW_S, _COST_FAST_S = 4.0, 0.05


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """A test with no ``xdist_group`` is grouped with its file (before xdist reads the
    groups: tryfirst). Under xdist the groups then come longest first (by their tests'
    ``slow`` marks; ``make test`` turns off xdist's own order, by number of tests), so no
    long group is left for the end, when the other worker has nothing to do."""
    group = {}
    for item in items:
        mark = item.get_closest_marker("xdist_group")
        if mark is None:
            serial = item.get_closest_marker("serial") is not None
            mark = pytest.mark.xdist_group("serial" if serial else item.nodeid.split("::")[0])
            item.add_marker(mark)
            mark = mark.mark
        group[item] = str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))
    background: dict[str, set[bool]] = {}
    for item in items:
        background.setdefault(group[item], set()).add(_background(item))
        if _background(item) and _serial(item):
            raise pytest.UsageError(f"{item.nodeid}: a test is serial or background, not both")
    mixed = sorted(g for g, kinds in background.items() if len(kinds) > 1)
    if mixed:       # a group runs on one worker in one go: all of it yields, or none of it
        raise pytest.UsageError("xdist groups with background tests and others: " + ", ".join(mixed))
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    cost: dict[str, float] = {}
    for item in items:
        cost[group[item]] = cost.get(group[item], 0.0) + (
            _COST_SLOW_S if item.get_closest_marker("slow") else _COST_FAST_S)
    first = {g: i for i, g in reversed(list(enumerate(group[it] for it in items)))}

    def rank(g: str) -> int:        # the serial group, then the background ones, then the rest
        return 0 if g == "serial" else 1 if True in background[g] else 2
    items.sort(key=lambda it: (rank(group[it]), -cost[group[it]], first[group[it]]))  # stable


def _serial(item) -> bool:
    return item is not None and item.get_closest_marker("serial") is not None


def _background(item) -> bool:
    return item is not None and item.get_closest_marker("background") is not None


class _Turns:
    """The suite lock (a file both workers open): exclusive for a ``serial`` test, shared
    otherwise. A gate taken first keeps a waiting exclusive turn from being passed by one
    shared turn after another. An exclusive turn is kept while the worker's next test is
    serial too."""

    def __init__(self) -> None:
        self.lock = None            # the open lock file while this worker holds a turn
        self.exclusive = False

    def take(self, exclusive: bool) -> None:
        if self.lock is not None:
            if self.exclusive == exclusive:
                return
            self.give()
        d = os.environ[_LOCK_DIR]
        lock = open(os.path.join(d, "lock"), "a")
        with open(os.path.join(d, "gate"), "a") as gate:
            fcntl.flock(gate, fcntl.LOCK_EX)
            try:
                fcntl.flock(lock, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
            finally:
                fcntl.flock(gate, fcntl.LOCK_UN)
        self.lock, self.exclusive = lock, exclusive

    def give(self) -> None:
        if self.lock is not None:
            fcntl.flock(self.lock, fcntl.LOCK_UN)
            self.lock.close()
            self.lock = None


_TURNS = _Turns()


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_protocol(item, nextitem):
    """Setup (module and session fixtures included), call and teardown in one turn; the
    outermost wrapper, so waiting for the turn does not count in pytest-timeout's time."""
    timeline = os.environ.get("DIFFBOT_TEST_TIMELINE")
    t0, cpu0 = time.time(), _cpu_s()
    if _background(item):               # no turn taken: its processes yield the CPU
        with _background_processes_yield():
            yield
    elif not os.environ.get(_LOCK_DIR) or not os.environ.get("PYTEST_XDIST_WORKER"):
        yield
    else:
        serial = _serial(item)
        _TURNS.take(serial)
        t0, cpu0 = time.time(), _cpu_s()    # (the wait for the turn is the line's gap)
        try:
            yield
        finally:
            if not (serial and _serial(nextitem)):
                _TURNS.give()
    if timeline:                    # when each test ran, on which worker: tuning the schedule
        with open(timeline, "a") as f:
            f.write(f"{os.environ.get('PYTEST_XDIST_WORKER', 'main')} {t0:.3f} {time.time():.3f}"
                    f" {int(_serial(item))} {_cpu_s() - cpu0:.2f} {item.nodeid}\n")


def _cpu_s() -> float:
    """CPU seconds (user and system) of this process and of the children it has waited
    for: a test's processes, theirs included once each is reaped by its parent."""
    use = (resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    return sum(u.ru_utime + u.ru_stime for u in use)


#: programs libraries run for a quick answer (platform.processor(), the docs' file list,
#: matplotlib's font list on a machine with no font cache yet): not a process the test is about
QUICK_LOOKUPS = {"uname", "git", "fc-list"}


#: a background test's processes: a low CPU priority (``nice``), for the process and its
#: session's scheduler autogroup (with autogroups on, the kernel shares the CPU between
#: sessions first). Not 19: at 19 (weight 15 against 1024) a busy machine kept such a process
#: off the CPU for over a second, past the bus's 1 s lease; at 10 (110) it yields ~90 %.
BACKGROUND_NICE = 10


def lower_priority(pid: int, nice: int = BACKGROUND_NICE) -> None:
    """``pid`` (a session leader: its session's autogroup too) at CPU priority ``nice``;
    quietly nothing where the system does not allow it."""
    try:
        os.setpriority(os.PRIO_PROCESS, pid, nice)
    except OSError:
        pass
    try:
        with open(f"/proc/{pid}/autogroup", "w") as f:
            f.write(str(nice))
    except OSError:                 # no autogroups (or the process is already gone)
        pass


@contextlib.contextmanager
def _background_processes_yield():
    """Every process a ``background`` test starts runs in a session of its own (so its
    children share its autogroup) at BACKGROUND_NICE, set from here as it starts.
    Around the background tests only (:func:`pytest_runtest_protocol`): Popen's keyword
    arguments can be changed nowhere else."""
    real_init = subprocess.Popen.__init__

    def init(self, args, *a, **kw):
        if not kw.get("start_new_session") and kw.get("process_group") is None:
            kw["start_new_session"] = True
        real_init(self, args, *a, **kw)
        lower_priority(self.pid)
    subprocess.Popen.__init__ = init
    try:
        yield
    finally:
        subprocess.Popen.__init__ = real_init


class _Starts:
    """What the running test starts, as Python's audit events say it (PEP 578: the
    ``subprocess.Popen`` event, raised by every Popen, ours and libraries'): one hook for
    the session, nothing patched."""

    def __init__(self) -> None:
        self.started: list[str] | None = None      # None: not watching

    def audit(self, event: str, args) -> None:
        if event != "subprocess.Popen" or self.started is None:
            return
        argv = args[1]
        argv = [str(a) for a in argv] if isinstance(argv, (list, tuple)) else [str(argv)]
        if argv and os.path.basename(argv[0].split()[0]) not in QUICK_LOOKUPS:
            self.started.append(" ".join(argv))


_STARTS = _Starts()
sys.addaudithook(_STARTS.audit)


@pytest.fixture(autouse=True)
def _slow_mark_is_true(request):
    """A test that starts a process (a plant, a compiler, openssl, a Ray node) must be
    marked ``slow``: ``make test-fast`` (``-m "not slow"``) is the in-process subset
    docs/install.md describes. Such a test fails here, naming what it started."""
    if request.node.get_closest_marker("slow"):
        yield
        return
    _STARTS.started = []
    try:
        yield
    finally:
        started, _STARTS.started = _STARTS.started, None
    if started:
        pytest.fail(f"{request.node.nodeid} starts processes but is not marked slow: "
                    + "; ".join(a[:120] for a in started[:3]), pytrace=False)


@pytest.fixture
def endpoint():
    """A unix-socket endpoint private to this test (no ports shared between parallel runs)."""
    d = tempfile.mkdtemp(prefix="dbt-")
    yield f"unixsock-stream/{d}/bus.sock"
    shutil.rmtree(d, ignore_errors=True)


class Procs:
    """Starts ``diffbot`` processes and kills every one of them by PID at teardown."""

    def __init__(self, tmp) -> None:
        self.tmp = tmp
        self.procs: list[subprocess.Popen] = []

    def diffbot(self, *args: str, name: str = "proc", netns: str | None = None,
                env: dict | None = None, **kw) -> subprocess.Popen:
        """``diffbot ARGS`` as a process of its own, logged; in network namespace ``netns``
        if given (``ip netns exec`` execs, so the PID is still python's); ``env``: extra
        environment variables."""
        log = open(os.path.join(self.tmp, f"{name}-{len(self.procs)}.log"), "wb")
        env = dict(os.environ, PYTHONUNBUFFERED="1", **(env or {}))
        kw.setdefault("stdout", log)
        kw.setdefault("stderr", subprocess.STDOUT)
        kw.setdefault("stdin", subprocess.DEVNULL)
        argv = [sys.executable, "-m", "diffbot.cli", *args]
        if netns:
            argv = ["ip", "netns", "exec", netns, *argv]
        kw.setdefault("cwd", ROOT)
        p = subprocess.Popen(argv, env=env, start_new_session=True, **kw)
        p.log_path = log.name
        self.procs.append(p)
        return p

    @staticmethod
    def log(p) -> str:
        with open(p.log_path, "rb") as f:
            return f.read().decode("utf-8", "replace")

    @staticmethod
    def wait(p, timeout: float, what: str = "the process to exit") -> int:
        """``p``'s exit code once it exits within ``timeout`` s; else fail with where its
        threads are (SIGUSR1: bus/process.py has every process dump its stacks to its log)
        and the end of its log."""
        try:
            return p.wait(timeout)
        except subprocess.TimeoutExpired:
            Procs.dump_stacks(p, 5.0)
            raise AssertionError(f"timed out after {timeout} s waiting for {what}; its log "
                                 f"ends:\n{Procs.log(p)[-6000:]}") from None

    @staticmethod
    def dump_stacks(p, timeout: float) -> str:
        """Where ``p``'s threads are (SIGUSR1, docs/failures.md), once its main thread's stack
        is in its log whole (faulthandler writes it last, down to the bottom frame), or what
        came within ``timeout`` s: the main thread's part of the dump."""
        p.send_signal(signal.SIGUSR1)
        deadline = time.monotonic() + timeout
        while True:
            main = Procs.log(p).rpartition("Current thread")[2]
            if "in _run_module_as_main" in main or time.monotonic() > deadline:
                return main
            time.sleep(0.05)

    def cleanup(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 3
        for p in self.procs:
            try:
                p.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)


@pytest.fixture
def procs(tmp_path):
    pr = Procs(str(tmp_path))
    yield pr
    pr.cleanup()


#: tests/runs/test_sweep.py's table and tests/runs/test_sweep_ray.py's reference (conftest.local_sweep)
LOCAL_SWEEP = ("sweep", "drive-test", "--grid",
               "robots.robot1.motion.command_noise_std_radps=0,0.3", "--seeds", "0-1",
               "--duration", "10.5")


@pytest.fixture(scope="session")
def local_sweep(tmp_path_factory):
    """``diffbot sweep`` LOCAL_SWEEP on the local engine, run once for the files that read
    it (tests/runs/test_sweep.py: its table, plots and resume; tests/runs/test_sweep_ray.py: the
    metrics the Ray engine must give), one xdist group ("ray"). {"out": its folder,
    "args": the command's arguments, "log": its output}."""
    out = tmp_path_factory.mktemp("local_sweep") / "sweep"
    args = (*LOCAL_SWEEP, "--plots", "--out", str(out))      # (the suite's default: none)
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", *args], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (r.stdout + r.stderr)[-2000:]
    return {"out": str(out), "args": args, "log": r.stdout + r.stderr}


@pytest.fixture(scope="session")
def ray_cluster():
    """A real two-node Ray cluster on this machine (tests/support/ray_cluster.py), started once for
    the tests that need one; a module takes it with ``ray_cluster.revive()`` first (a test
    may have killed the worker)."""
    pytest.importorskip("ray", reason="the [cluster] extra (make setup installs it)")
    from .support.ray_cluster import two_nodes
    with two_nodes() as c:
        yield c


@pytest.fixture
def bus(endpoint, procs):
    """``connect()``: a client session to the test's endpoint, opened once the plant the test
    started there listens, however long its start takes (tests/support/patience.py)."""
    from .support.patience import sessions
    with sessions(endpoint, procs.procs) as connect:
        yield connect


def wait_for(pred, timeout: float, step: float = 0.02, what: str = "condition"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = pred()
        if v:
            return v
        time.sleep(step)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def check_real_time_factor(s: dict) -> None:
    """A run's ``real_time_factor`` (summary.json, a sweep row, a study report) is its
    simulated time over the plant's wall time (plant/node.py), which is a part of the run's
    wall time: so it is at least ``sim_time_s / wall_time_s``, and exactly
    ``sim_time_s / plant_wall_time_s`` where that is given. Not a speed check (speed is
    ``diffbot bench``'s): a factor computed the wrong way round, from the wrong clock or
    left out fails it."""
    rtf, sim, wall = (float(s[k]) for k in ("real_time_factor", "sim_time_s", "wall_time_s"))
    assert sim > 0 and wall > 0, s
    assert rtf >= sim / wall * (1 - 1e-9), (rtf, sim, wall)
    if s.get("plant_wall_time_s") is not None:
        plant_wall = float(s["plant_wall_time_s"])
        assert plant_wall <= wall, (plant_wall, wall)
        assert rtf == pytest.approx(sim / plant_wall, rel=1e-9), (rtf, sim, plant_wall)


def require_built_fmus() -> None:
    """The FMUs `make setup` builds (fmus/build): skipped without them on a developer's
    machine, a failure under CI, where setup has built them."""
    missing = [f for f in ("odometry_fmi2.fmu", "odometry_fmi3.fmu")
               if not os.path.isfile(os.path.join(ROOT, "fmus", "build", f))]
    if missing:
        why = f"FMUs not built ({', '.join(missing)}; `make setup` builds them)"
        if CI:
            pytest.fail(why)
        pytest.skip(why)


@pytest.fixture(scope="session")
def built_fmus(tmp_path_factory):
    """The odometry FMUs built from fmus/ once per session (fmus.build, the system C
    compiler) into a temporary directory: {2: FMI 2 path, 3: FMI 3 path}."""
    from fmus import build
    paths = build.build_fmus(tmp_path_factory.mktemp("fmus"))
    return {2: paths["fmi2"], 3: paths["fmi3"]}


def check_realtime_pace(stats: dict, rate: float = 1.0, tick_s: float = 0.02) -> None:
    """A realtime plant's own stats (``--stats``) against the wall clock: it never runs
    ahead of wall time x ``rate`` (each tick waits for its due time); and unless it
    re-anchored (``stalls``: it fell further behind than plant.modes.STALL_S, stopped or
    starved, and carries on from there instead of racing to catch up, docs/failures.md)
    it is behind by at most that, plus SLACK_S for its last tick and a loaded machine."""
    from plant.modes import STALL_S
    sim, wall = stats["sim_time_s"], stats["wall_time_s"]
    assert sim > 0 and wall > 0, stats
    assert sim <= wall * rate * (1 + 1e-6), f"ran ahead: {sim:.3f} s in {wall:.3f} s x {rate:g}"
    if not stats.get("stalls"):
        behind = wall - sim / rate
        assert behind <= max(STALL_S, 5 * tick_s / rate) + SLACK_S, \
            f"{behind:.3f} s behind the wall clock at --rate {rate:g}, and no stall reported"


@pytest.fixture(scope="session")
def square_seed0(tmp_path_factory):
    """``diffbot run square --seed 0 --record`` (the scenario's whole square, lockstep),
    run once for the files that compare against it (tests/network/test_netns.py: the recording;
    tests/fmus/test_plant_fmu.py: the odometry error; tests/bridges/test_ros2_bridge.py: the trajectory
    the rclpy square drives), and by whichever runs first: a test run
    alone runs it too. Those files are one xdist group, so one worker runs it.
    {"out": results folder, "mcap": recording, "summary": summary.json}."""
    d = tmp_path_factory.mktemp("square_seed0")
    out, mcap = d / "out", d / "square.mcap"
    r = subprocess.run([sys.executable, "-m", "diffbot.cli", "run", "square", "--seed", "0",
                        "--out", str(out), "--record", str(mcap), "--plots"],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    import json
    return {"out": str(out), "mcap": str(mcap),
            "summary": json.loads((out / "summary.json").read_text())}
