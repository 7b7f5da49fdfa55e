"""Bus plumbing for the experiments: a private plant process and lockstep nodes in-process.

:class:`PlantProcess` starts ``diffbot plant`` on a unix-socket endpoint private to the
experiment (no ports shared with anything else) and always stops it by PID: it waits
for the plant to end on its own (``--end-with``), then SIGINT, then SIGKILL.
:func:`run_controller` runs a controller object as a lockstep member of that plant in
this process (:class:`bus.runtime.NodeRunner`), with a wall-clock limit.
:class:`Capture` is the controller that takes the first observation carrying every
input it asks for (tick 0: every sensor is due then) and ends the run.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import threading
import time

from bus.keys import Keys
from bus.log import setup_logging
from bus.runtime import NodeRunner
from bus.session import BusConfigError, open_session

from ..runner import procs
from ..runner.procs import diffbot_argv


class ExperimentError(RuntimeError):
    """An experiment could not run (a process failed); the message says which and why."""


class PlantProcess:
    """``diffbot plant`` in lockstep on a private endpoint; use as a context manager.

    ``sets`` are world overrides (``--set``), ``disable`` sensors to leave off,
    ``node`` the lockstep member the plant waits for and stops with.
    """

    def __init__(self, out: str, tag: str, node: str, world: str = "living_room",
                 sets: list[str] | tuple[str, ...] = (), seed: int = 0,
                 disable: tuple[str, ...] = ()) -> None:
        logs = os.path.join(out, "logs")
        os.makedirs(logs, exist_ok=True)
        self.tag = tag
        self.log_path = os.path.join(logs, f"{tag}.log")
        self.stats_path = os.path.join(logs, f"{tag}.json")
        self.tmp = tempfile.mkdtemp(prefix="dbx-")
        self.endpoint = f"unixsock-stream/{self.tmp}/bus.sock"
        argv = ["plant", "--world", world, "--mode", "lockstep", "--seed", str(seed),
                "--expect", node, "--end-with", node, "--join-timeout", "60",
                "--stats", self.stats_path, "--endpoint", self.endpoint]
        for s in sets:
            argv += ["--set", s]
        if disable:
            argv += ["--disable", ",".join(disable)]
        self.child = procs.Child(tag, diffbot_argv(*argv), self.log_path, die_with_parent=True)

    def __enter__(self) -> "PlantProcess":
        self.child.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def alive(self) -> bool:
        return self.child.running()

    def tail(self, n: int = 10) -> str:
        return self.child.tail(n)

    def stats(self) -> dict:
        try:
            with open(self.stats_path) as f:
                return json.load(f)
        except (OSError, ValueError):
            return {}

    def stop(self, grace_s: float = 1.0) -> int | None:
        """Let the plant finish (it ends with its node), else SIGINT, else SIGKILL, by PID.

        The plant normally ends by itself at the node's final ack (``--end-with``). The
        grace is short on purpose: a plant that missed that ack runs on without members
        (seen before bus.node kept finished nodes until their final ack was in); SIGINT
        ends it cleanly and its stats are still written."""
        if self.child.started and self.child.wait(grace_s) is None:
            self.child.stop(grace_s=3.0)
        self.child.close_log()
        shutil.rmtree(self.tmp, ignore_errors=True)
        return self.child.exit_code


def _wait_for_plant(session, keys: Keys, plant: PlantProcess, timeout_s: float) -> None:
    """Until the plant answers ``sim/info``; fail at once if its process exits."""
    deadline = time.monotonic() + timeout_s
    while True:
        if not plant.alive():
            raise ExperimentError(f"the plant exited (code {plant.child.poll()}); last lines "
                                  f"of {plant.log_path}:\n{plant.tail()}")
        if any(r.ok is not None for r in session.get(keys.info, timeout=0.5)):
            return
        if time.monotonic() > deadline:
            raise ExperimentError(f"the plant did not answer within {timeout_s:.0f} s; last "
                                  f"lines of {plant.log_path}:\n{plant.tail()}")
        time.sleep(0.05)


def run_controller(controller, plant: PlantProcess, name: str, robot: str = "robot1",
                   timeout_s: float = 300.0, log_level: str = "WARNING") -> NodeRunner:
    """Run ``controller`` as lockstep member ``name`` of ``plant`` until it is done.

    ``controller`` may hold ``session`` / ``keys`` attributes set here before the run
    (to send ``sim/reset`` from its ``step``). Raises :class:`ExperimentError` if the
    plant dies, does not answer, or the run exceeds ``timeout_s`` of wall time.
    """
    log = setup_logging(name, log_level)
    sock = os.path.join(plant.tmp, "bus.sock")
    deadline = time.monotonic() + 60.0
    while not os.path.exists(sock) and plant.alive() and time.monotonic() < deadline:
        time.sleep(0.02)                 # the plant listens once it has loaded its world
    if not plant.alive():
        raise ExperimentError(f"the plant exited (code {plant.child.poll()}); last lines of "
                              f"{plant.log_path}:\n{plant.tail()}")
    try:
        session = open_session("node", plant.endpoint)
    except BusConfigError as exc:
        raise ExperimentError(f"cannot reach the plant: {exc}\n{plant.tail()}") from None
    keys = Keys()
    timer = None
    try:
        controller.session, controller.keys = session, keys
        _wait_for_plant(session, keys, plant, 60.0)
        try:
            runner = NodeRunner(controller, robot, name, session, keys, log,
                                wait_for_plant_s=60.0)
        except TimeoutError:
            raise ExperimentError(f"the plant did not answer (exit code {plant.child.poll()});"
                                  f" last lines of {plant.log_path}:\n{plant.tail()}") from None
        controller.runner = runner
        timed_out = []

        def on_timeout():
            timed_out.append(True)
            runner.stop_event.set()
        timer = threading.Timer(timeout_s, on_timeout)
        timer.daemon = True
        timer.start()
        code = runner.run()
        if timed_out:
            raise ExperimentError(f"{name}: no result within {timeout_s:.0f} s of wall time")
        if code != 0 or not getattr(controller, "done", False):
            raise ExperimentError(f"{name} stopped early (exit code {code}); last lines of "
                                  f"{plant.log_path}:\n{plant.tail()}")
        return runner
    finally:
        if timer is not None:
            timer.cancel()
        controller.session = controller.keys = controller.runner = None
        session.close()


def forget_inputs(runner: NodeRunner) -> None:
    """After a ``sim/reset`` sent from ``step``: make the runner forget the inputs and clock
    ticks of the old world. The new world's clock starts again at 0, and the runner would
    ignore stamps it has already acted on (it keeps (topic, stamp) pairs it used), so the
    node would wait forever (:meth:`bus.runtime.NodeRunner.reset_inputs`). Call it only
    from ``step``, between the reset's reply and the step's return (the plant publishes the
    new world only after the ack)."""
    runner.reset_inputs()


class Capture:
    """Takes the first observation that carries every input, then ends the run.

    ``info`` is the plant's ``sim/info`` (world geometry, robot poses)."""

    def __init__(self, inputs: list[str]) -> None:
        self.inputs = list(inputs)
        self.obs = None
        self.info: dict = {}
        self.done = False

    def configure(self, info: dict, robot: str) -> None:
        self.info = info

    def step(self, obs):
        if all(obs[t] is not None for t in self.inputs):
            self.obs = obs
            self.done = True
        return None


def capture(out: str, tag: str, inputs: list[str], world: str = "living_room",
            sets: list[str] | tuple[str, ...] = (), seed: int = 0,
            disable: tuple[str, ...] = (), robot: str = "robot1",
            timeout_s: float = 120.0) -> Capture:
    """Start a plant, take one observation of ``inputs`` from the bus, stop the plant."""
    node = f"capture_{tag.replace('-', '_')}"
    cap = Capture(inputs)
    t0 = time.monotonic()
    with PlantProcess(out, tag, node, world, sets, seed, disable) as plant:
        run_controller(cap, plant, node, robot, timeout_s)
    print(f"  {tag}: captured {', '.join(inputs)} at t={cap.obs.t:.2f} s "
          f"({time.monotonic() - t0:.1f} s wall)", file=sys.stderr)
    return cap
