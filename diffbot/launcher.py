"""``diffbot run``: start a scenario's processes, supervise them, analyse the run.

Each process is its own OS process in its own session (process group), so the
launcher decides the order of shutdown: on Ctrl-C, SIGTERM, the end of the run
or a failure, it sends SIGINT to every child, waits, then SIGKILLs what is left,
by PID. A required process that dies ends the run with a non-zero exit code and
its last stderr lines; an optional one may die alone. A process marked
``ends_run`` that exits 0 ends the run normally.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import deque
from dataclasses import dataclass, field

from bus.keys import Keys
from bus.node import write_json
from bus.session import BusConfigError, open_session
from plant.world import WorldError, load_world

from .scenario import ScenarioSpec, load_scenario

STOP_GRACE_S = 1.5
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


@dataclass
class Child:
    name: str
    argv: list[str]
    required: bool = True
    ends_run: bool = False
    interactive: bool = False
    log_path: str = ""
    proc: subprocess.Popen | None = None
    exit_code: int | None = None
    started: float = 0.0
    log_file: object = None

    def start(self, env: dict) -> None:
        self.log_file = open(self.log_path, "wb")
        kw = dict(env=env, stderr=self.log_file)
        if self.interactive:
            self.proc = subprocess.Popen(self.argv, **kw)
        else:
            self.proc = subprocess.Popen(self.argv, stdin=subprocess.DEVNULL, stdout=self.log_file,
                                         start_new_session=True, **kw)
        self.started = time.monotonic()

    def poll(self) -> int | None:
        if self.proc is not None and self.exit_code is None:
            self.exit_code = self.proc.poll()
        return self.exit_code

    def signal(self, sig: int) -> None:
        if self.proc is not None and self.poll() is None:
            try:
                self.proc.send_signal(sig)
            except ProcessLookupError:
                pass

    def tail(self, n: int = 12) -> str:
        try:
            with open(self.log_path, "rb") as f:
                lines = deque(f, maxlen=n)
            return b"".join(lines).decode("utf-8", "replace").rstrip()
        except OSError:
            return ""

    def close(self) -> None:
        if self.log_file is not None:
            self.log_file.close()


def diffbot_argv(*args: str) -> list[str]:
    return [sys.executable, "-m", "diffbot.cli", *args]


@dataclass
class Run:
    spec: ScenarioSpec
    out: str
    mode: str
    seed: int
    endpoint: str
    namespace: str = ""
    zenoh_config: str | None = None
    duration_s: float | None = None
    timeout_s: float = 900.0
    children: list[Child] = field(default_factory=list)
    reason: str = ""
    failed: Child | None = None

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
        expect = [p.name for p in self.spec.processes if p.sync]
        plant = diffbot_argv("plant", "--world", self.spec.world, "--mode", self.mode,
                             "--seed", str(self.seed), "--stats",
                             os.path.join(logs, "plant.json"), *self.spec.plant_args,
                             *self.bus_args())
        if expect:
            plant += ["--expect", ",".join(expect)]
        enders = [p.name for p in self.spec.processes if p.ends_run and p.sync]
        if enders and self.mode == "lockstep":
            plant += ["--end-with", ",".join(enders)]
        if self.duration_s is not None:
            plant += ["--duration", repr(self.duration_s)]
        self.children.append(Child("plant", plant, log_path=os.path.join(logs, "plant.log")))
        for p in self.spec.processes:
            argv = diffbot_argv(*p.command, "--name", p.name, "--stats",
                                os.path.join(logs, f"{p.name}.json"), *self.bus_args())
            self.children.append(Child(p.name, argv, p.required, p.ends_run, p.interactive,
                                       log_path=os.path.join(logs, f"{p.name}.log")))

    def stop_all(self) -> None:
        """SIGINT the nodes, then the plant (so nodes do not see it vanish), then SIGKILL
        by PID whatever is left after the grace period."""
        plant, nodes = self.children[0], self.children[1:]
        for c in nodes:
            c.signal(signal.SIGINT)
        deadline = time.monotonic() + STOP_GRACE_S / 2
        while time.monotonic() < deadline and any(c.poll() is None for c in nodes):
            time.sleep(0.02)
        plant.signal(signal.SIGINT)
        deadline = time.monotonic() + STOP_GRACE_S / 2
        while time.monotonic() < deadline and any(c.poll() is None for c in self.children):
            time.sleep(0.02)
        for c in self.children:
            if c.poll() is None:
                c.signal(signal.SIGKILL)
                try:
                    c.proc.wait(1.0)
                except subprocess.TimeoutExpired:
                    pass
                c.poll()
            c.close()

    def supervise(self, stop_flag: list) -> int:
        start = time.monotonic()
        while True:
            if stop_flag:
                self.reason = f"interrupted ({stop_flag[0]})"
                return EXIT_INTERRUPTED
            for c in self.children:
                code = c.poll()
                if code is None:
                    continue
                if c.name == "plant" or c.required:
                    if code == 0:
                        self.reason = f"{c.name} finished"
                        return 0
                    self.failed = c
                    self.reason = f"{c.name} failed with exit code {code}"
                    return EXIT_FAILED
            if time.monotonic() - start > self.timeout_s:
                self.reason = f"wall-clock timeout after {self.timeout_s:.0f} s"
                return EXIT_FAILED
            time.sleep(0.02)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="diffbot run", description="Run a scenario.")
    p.add_argument("scenario", help="scenario name (see `diffbot scenarios`) or TOML file")
    p.add_argument("--mode", choices=("lockstep", "realtime", "fast"), default=None,
                   help="override the scenario's mode")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S simulated seconds")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="output directory (default out/<scenario>)")
    p.add_argument("--endpoint", default=None,
                   help="Zenoh endpoint (default: a unix socket private to this run)")
    p.add_argument("--namespace", default="")
    p.add_argument("--zenoh-config", default=None, metavar="FILE")
    p.add_argument("--timeout", type=float, default=900.0, metavar="S",
                   help="wall-clock limit for the whole run (default 900)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        spec = load_scenario(args.scenario)
        world = load_world(spec.world)
        keys = Keys(args.namespace)
    except (WorldError, ValueError) as exc:
        print(f"diffbot run: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    from .analysis import ANALYSES
    out = os.path.abspath(args.out or os.path.join("out", spec.name))
    os.makedirs(out, exist_ok=True)
    tmp = None
    endpoint = args.endpoint
    if endpoint is None and args.zenoh_config is None:
        tmp = tempfile.mkdtemp(prefix="diffbot-")
        endpoint = f"unixsock-stream/{tmp}/bus.sock"
    run = Run(spec, out, args.mode or spec.mode, args.seed, endpoint or "", args.namespace,
              args.zenoh_config, args.duration if args.duration is not None else spec.duration_s,
              args.timeout)
    run.build()
    analysis = ANALYSES[spec.analysis]
    stop_flag: list[str] = []

    def on_signal(signum, frame):
        stop_flag.append(signal.Signals(signum).name)
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    observer = session = None
    wall0 = time.monotonic()
    code = EXIT_FAILED
    try:
        run.children[0].start(env)
        try:
            session = open_session("observer", endpoint or "", args.zenoh_config)
        except BusConfigError as exc:
            run.reason = f"cannot connect to the plant: {exc}"
            run.failed = run.children[0]
        if session is not None:
            from .observer import Observer
            observer = Observer(session, keys, analysis.keys(keys, spec, world))
            for c in run.children[1:]:
                c.start(env)
            print(f"diffbot run {spec.name}: {run.mode} mode, seed {run.seed}, "
                  f"{len(run.children)} processes, output in {out}", file=sys.stderr)
            code = run.supervise(stop_flag)
    finally:
        run.stop_all()
        for s, h in old.items():
            signal.signal(s, h)
        wall = time.monotonic() - wall0
        if observer is not None:
            observer.close()
        if session is not None:
            session.close()
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    if run.failed is not None:
        code = EXIT_FAILED if code == 0 else code
        print(f"diffbot run: {run.reason or run.failed.name + ' failed'}\n"
              f"--- last lines of {run.failed.name}'s log ({run.failed.log_path}):\n"
              f"{run.failed.tail()}", file=sys.stderr)
    summary = summarize(run, wall, code)
    if observer is not None:
        try:
            summary["metrics"] = analysis.analyse(observer, keys, spec, world, out)
        except Exception as exc:  # analysis must not lose the summary
            summary["analysis_error"] = f"{type(exc).__name__}: {exc}"
            code = code or EXIT_FAILED
    write_json(os.path.join(out, "summary.json"), summary)
    print(f"diffbot run {spec.name}: {run.reason}; summary in {os.path.join(out, 'summary.json')}",
          file=sys.stderr)
    return code


def summarize(run: Run, wall: float, code: int) -> dict:
    stats = {c.name: _read_json(os.path.join(run.out, "logs", f"{c.name}.json"))
             for c in run.children}
    plant = stats["plant"]
    counts: dict[str, int] = {}
    for st in stats.values():            # every process counts what it published
        for key, n in st.get("published", {}).items():
            counts[key] = counts.get(key, 0) + n
    return {
        "scenario": run.spec.name, "world": run.spec.world, "mode": run.mode, "seed": run.seed,
        "sim_time_s": plant.get("sim_time_s"), "wall_time_s": wall,
        "plant_wall_time_s": plant.get("wall_time_s"),
        "real_time_factor": plant.get("real_time_factor"),
        "end_reason": run.reason, "exit_code": code,
        "exit_codes": {c.name: c.exit_code for c in run.children},
        "message_counts": dict(sorted(counts.items())),
        "rejected": {name: st.get("rejected", {}) for name, st in stats.items()},
    }


def _read_json(path: str) -> dict:
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return {}
