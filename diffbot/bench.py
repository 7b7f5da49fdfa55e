"""``diffbot bench``: a small benchmark harness and its suites.

    diffbot bench [--suite NAME ...] [--quick] [--repeats N] [--json FILE] [--list]

Speed is measured here and printed, never asserted in tests. Each suite is a
function registered in :data:`SUITES` that returns (or yields) cases:

- :class:`Case` -- a micro-benchmark: ``fn(number) -> total seconds`` (``timer=True``)
  or a plain callable timed with :func:`time.perf_counter`. ``number`` is picked so
  that one repeat takes ~0.1-0.2 s (:func:`autorange`); a warm-up call comes first.
- :class:`Probe` -- one expensive run per repeat (a subprocess, a scenario) that
  returns several numbers at once, e.g. ``{"rtf": 2.8, "overhead_s": 3e-3}``.

Adding a suite takes a few lines::

    @suite("raycast", "one 180-ray lidar sweep")
    def raycast_suite(ctx):
        return [Case("sweep 180 rays", lambda: caster.sweep(origin, angles))]

A suite that cannot run raises :class:`Skip` with the reason. Units: ``"s"`` values
are seconds per operation in the JSON and printed as ns/µs/ms/s; ``"x"`` is a
real-time factor (simulated seconds per wall second). Results go to stdout as an
aligned table, progress to stderr, and everything to ``--json FILE``.
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import math
import os
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: One repeat of a micro-benchmark aims at this much wall time (s): normal, --quick.
MIN_TIME_S, QUICK_MIN_TIME_S = 0.1, 0.02
TARGET_TIME_S, QUICK_TARGET_TIME_S = 0.15, 0.03
DEFAULT_REPEATS, QUICK_REPEATS = 5, 3
MAX_NUMBER = 10_000_000


# ============================================================================ cases
class Skip(Exception):
    """Raised by a suite (or a case) that cannot run here; the message says why."""


@dataclass
class Case:
    """A micro-benchmark of one operation.

    ``fn`` is ``fn(number) -> total seconds for number operations`` when ``timer`` is
    true, otherwise a plain callable (one call = one operation) timed with perf_counter.
    ``number`` fixes the operations per repeat (default: auto-picked).
    """
    name: str
    fn: Callable
    timer: bool = False
    unit: str = "s"
    notes: str = ""
    number: int | None = None
    repeats: int | None = None
    warmup: int = 1


@dataclass
class Metric:
    """One number a :class:`Probe` reports: ``key`` in its result dict, shown as ``name``."""
    key: str
    name: str
    unit: str = "s"
    notes: str = ""


@dataclass
class Probe:
    """An expensive measurement: each repeat is one call of ``fn() -> {key: value}``."""
    name: str
    fn: Callable[[], dict]
    metrics: list[Metric]
    repeats: int | None = None
    warmup: int = 0
    notes: str = ""


@dataclass
class Context:
    """What a suite may want to know: quick mode, an explicit repeat count, a temp dir."""
    quick: bool = False
    repeats: int | None = None
    tmpdir: str = field(default_factory=tempfile.gettempdir)

    def progress(self, msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)


#: name -> function(Context) returning an iterable of Case / Probe (a generator may
#: hold resources open across its cases and release them in ``finally``).
SUITES: dict[str, Callable[[Context], Iterable]] = {}


def suite(name: str, description: str = ""):
    """Decorator registering a suite function under ``name``."""
    def register(fn):
        fn.description = description
        SUITES[name] = fn
        return fn
    return register


# ============================================================================ timing
def as_timer(fn: Callable[[], object], clock: Callable[[], float] = time.perf_counter):
    """Turn a plain callable into ``timer(number) -> total seconds`` (like timeit)."""
    def timer(number: int) -> float:
        it = range(number)
        t0 = clock()
        for _ in it:
            fn()
        return clock() - t0
    return timer


def autorange(timer: Callable[[int], float], min_time: float = MIN_TIME_S,
              target: float = TARGET_TIME_S, max_number: int = MAX_NUMBER) -> tuple[int, float]:
    """Smallest ``number`` found for which ``timer(number)`` takes >= ``min_time``.

    Grows ``number`` by the factor the last timing suggests (aiming at ``target``,
    at least x2, at most x10 per try), so one repeat ends up at ~min_time..2*target.
    Returns (number, seconds of the last try).
    """
    number = 1
    while True:
        t = timer(number)
        if t >= min_time or number >= max_number:
            return number, t
        factor = 10.0 if t <= 0 else min(10.0, max(2.0, target / t))
        number = min(max_number, int(math.ceil(number * factor)))


def percentile(values: list[float], q: float) -> float:
    """``q``-th percentile (0-100), linear interpolation between closest ranks."""
    v = sorted(values)
    if not v:
        return math.nan
    k = (len(v) - 1) * q / 100.0
    lo, hi = math.floor(k), math.ceil(k)
    return v[lo] + (v[hi] - v[lo]) * (k - lo)


def stats(samples: list[float]) -> dict:
    """median, min, max, mean, p90 and quartiles of ``samples``."""
    if not samples:
        return {k: None for k in ("median", "min", "max", "mean", "p90", "q1", "q3")}
    return {"median": percentile(samples, 50), "min": min(samples), "max": max(samples),
            "mean": sum(samples) / len(samples), "p90": percentile(samples, 90),
            "q1": percentile(samples, 25), "q3": percentile(samples, 75)}


def measure(timer: Callable[[int], float], repeats: int = DEFAULT_REPEATS,
            number: int | None = None, warmup: int = 1, min_time: float = MIN_TIME_S,
            target: float = TARGET_TIME_S) -> tuple[int, list[float]]:
    """Warm up, pick ``number`` (unless given), then time ``repeats`` repeats.

    Returns (number, per-operation seconds of each repeat).
    """
    for _ in range(warmup):
        timer(1)
    if number is None:
        number, _ = autorange(timer, min_time, target)  # its last try is a full-size warm-up
    return number, [timer(number) / number for _ in range(repeats)]


# ============================================================================ running
@dataclass
class Result:
    suite: str
    name: str
    unit: str
    samples: list[float]
    number: int = 1
    notes: str = ""
    error: str | None = None

    def as_dict(self) -> dict:
        return {"suite": self.suite, "name": self.name, "unit": self.unit, **stats(self.samples),
                "repeats": len(self.samples), "number": self.number, "samples": self.samples,
                "notes": self.notes, **({"error": self.error} if self.error else {})}


def _repeats(ctx: Context, own: int | None) -> int:
    if ctx.repeats is not None:
        return ctx.repeats
    if own is not None:
        return own
    return QUICK_REPEATS if ctx.quick else DEFAULT_REPEATS


def run_case(ctx: Context, suite_name: str, case: Case) -> Result:
    timer = case.fn if case.timer else as_timer(case.fn)
    min_time, target = (QUICK_MIN_TIME_S, QUICK_TARGET_TIME_S) if ctx.quick else \
        (MIN_TIME_S, TARGET_TIME_S)
    number, samples = measure(timer, _repeats(ctx, case.repeats), case.number, case.warmup,
                              min_time, target)
    return Result(suite_name, case.name, case.unit, samples, number, case.notes)


def run_probe(ctx: Context, suite_name: str, probe: Probe) -> list[Result]:
    n = _repeats(ctx, probe.repeats)
    for i in range(probe.warmup):
        ctx.progress(f"  [{suite_name}] {probe.name}: warm-up run {i + 1}/{probe.warmup}")
        probe.fn()
    runs = []
    for i in range(n):
        ctx.progress(f"  [{suite_name}] {probe.name}: run {i + 1}/{n}")
        runs.append(probe.fn())
    out = []
    for i, m in enumerate(probe.metrics):
        vals = [float(r[m.key]) for r in runs if r.get(m.key) is not None]
        notes = "; ".join(x for x in (m.notes, probe.notes if i == 0 else "") if x)
        out.append(Result(suite_name, m.name, m.unit, vals, 1, notes,
                          None if vals else f"no {m.key!r} in any run"))
    return out


def run_suite(ctx: Context, name: str) -> tuple[list[Result], dict]:
    """Run one suite; returns its results and a status dict (ok / skipped / error)."""
    results: list[Result] = []
    status = {"name": name, "status": "ok"}
    ctx.progress(f"[{name}] {getattr(SUITES[name], 'description', '')}")
    t0 = time.monotonic()
    try:
        cases = SUITES[name](ctx)
        with contextlib.closing(cases) if hasattr(cases, "close") else contextlib.nullcontext():
            for case in cases:
                label = case.name
                try:
                    if isinstance(case, Probe):
                        got = run_probe(ctx, name, case)
                    else:
                        got = [run_case(ctx, name, case)]
                except Skip as exc:
                    ctx.progress(f"  [{name}] {label}: skipped: {exc}")
                    continue
                except (KeyboardInterrupt, GeneratorExit):
                    raise
                except Exception as exc:
                    msg = f"{type(exc).__name__}: {exc}"
                    ctx.progress(f"  [{name}] {label}: FAILED: {msg}")
                    got = [Result(name, label, getattr(case, "unit", "s"), [], error=msg)]
                for r in got:
                    results.append(r)
                    if r.samples:
                        ctx.progress(f"  [{name}] {r.name}: {fmt_value(stats(r.samples)['median'], r.unit)}"
                                     f" (median of {len(r.samples)} x {r.number})")
    except Skip as exc:
        status = {"name": name, "status": "skipped", "reason": str(exc)}
        ctx.progress(f"[{name}] skipped: {exc}")
    except KeyboardInterrupt:
        raise
    except Exception as exc:
        status = {"name": name, "status": "error", "reason": f"{type(exc).__name__}: {exc}"}
        ctx.progress(f"[{name}] FAILED: {status['reason']}")
    status["wall_time_s"] = time.monotonic() - t0
    if status["status"] == "ok" and any(r.error for r in results):
        status["status"] = "error"
    return results, status


# ============================================================================ report
def machine_info() -> dict:
    from importlib.metadata import PackageNotFoundError, version
    vers = {}
    for pkg in ("dartpy", "eclipse-zenoh", "rosbags", "numpy", "fmpy"):
        try:
            vers[pkg] = version(pkg)
        except PackageNotFoundError:
            vers[pkg] = None
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        affinity = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        affinity = None
    try:
        load = list(os.getloadavg())
    except OSError:
        load = None
    return {"cpu_count": os.cpu_count(), "cpus_usable": affinity, "cpu_model": cpu,
            "platform": platform.platform(), "python": platform.python_version(),
            "python_implementation": platform.python_implementation(),
            "versions": vers, "load_avg_start": load,
            "started": datetime.datetime.now().astimezone().isoformat(timespec="seconds")}


def fmt_value(v: float | None, unit: str, scale: tuple[float, str] | None = None) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if unit == "s":
        f, u = scale or time_scale(v)
        return f"{_num(v / f)} {u}"
    if unit == "x":
        return f"{_num(v)} xRT"
    return f"{_num(v)} {unit}"


def time_scale(v: float) -> tuple[float, str]:
    a = abs(v)
    if a < 1e-6:
        return 1e-9, "ns"
    if a < 1e-3:
        return 1e-6, "µs"
    if a < 1.0:
        return 1e-3, "ms"
    return 1.0, "s"


def _num(x: float) -> str:
    a = abs(x)
    if a >= 100:
        return f"{x:.0f}"
    if a >= 10:
        return f"{x:.1f}"
    return f"{x:.2f}"


def table(results: list[Result], statuses: list[dict], info: dict) -> str:
    v = info["versions"]
    lines = [
        f"diffbot bench  {info['started']}",
        f"machine: {info['cpu_count']} CPUs ({info['cpu_model']}), {info['platform']}",
        f"python {info['python']}, dartpy {v.get('dartpy')}, eclipse-zenoh {v.get('eclipse-zenoh')}, "
        f"rosbags {v.get('rosbags')}, numpy {v.get('numpy')}; load avg at start "
        + (" ".join(f"{x:.2f}" for x in info["load_avg_start"]) if info.get("load_avg_start")
           else "n/a"),
        "",
    ]
    head = ["suite", "case", "median", "min", "p90", "max", "n", "notes"]
    rows = []
    for r in results:
        if r.error:
            rows.append([r.suite, r.name, "FAILED", "", "", "", "", r.error])
            continue
        s = stats(r.samples)
        sc = time_scale(s["median"]) if r.unit == "s" else None
        rows.append([r.suite, r.name, *(fmt_value(s[k], r.unit, sc)
                                         for k in ("median", "min", "p90", "max")),
                     f"{len(r.samples)}x{r.number}" if r.number > 1 else str(len(r.samples)),
                     r.notes])
    for st in statuses:
        if st["status"] == "skipped":
            rows.append([st["name"], "(suite)", "skipped", "", "", "", "", st["reason"]])
        elif st["status"] == "error" and "reason" in st:
            rows.append([st["name"], "(suite)", "FAILED", "", "", "", "", st["reason"]])
    widths = [max([len(head[i])] + [len(row[i]) for row in rows]) for i in range(len(head) - 1)]
    right = {2, 3, 4, 5, 6}

    def line(cells):
        out = [c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(cells, widths))]
        return "  ".join(out + [cells[-1]]).rstrip()
    lines.append(line(head))
    lines.append(line(["-" * w for w in widths] + ["-----"]))
    prev = None
    for row in rows:
        if prev is not None and row[0] != prev:
            lines.append("")
        lines.append(line(row))
        prev = row[0]
    lines += ["", "n = repeats x operations per repeat (subprocess suites: runs); times are per "
                  "operation; xRT = simulated seconds per wall second."]
    return "\n".join(lines)


# ============================================================================ processes
def _spawn(args: list[str], log_path: str, module: str = "diffbot.cli") -> subprocess.Popen:
    """Start ``python -m module args`` in its own session, output to ``log_path``."""
    log = open(log_path, "wb")
    try:
        return subprocess.Popen([sys.executable, "-m", module, *args], cwd=ROOT,
                                env=dict(os.environ, PYTHONUNBUFFERED="1"),
                                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
    finally:
        log.close()


def _stop(procs: list[subprocess.Popen], grace_s: float = 3.0) -> None:
    """SIGINT every process still running, wait ``grace_s``, then SIGKILL it (by PID)."""
    for p in procs:
        if p.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                p.send_signal(signal.SIGINT)
    deadline = time.monotonic() + grace_s
    for p in procs:
        try:
            p.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                p.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(5)


def _tail(path: str, n: int = 8) -> str:
    try:
        with open(path, "rb") as f:
            return " | ".join(f.read().decode("utf-8", "replace").strip().splitlines()[-n:])
    except OSError:
        return ""


def _private_endpoint(ctx: Context, tag: str) -> tuple[str, str]:
    d = tempfile.mkdtemp(prefix=f"{tag}-", dir=ctx.tmpdir)
    return d, f"unixsock-stream/{d}/bus.sock"


# ============================================================================ suites
@suite("physics", "one DART physics step and one control tick of the robot")
def physics_suite(ctx: Context):
    from plant.sim import Simulation
    from plant.world import load_world
    from time import perf_counter
    for world in ("empty", "living_room"):
        spec = load_world(world)
        sim = Simulation(spec)
        robot = next(iter(sim.robots))
        for _ in range(10):  # let the drive limiter ramp the targets up to the command
            sim.command_wheels(robot, 1.0, -1.0)
        robots, w = list(sim.robots.values()), sim.world
        detector = type(w.getConstraintSolver().getCollisionDetector()).__name__
        n = len(sim.objects)
        what = (f"{n} static object{'' if n == 1 else 's'}, {detector}, dt {spec.physics_step_s * 1e3:g} ms,"
                f" robot spinning in place (wheels -/+1 rad/s)")

        def step(number, robots=robots, w=w):
            it = range(number)
            t0 = perf_counter()
            for _ in it:
                for r in robots:
                    r.apply()
                w.step()
            return perf_counter() - t0
        yield Case(f"{world}: physics step", step, timer=True, notes=what)
        yield Case(f"{world}: control tick ({spec.substeps} steps)", sim.step_tick,
                   notes="Simulation.step_tick()")
        yield Case(f"{world}: build world", lambda spec=spec: Simulation(spec),
                   notes="Simulation(spec): what a reset costs")


def _sensor_scene(world: str, robot: str):
    """(spec, sim, robot state, Scene) of a shipped world with its robots at their start."""
    from plant.raycast import Scene
    from plant.sim import Simulation
    from plant.world import load_world
    spec = load_world(world)
    sim = Simulation(spec)
    return spec, sim, sim.state(robot), Scene(sim.shapes())


@suite("lidar", "one 180-ray lidar sweep in the living room")
def lidar_suite(ctx: Context):
    from plant import lidar
    from plant.raycast import Scene
    spec, sim, st, scene = _sensor_scene("living_room", "robot1")
    cfg = spec.robot("robot1").sensors.lidar or lidar.LidarConfig()
    where = (f"{len(scene)} shapes (floor, 4 walls, {len(spec.objects)} objects, the robot), "
             f"{cfg.num_rays} rays over {cfg.fov_rad:.3g} rad, max range {cfg.max_range_m:g} m")
    yield Case("sweep 180 rays", lambda: lidar.scan(cfg, st.tf, scene, exclude_owner="robot1"),
               notes=where + "; target <= 0.3 ms")
    yield Case("sweep + noise", lambda: lidar.measure(cfg, st.tf, scene, None, "robot1"),
               notes="lidar.measure: sweep, clip, (no) noise: what the plant calls")
    yield Case("scene snapshot", lambda: Scene(sim.shapes()),
               notes="world shapes -> arrays, once per tick a lidar or camera is due")


@suite("camera", "pinhole camera frames in the living room (follow world)")
def camera_suite(ctx: Context):
    from dataclasses import replace

    from plant import camera as cam
    spec, sim, st, scene = _sensor_scene("living_room_follow", "follower")
    base = spec.robot("follower").sensors.camera or cam.CameraConfig()
    pose = cam.camera_pose(base, st.tf)
    where = f"{len(scene)} shapes, the leader and its green ball in view"
    for (w, h), target in (((160, 120), 3e-3), ((320, 240), 10e-3)):
        cfg = replace(base, width=w, height=h)
        cam.render(cfg, pose, scene, exclude_owner="follower")    # rays cached per size
        yield Case(f"render {w}x{h}", lambda cfg=cfg: cam.render(cfg, pose, scene, "follower"),
                   notes=f"{where}; target <= {target * 1e3:g} ms")
    dist = replace(base, k1=-0.25, k2=0.08, p1=0.001, p2=-0.001)
    cam.render(dist, pose, scene, exclude_owner="follower")
    yield Case("render 160x120, lens distortion", lambda: cam.render(dist, pose, scene, "follower"),
               notes="k1 -0.25, k2 0.08, p1 0.001, p2 -0.001 (per-pixel rays, tiled culling)")
    yield Case("third-person 640x480", lambda: cam.third_person((-2.5, -2.0, 2.2), (0, 0, 0), scene),
               notes="figure 1's kind of picture, from above the room")


def codec_messages() -> dict:
    """One message of each type the bus carries: type name -> message."""
    import numpy as np
    from bus import codec
    t = 12_345_678_901
    T = codec.TYPESTORE.types
    rng = np.random.default_rng(0)
    image = T["sensor_msgs/msg/Image"](
        header=codec.header(t, "camera"), height=120, width=160, encoding="rgb8",
        is_bigendian=0, step=160 * 3, data=rng.integers(0, 256, 160 * 120 * 3, dtype=np.uint8))
    scan = T["sensor_msgs/msg/LaserScan"](
        header=codec.header(t, "lidar"), angle_min=-math.pi / 2, angle_max=math.pi / 2,
        angle_increment=math.pi / 179, time_increment=0.0, scan_time=0.02, range_min=0.05,
        range_max=80.0, ranges=rng.uniform(0.5, 8.0, 180).astype(np.float32),
        intensities=np.zeros(0, dtype=np.float32))
    return {
        "JointState": codec.joint_state(t, ["left_wheel_joint", "right_wheel_joint"],
                                        [1.5, -2.5], [1.0, -1.0]),
        "TwistStamped": codec.twist_stamped(t, 0.3, 0.5),
        "Odometry": codec.odometry(t, 1.0, 2.0, 0.3, 0.2, 0.1),
        "PointStamped": codec.point_stamped(t, 1.0, 2.0, 0.0),
        "Clock": codec.clock(t),
        "Image 160x120 rgb8": image,
        "LaserScan 180 rays": scan,
    }


@suite("codec", "CDR encode / decode of every bus message type (bus.codec)")
def codec_suite(ctx: Context):
    from bus import codec
    fast = getattr(codec, "_FAST", {})  # types with hand-written encoders (same bytes as rosbags)
    ts = codec.TYPESTORE
    cases = []
    for label, msg in codec_messages().items():
        data = codec.encode(msg)
        mt = msg.__msgtype__
        size = f"{len(data)} B"
        cases.append(Case(f"encode {label}", lambda m=msg: codec.encode(m),
                          notes=f"{size}, hand-written CDR" if mt in fast else size))
        if mt in fast:
            cases.append(Case(f"encode {label} (rosbags)",
                              lambda m=msg, mt=mt: bytes(ts.serialize_cdr(m, mt)),
                              notes=f"{size}, for comparison: what codec.encode replaced"))
        cases.append(Case(f"decode {label}", lambda d=data, mt=mt: codec.decode(d, mt), notes=size))
    return cases


PING, PONG = "diffbot_bench/ping", "diffbot_bench/pong"


def echo_main(endpoint: str) -> int:
    """The bus suite's child: echo every sample on PING back on PONG until b"stop"."""
    from bus.session import open_session
    parent = os.getppid()

    def orphan_watch():  # never outlive the benchmark, even if it was SIGKILLed
        while True:
            time.sleep(0.5)
            if os.getppid() != parent:
                os._exit(0)
    threading.Thread(target=orphan_watch, daemon=True).start()
    s = open_session("node", endpoint)
    try:
        pub = s.declare_publisher(PONG)
        sub = s.declare_subscriber(PING)
        while True:
            data = sub.recv().payload.to_bytes()
            if data == b"stop":
                return 0
            pub.put(data)
    finally:
        s.close()


@suite("bus", "Zenoh round trip to an echo process (router here, client there, unix socket)")
def bus_suite(ctx: Context):
    from time import perf_counter

    from bus.session import open_session
    d, endpoint = _private_endpoint(ctx, "bus")
    session = open_session("plant", endpoint)
    child = None
    dead = threading.Event()
    done = threading.Event()
    try:
        pub = session.declare_publisher(PING)
        sub = session.declare_subscriber(PONG)
        child = _spawn(["--echo", endpoint], os.path.join(d, "echo.log"), module="diffbot.bench")

        def watch():  # a dead echo process must not leave recv() blocked forever
            while not done.wait(0.1):
                if child.poll() is not None:
                    dead.set()
                    with contextlib.suppress(Exception):
                        session.put(PONG, b"")  # our own subscriber sees our own puts
        threading.Thread(target=watch, daemon=True).start()
        deadline = time.monotonic() + 30
        while True:  # say hello until the echo answers (its subscriber is then routed)
            if dead.is_set() or time.monotonic() > deadline:
                raise RuntimeError(f"echo process did not answer: {_tail(os.path.join(d, 'echo.log'))}")
            pub.put(b"hello")
            got = None
            t_end = time.monotonic() + 0.1
            while got is None and time.monotonic() < t_end:
                got = sub.try_recv()
                if got is None:
                    time.sleep(0.002)
            if got is not None:
                break
        time.sleep(0.2)
        while sub.try_recv() is not None:  # drop stray hellos
            pass

        for size, label in ((64, "64 B"), (160 * 120 * 3, "57.6 KB (160x120 rgb8)")):
            if dead.is_set():
                raise RuntimeError("echo process died")
            payload = os.urandom(size)
            pub.put(payload)
            echoed = sub.recv().payload.to_bytes()
            if echoed != payload:
                raise RuntimeError(f"echo returned {len(echoed)} B for {size} B")

            def rtt(number, payload=payload):
                it = range(number)
                t0 = perf_counter()
                for _ in it:
                    pub.put(payload)
                    sub.recv()
                    if dead.is_set():
                        raise RuntimeError("echo process died")
                return perf_counter() - t0
            notes = "put + blocking FIFO recv, echo in another process"
            if size > 3000:
                notes += "; Zenoh shared memory on by default above ~3 KB"
            yield Case(f"round trip {label}", rtt, timer=True, notes=notes)
    finally:
        done.set()
        if child is not None:
            if child.poll() is None:
                with contextlib.suppress(Exception):
                    session.put(PING, b"stop")
                with contextlib.suppress(subprocess.TimeoutExpired):
                    child.wait(2)
            _stop([child], grace_s=1.0)
        session.close()
        shutil.rmtree(d, ignore_errors=True)


LOCKSTEP_NODE = "bench_node"


def run_plant(ctx: Context, mode: str, duration_s: float, with_node: bool) -> dict:
    """One ``diffbot plant --world empty`` run (with one trivial lockstep node, or none).

    Returns the plant's stats plus derived per-tick numbers in seconds.
    """
    d, endpoint = _private_endpoint(ctx, "ls")
    stats_path = os.path.join(d, "plant.json")
    procs: list[subprocess.Popen] = []
    try:
        args = ["plant", "--world", "empty", "--mode", mode, "--duration", f"{duration_s:g}",
                "--stats", stats_path, "--endpoint", endpoint, "--log-level", "WARNING"]
        if with_node:
            args += ["--expect", LOCKSTEP_NODE]
        plant = _spawn(args, os.path.join(d, "plant.log"))
        procs.append(plant)
        if with_node:
            procs.append(_spawn(["controller", "wheel_schedule", "--schedule", "1000:1,1",
                                 "--name", LOCKSTEP_NODE, "--endpoint", endpoint,
                                 "--log-level", "WARNING"], os.path.join(d, "node.log")))
        try:
            rc = plant.wait(timeout=60 + 20 * duration_s)
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"plant did not finish: {_tail(os.path.join(d, 'plant.log'))}") \
                from None
        if rc != 0 or not os.path.exists(stats_path):
            raise RuntimeError(f"plant exited {rc}: {_tail(os.path.join(d, 'plant.log'))}")
        with open(stats_path) as f:
            st = json.load(f)
    finally:
        _stop(procs)
        shutil.rmtree(d, ignore_errors=True)
    ticks = max(int(st.get("ticks") or 0), 1)
    per = st.get("per_tick_ms", {})
    wall_tick = st["wall_time_s"] / ticks
    physics = per.get("physics", 0.0) * 1e-3
    return {"rtf": st.get("real_time_factor"), "tick_s": wall_tick, "physics_s": physics,
            "overhead_s": wall_tick - physics, "publish_s": per.get("publish", 0.0) * 1e-3,
            "wait_s": per.get("wait", 0.0) * 1e-3, "ticks": ticks}


@suite("lockstep", "plant tick overhead: lockstep with one trivial node vs fast with none")
def lockstep_suite(ctx: Context):
    duration = 2.0 if ctx.quick else 10.0
    warm = 0 if ctx.quick else 1
    reps = 2 if ctx.quick else None
    tick = f"empty world, {duration:g} s sim = {int(round(duration / 0.02))} ticks"
    yield Probe("lockstep + 1 node", lambda: run_plant(ctx, "lockstep", duration, True), [
        Metric("overhead_s", "lockstep: tick overhead (wall - physics)", notes=tick),
        Metric("publish_s", "lockstep: publish per tick", notes="sensors + clock"),
        Metric("wait_s", "lockstep: wait for node per tick",
               notes="wheel_schedule node answers each tick"),
        Metric("physics_s", "lockstep: physics per tick", notes="20 steps"),
        Metric("rtf", "lockstep: real-time factor", "x"),
    ], repeats=reps, warmup=warm)
    yield Probe("fast, no node", lambda: run_plant(ctx, "fast", duration, False), [
        Metric("overhead_s", "fast: tick overhead (wall - physics)", notes=tick),
        Metric("physics_s", "fast: physics per tick", notes="20 steps"),
        Metric("rtf", "fast: real-time factor", "x"),
    ], repeats=reps, warmup=warm)


def run_scenario(ctx: Context, name: str, timeout_s: float = 900.0) -> dict:
    """One ``diffbot run NAME --out TMP`` run; returns its summary.json."""
    out = tempfile.mkdtemp(prefix=f"{name}-", dir=ctx.tmpdir)
    proc = None
    try:
        proc = _spawn(["run", name, "--out", out, "--timeout", f"{timeout_s:g}"],
                      os.path.join(out, "run.log"))
        try:
            rc = proc.wait(timeout=timeout_s + 60)
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"diffbot run {name} did not finish") from None
        try:
            with open(os.path.join(out, "summary.json")) as f:
                summary = json.load(f)
        except (OSError, ValueError):
            raise RuntimeError(f"diffbot run {name} exited {rc} without a summary: "
                               f"{_tail(os.path.join(out, 'run.log'))}") from None
        if rc != 0:
            raise RuntimeError(f"diffbot run {name} exited {rc}: {summary.get('end_reason')}")
        return summary
    finally:
        if proc is not None:
            _stop([proc], grace_s=15.0)  # the launcher stops its own children on SIGINT
        shutil.rmtree(out, ignore_errors=True)


@suite("scenario", "the square and follow scenarios end to end in lockstep (diffbot run)")
def scenario_suite(ctx: Context):
    for name in ("square", "follow"):
        yield Probe(name, lambda name=name: run_scenario(ctx, name), [
            Metric("real_time_factor", f"{name}: real-time factor", "x",
                   notes="summary.json real_time_factor (plant, lockstep)"),
            Metric("wall_time_s", f"{name}: wall time",
                   notes="whole run incl. start-up, analysis"),
            Metric("sim_time_s", f"{name}: simulated time"),
        ], repeats=1 if ctx.quick or name == "follow" else 3, warmup=0, notes="no warm-up run")


@suite("fmu", "odometry FMU steps (timed by fmus/bench.py, when it exists)")
def fmu_suite(ctx: Context):
    path = os.path.join(ROOT, "fmus", "bench.py")
    if not os.path.exists(path):
        raise Skip("fmus/bench.py not available")
    try:
        import importlib
        mod = importlib.import_module("fmus.bench")
        benchmarks = mod.benchmarks
    except Exception as exc:
        raise Skip(f"fmus/bench.py not usable: {type(exc).__name__}: {exc}") from None
    try:
        items = list(benchmarks())
    except Exception as exc:
        raise Skip(f"fmus.bench.benchmarks() failed: {type(exc).__name__}: {exc}") from None
    return [Case(name, fn, timer=True, notes=desc) for name, desc, fn in items]


# ============================================================================ CLI
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="diffbot bench", description="Run benchmark suites and "
                                "print median / min / p90 / max per operation.")
    p.add_argument("--suite", action="append", default=[], metavar="NAME",
                   help="suite to run (repeatable or comma-separated; default: all)")
    p.add_argument("--quick", action="store_true", help="fewer repeats, smaller runs")
    p.add_argument("--repeats", type=int, default=None, metavar="N",
                   help=f"repeats per case (default {DEFAULT_REPEATS}, --quick {QUICK_REPEATS}; "
                        "some suites use fewer)")
    p.add_argument("--json", metavar="FILE", help="also write machine info and every case as JSON")
    p.add_argument("--list", action="store_true", help="list the suites and exit")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.list:
        for name, fn in SUITES.items():
            print(f"{name:10s} {getattr(fn, 'description', '')}")
        return 0
    names = [n.strip() for s in args.suite for n in s.split(",") if n.strip()] or list(SUITES)
    unknown = [n for n in names if n not in SUITES]
    if unknown:
        print(f"diffbot bench: unknown suite {', '.join(map(repr, unknown))} "
              f"(known: {', '.join(SUITES)})", file=sys.stderr)
        return 2
    if args.repeats is not None and args.repeats < 1:
        print(f"diffbot bench: --repeats must be >= 1, got {args.repeats}", file=sys.stderr)
        return 2
    names = list(dict.fromkeys(names))
    info = machine_info()
    tmp = tempfile.mkdtemp(prefix="dbb-")
    ctx = Context(quick=args.quick, repeats=args.repeats, tmpdir=tmp)
    results: list[Result] = []
    statuses: list[dict] = []
    interrupted = False
    try:
        for name in names:
            got, st = run_suite(ctx, name)
            results += got
            statuses.append(st)
    except KeyboardInterrupt:
        interrupted = True
        print("diffbot bench: interrupted; reporting what finished", file=sys.stderr)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    with contextlib.suppress(OSError):
        info["load_avg_end"] = list(os.getloadavg())
    print(table(results, statuses, info))
    if args.json:
        doc = {"tool": "diffbot bench", "format": 1, "machine": info,
               "options": {"suites": names, "quick": args.quick, "repeats": args.repeats},
               "suites": statuses, "cases": [r.as_dict() for r in results],
               "interrupted": interrupted}
        with open(args.json, "w") as f:
            json.dump(doc, f, indent=2, allow_nan=False, default=str)
            f.write("\n")
        print(f"diffbot bench: wrote {args.json}", file=sys.stderr)
    if interrupted:
        return 130
    return 1 if any(st["status"] == "error" for st in statuses) else 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--echo"] and len(sys.argv) == 3:
        sys.exit(echo_main(sys.argv[2]))
    sys.exit(main())
