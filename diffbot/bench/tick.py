"""Suite ``tick``: where the plant's own tick goes, function by function.

A sampling profile (py-spy, from PyPI: ``pip install -e '.[test]'`` brings it) of the plant
process of a running ``diffbot run follow``, ``square`` and the 24-robot ``swarm``, a few
seconds after its ticks start. Each sample of the plant's main thread is put in one *phase*:
the first of :data:`PHASES` one of whose marks is in one of its frames. The shares say where a tick goes, and
unlike wall times they hardly move with the machine's load. The phases and the top
functions (self and inclusive) as markdown tables, the way docs/benchmarks.md shows them::

    python -m diffbot.bench.plantprofile follow square swarm [--seconds 6] [--rate 500]
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter

from diffbot.runner import procs

from .common import run_summary, spawn, stop, tail
from .harness import Context, Metric, Probe, Skip, suite

#: (phase, frame marks): a sample goes to the first phase, in this order, one of whose marks
#: is in one of its frames (frames are "function (file:line)"): the camera's ray maths in
#: plant/raycast.py is the camera's, the lidar's noise is noise, not lidar
PHASES: list[tuple[str, tuple[str, ...]]] = [
    ("image noise", ("NoiseModel.prefetch_image", "NoiseModel._take_image_noise",
                     "image_noise (plant/kernels/__init__.py", "frame_seed (plant/noise.py",
                     "prefetch (plant/sensors.py")),
    ("noise (other)", ("(plant/noise.py",)),
    ("camera render", ("(plant/camera.py", "(plant/lens.py")),
    ("scene snapshot", ("Scene.__init__", "Scene.from_shapes", "Scene.placed",
                        "Simulation.scene", "Simulation.shapes",
                        "Simulation.part_transforms", "Stepper.shapes")),
    ("lidar", ("(plant/lidar.py", "(plant/raycast.py", "scan_all (plant/sensors.py")),
    ("encode", ("(bus/codec.py", "(bus/packed.py")),
    ("zenoh put", ("Publisher.put", "(plant/outbox.py", "Plant._put", "Plant._publisher")),
    ("robot state", ("Simulation.state", "(plant/robot.py", "Stepper.state",
                     "state_from_row")),
    ("physics", ("Simulation.step_tick", "(plant/physics_process.py", "Plant.apply_commands",
                 "Stepper.finite")),
    ("waiting for nodes", ("(plant/modes.py", "(bus/lockstep.py", "Plant.drain",
                           "(bus/inbox.py")),
    ("sensor messages", ("RobotSensors.messages", "Plant.publish_sensors")),
]
#: what the plant's main thread samples start with (other threads are zenoh callbacks)
MAIN_ROOT = "_run_module_as_main"

SCENARIOS = {
    "follow": ["--coupling", "pipelined"],
    "square": ["--coupling", "pipelined"],
    "swarm": ["--robots", "24", "--controller-processes", "3", "--coupling", "pipelined",
              "--duration", "30"],
}


def py_spy() -> str:
    """The py-spy executable (next to this Python, else on PATH); Skip if there is none."""
    here = os.path.join(os.path.dirname(sys.executable), "py-spy")
    found = here if os.access(here, os.X_OK) else shutil.which("py-spy")
    if not found:
        raise Skip("py-spy is not installed (pip install py-spy; the [test] extra has it)")
    return found


def phase_of(frames: list[str]) -> str:
    for phase, marks in PHASES:
        if any(m in frame for frame in frames for m in marks):
            return phase
    return "other"


def parse_raw(text: str) -> list[tuple[list[str], int]]:
    """py-spy's ``-f raw`` (collapsed stacks: ``f1;f2;...;leaf COUNT``), main thread only."""
    out = []
    for line in text.splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack or not count.isdigit():
            continue
        frames = stack.split(";")
        if frames[0].startswith(MAIN_ROOT):
            out.append((frames, int(count)))
    return out


def _func(frame: str) -> str:
    """``Plant._put (plant/process.py:276)`` -> ``Plant._put (plant/process.py)``: no line."""
    name, _, where = frame.partition(" (")
    return f"{name} ({where.rsplit(':', 1)[0]})" if where else name


def summarise(stacks: list[tuple[list[str], int]], top: int = 15) -> dict:
    """Phase shares, and the top functions by self and by inclusive share (fractions)."""
    total = sum(c for _, c in stacks) or 1
    phases, selfs, incl = Counter(), Counter(), Counter()
    for frames, c in stacks:
        phases[phase_of(frames)] += c
        selfs[_func(frames[-1])] += c
        for f in {_func(f) for f in frames}:
            incl[f] += c
    return {"samples": total,
            "phases": {p: phases[p] / total for p, _ in [*PHASES, ("other", ())]},
            "self": [(f, c / total) for f, c in selfs.most_common(top)],
            "inclusive": [(f, c / total) for f, c in incl.most_common(top + 12)
                          if c < total][:top]}


def profile_run(scenario: str, extra: list[str], tmpdir: str, seconds: float = 6.0,
                rate: int = 500, settle_s: float = 2.0) -> dict:
    """Start ``diffbot run SCENARIO``, py-spy its plant for ``seconds`` once ``settle_s``
    have passed since the plant started running its ticks, let the run finish; the summary of the profile
    plus the run's real-time factor and per-tick times."""
    spy = py_spy()
    out = tempfile.mkdtemp(prefix=f"tick-{scenario}-", dir=tmpdir)
    run = spawn(["run", scenario, "--out", out, *extra], os.path.join(out, "run.log"))
    try:
        deadline, plant = time.monotonic() + 60, None
        while plant is None and time.monotonic() < deadline and run.running():
            time.sleep(0.1)
            plant = next((p for p in procs.descendants(run.pid) if _is_plant(p)), None)
        if plant is None:
            raise RuntimeError(f"no plant process appeared: {tail(os.path.join(out, 'run.log'))}")
        _wait_until_running(os.path.join(out, "logs", "plant.log"), run, deadline)
        time.sleep(settle_s)
        raw = os.path.join(out, "raw.txt")
        r = subprocess.run([spy, "record", "-p", str(plant), "-d", f"{seconds:g}", "-r",
                            str(rate), "-f", "raw", "-o", raw], capture_output=True, text=True)
        if r.returncode != 0 or not os.path.exists(raw):
            raise RuntimeError(f"py-spy failed: {r.stderr.strip()[-400:]}")
        with open(raw) as f:
            prof = summarise(parse_raw(f.read()))
        # (a run may end non-zero because py-spy's pauses cost the plant its bus lease on a
        # loaded machine: the profile stands, the summary is read if there is one)
        code = run.wait(900)
        summary = run_summary(out, scenario, code)
        prof["exit_code"] = code
        prof["real_time_factor"] = summary.get("real_time_factor")
        prof["plant_per_tick_ms"] = summary.get("plant_per_tick_ms")
        return prof
    finally:
        stop([run], grace_s=15.0)
        shutil.rmtree(out, ignore_errors=True)


def _wait_until_running(log: str, run, deadline: float) -> None:
    """Until the plant says it runs (its nodes joined: a loaded machine takes seconds), so
    that the samples are of ticks, not of start-up."""
    while time.monotonic() < deadline and run.running():
        try:
            with open(log, errors="replace") as f:
                if " running " in f.read():
                    return
        except OSError:
            pass
        time.sleep(0.1)


def _is_plant(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            argv = f.read().split(b"\0")
    except OSError:
        return False
    return b"plant" in argv and b"diffbot.cli" in argv


@suite("tick", "where the plant's tick goes: py-spy phase shares of follow, square and the "
               "24-robot swarm (needs py-spy)")
def tick_suite(ctx: Context):
    py_spy()
    for name, extra in SCENARIOS.items():
        def run(name=name, extra=extra) -> dict:
            p = profile_run(name, extra, ctx.tmpdir, seconds=3.0 if ctx.quick else 6.0)
            return {**{k: v * 100 for k, v in p["phases"].items()},
                    "real_time_factor": p["real_time_factor"]}
        yield Probe(f"{name} plant", run, [
            *(Metric(p, f"{name}: {p}", "%") for p, _ in [*PHASES, ("other", ())]),
            Metric("real_time_factor", f"{name}: real-time factor (while profiled)", "x",
                   notes="py-spy pauses the plant to sample it: slower than unprofiled")],
            repeats=1, warmup=0, notes="share of the plant's main-thread samples")
