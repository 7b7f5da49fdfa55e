"""Endurance: one hour of simulated time, in lockstep, with every sensor on.

    make soak                     # SOAK_SIM_S=600 make soak for a 10-minute one

The square path is driven lap after lap (``--laps``) in the living room, with lidar and
camera on, the odometry FMU node (or the Python one), under ``diffbot run``. Pinned down:

* resident memory (VmRSS from /proc/<pid>/status) of every process grows < 5 % from the
  end of the warm-up (10 % of the run, at least 60 s simulated) to the end;
* no lockstep message is lost: the plant's clock ticks, every member's acted ticks, their
  odom and cmd_vel counts and what a bystander subscriber heard all agree; nothing rejected;
* no /dev/shm segment is left behind once the run is over.

It writes its numbers to ``out/soak/soak.json`` (``SOAK_OUT`` to change) and prints them.
"""
from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import pytest

from ..conftest import ROOT
from ..runs.test_scenarios import processes_mentioning

SIM_S = float(os.environ.get("SOAK_SIM_S", "3600"))
OUT = os.environ.get("SOAK_OUT", os.path.join(ROOT, "out", "soak"))
SAMPLE_S = 5.0
MAX_GROWTH = 0.05

pytestmark = [pytest.mark.soak, pytest.mark.slow]


def rss_kb(pid: int) -> int | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def shm_of(pid: int) -> set[str]:
    """/dev/shm files a process has open or mapped (other processes' are not ours)."""
    out = set()
    try:
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if target.startswith("/dev/shm/"):
                out.add(target)
        with open(f"/proc/{pid}/maps") as f:
            for line in f:
                if "/dev/shm/" in line:
                    out.add(line[line.index("/dev/shm/"):].split(" (deleted)")[0].strip())
    except OSError:
        pass
    return out


def scenario_text(sim_s: float) -> str:
    fmu = os.path.join(ROOT, "fmus", "build", "odometry_fmi2.fmu")
    if os.path.exists(os.path.join(ROOT, "fmus", "fmu_node.py")) and os.path.exists(fmu):
        odometry = f'["fmu-node", "{fmu}", "--robot", "robot1"]'
    else:
        odometry = '["controller", "odometry", "--robot", "robot1"]'
    return f"""
[scenario]
description = "soak: the square, lap after lap, lidar and camera on"
world = "living_room"
mode = "lockstep"
duration_s = {sim_s}
analysis = "none"
robot = "robot1"

[[process]]
name = "odometry_robot1"
command = {odometry}

[[process]]
name = "square_path_robot1"
command = ["controller", "square_path", "--robot", "robot1", "--side", "1.5", "--laps", "100000"]
"""


class ClockCounter:
    def __init__(self, endpoint: str) -> None:
        from bus import codec
        from bus.keys import Keys
        from bus.session import open_session
        self.codec = codec
        self.session = open_session("soak", endpoint)
        self.lock = threading.Lock()
        self.n = 0
        self.t_ns = 0
        self.sub = self.session.declare_subscriber(Keys().clock, self._on)

    def _on(self, s) -> None:
        t = self.codec.msg_stamp_ns(self.codec.decode(s.payload.to_bytes(),
                                                      "rosgraph_msgs/msg/Clock"))
        with self.lock:
            self.n += 1
            self.t_ns = t

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


@pytest.mark.timeout(6 * 3600)
def test_one_hour_lockstep_soak():
    shutil.rmtree(OUT, ignore_errors=True)
    os.makedirs(OUT)
    scen = os.path.join(OUT, "soak.toml")
    with open(scen, "w") as f:
        f.write(scenario_text(SIM_S))
    tmp = tempfile.mkdtemp(prefix="dbsoak-")
    endpoint = f"unixsock-stream/{tmp}/bus.sock"
    shm_ours: set[str] = set()
    run_dir = os.path.join(OUT, "run")
    launcher = subprocess.Popen(
        [sys.executable, "-m", "diffbot.cli", "run", scen, "--out", run_dir, "--endpoint",
         endpoint, "--timeout", str(12 * SIM_S + 600)], cwd=ROOT,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    samples: list[dict] = []          # {wall, sim, name, rss_kb}
    shm_max = 0
    counter = None
    wall0 = time.monotonic()
    try:
        while launcher.poll() is None and counter is None:
            try:
                counter = ClockCounter(endpoint)
            except Exception:
                time.sleep(0.5)
        next_print = 0.0
        while launcher.poll() is None:
            with counter.lock:
                sim = counter.t_ns * 1e-9
            pids = {"launcher": launcher.pid}
            for pid in processes_mentioning(run_dir):
                cmd = open(f"/proc/{pid}/cmdline", "rb").read().split(b"\0")
                for name in ("plant", "odometry_robot1", "square_path_robot1"):
                    if f"{run_dir}/logs/{name}.json".encode() in cmd:
                        pids[name] = pid
            for name, pid in pids.items():
                kb = rss_kb(pid)
                if kb is not None:
                    samples.append({"wall": time.monotonic() - wall0, "sim": sim,
                                    "name": name, "rss_kb": kb})
            now_shm = set()
            for pid in pids.values():
                now_shm |= shm_of(pid)
            shm_ours |= now_shm
            shm_max = max(shm_max, len(now_shm))
            if time.monotonic() - wall0 > next_print:
                next_print += 60
                print(f"[soak] wall {time.monotonic() - wall0:7.0f} s  sim {sim:7.0f} s  "
                      + "  ".join(f"{n} {rss_kb(p) or 0:,} kB" for n, p in pids.items()),
                      flush=True)
            time.sleep(SAMPLE_S)
        _, err = launcher.communicate(timeout=120)
    finally:
        if launcher.poll() is None:
            launcher.kill()
        heard = None
        if counter is not None:
            with counter.lock:
                heard = counter.n
            counter.close()
        shutil.rmtree(tmp, ignore_errors=True)
    wall = time.monotonic() - wall0
    # Zenoh unlinks a segment once no process maps it; give the last exits a moment.
    deadline = time.monotonic() + 15
    while any(os.path.exists(f) for f in shm_ours) and time.monotonic() < deadline:
        time.sleep(0.5)
    # A segment this test process still maps (its bystander session received shared-memory
    # samples; Zenoh keeps them mapped until the process exits) is not the run's leak.
    mine = shm_of(os.getpid())
    shm_left = sorted(f for f in shm_ours if os.path.exists(f) and f not in mine)

    summary = json.load(open(os.path.join(run_dir, "summary.json")))
    stats = {n: json.load(open(os.path.join(run_dir, "logs", f"{n}.json")))
             for n in ("plant", "odometry_robot1", "square_path_robot1")}
    clocks = stats["plant"]["published"]["sim/clock"]

    warm = max(0.1 * SIM_S, 60.0)
    growth = {}
    for name in ("launcher", "plant", "odometry_robot1", "square_path_robot1"):
        series = [s for s in samples if s["name"] == name and s["sim"] >= warm]
        if len(series) < 4:
            continue
        k = min(5, len(series) // 2)
        base = statistics.median(s["rss_kb"] for s in series[:k])
        end = statistics.median(s["rss_kb"] for s in series[-k:])
        growth[name] = {"after_warmup_kb": base, "end_kb": end,
                        "max_kb": max(s["rss_kb"] for s in series),
                        "growth": (end - base) / base}
    report = {
        "sim_time_s": summary["sim_time_s"], "wall_time_s": wall,
        "real_time_factor": summary["real_time_factor"], "exit_codes": summary["exit_codes"],
        "end_reason": summary["end_reason"], "rss": growth,
        "clock_ticks_published": clocks, "clock_ticks_heard_by_a_bystander": heard,
        "ticks_acted": {n: stats[n]["ticks"] for n in ("odometry_robot1", "square_path_robot1")},
        "odom_published": stats["odometry_robot1"]["published"].get("robot1/odom"),
        "cmd_vel_published": stats["square_path_robot1"]["published"].get("robot1/cmd_vel"),
        "rejected": summary["rejected"],
        "shm_segments_of_the_run": sorted(shm_ours), "shm_segments_open_at_once": shm_max,
        "shm_segments_left": shm_left, "shm_segments_still_mapped_by_the_test": sorted(
            f for f in shm_ours if os.path.exists(f) and f in mine),
        "messages": summary["message_counts"],
    }
    with open(os.path.join(OUT, "soak.json"), "w") as f:
        json.dump(report, f, indent=2)
    print("[soak] " + json.dumps({k: v for k, v in report.items() if k != "messages"},
                                 indent=2))

    assert launcher.returncode == 0, err
    assert summary["sim_time_s"] == pytest.approx(SIM_S, abs=0.05)
    for name, g in growth.items():
        assert g["growth"] < MAX_GROWTH, f"{name}: RSS grew {100 * g['growth']:.1f} % ({g})"
    assert set(growth) >= {"plant", "odometry_robot1", "square_path_robot1"}
    # lockstep: every member acted on every tick the plant published, nothing was lost
    assert report["ticks_acted"] == {"odometry_robot1": clocks, "square_path_robot1": clocks}
    assert report["odom_published"] == clocks and report["cmd_vel_published"] == clocks
    assert heard == clocks
    assert all(not r for r in summary["rejected"].values()), summary["rejected"]
    assert not shm_left, f"/dev/shm segments left behind: {shm_left}"
