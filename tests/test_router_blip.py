"""Lockstep survives a router blip (issue 27): on loopback, a `diffbot router` killed and
restarted 2 s later during a lockstep square run with --rejoin-timeout 30 and --wait nodes
leaves the recording identical, payloads and sim stamps, to an undisturbed run's, under
both couplings (docs/PROTOCOL.md section 4, "Lost members")."""
from __future__ import annotations

import json
import os
import random
import signal
import socket
import time

import pytest

from bus.protocol import COUPLINGS

from .compare_recordings import compare
from .conftest import ROOT, Procs, wait_for

pytestmark = pytest.mark.slow

CLIENT = os.path.join(ROOT, "diffbot", "configs", "client.json5")
DURATION_S = "5"
BLIP_S = 2.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_router(r: Procs, port: int):
    router = r.diffbot("router", "--listen", f"tcp/127.0.0.1:{port}", name="router")
    wait_for(lambda: "listening on" in r.log(router) or router.poll() is not None, 30,
             what="the router")
    assert router.poll() is None, r.log(router)
    return router


def square(tmp: str, coupling: str, blip_at: float | None) -> tuple[str, dict, str]:
    """A square run through a loopback router: (MCAP path, plant stats, plant log); with
    ``blip_at`` (simulated s) the router is SIGKILLed then and restarted BLIP_S later."""
    os.makedirs(tmp, exist_ok=True)
    r = Procs(tmp)
    port = free_port()
    env = {"DIFFBOT_ROUTER": "127.0.0.1", "DIFFBOT_PORT": str(port)}
    bus = ["--zenoh-config", CLIENT]
    mcap, stats = os.path.join(tmp, "run.mcap"), os.path.join(tmp, "plant.json")
    try:
        router = start_router(r, port)
        plant = r.diffbot("plant", "--world", "living_room", "--disable", "camera",
                          "--coupling", coupling, "--seed", "0", "--duration", DURATION_S,
                          "--expect", "odometry_robot1,square_path_robot1",
                          "--rejoin-timeout", "30", "--stats", stats, "--log-level", "DEBUG",
                          *bus, name="plant", env=env)
        rec = r.diffbot("record", mcap, "--compression", "none", *bus, name="recorder",
                        env=env)
        wait_for(lambda: "recording" in r.log(rec) or rec.poll() is not None, 30,
                 what="the recorder")
        r.diffbot("fmu-node", "fmus/build/odometry_fmi2.fmu", "--robot", "robot1", "--name",
                  "odometry_robot1", "--wait", *bus, name="odometry", env=env)
        r.diffbot("controller", "square_path", "--robot", "robot1", "--side", "1.5",
                  "--name", "square_path_robot1", "--wait", *bus, name="square", env=env)
        if blip_at is not None:
            wait_for(lambda: "running living_room" in r.log(plant), 60, what="the run")
            # the plant logs nothing per tick: take the wall time the run needs to get there
            time.sleep(blip_at)
            router.send_signal(signal.SIGKILL)
            router.wait(5)
            time.sleep(BLIP_S)
            start_router(r, port)
        assert plant.wait(120) == 0, r.log(plant)
        assert rec.wait(30) == 0, r.log(rec)
        log = r.log(plant)
    finally:
        r.cleanup()
    with open(stats) as f:
        return mcap, json.load(f), log


@pytest.mark.parametrize("coupling", COUPLINGS)
def test_a_router_blip_leaves_the_recording_as_an_undisturbed_run_s(tmp_path, coupling):
    ref, st0, _ = square(str(tmp_path / "undisturbed"), coupling, None)
    blip_at = random.Random(coupling).uniform(0.3, 1.0)
    got, st1, log = square(str(tmp_path / "blip"), coupling, blip_at)
    assert "lost the router" in log and "lockstep member rejoined" in log, log[-3000:]
    lines = compare(ref, got)
    assert lines and all(ln.startswith("same") for ln in lines), "\n".join(lines)
    assert st0["sim_time_s"] == st1["sim_time_s"] == pytest.approx(float(DURATION_S))
    assert st1["protocol_errors"] == {}, st1
    print(f"\n{coupling}: router blip at wall +{blip_at:.2f} s: recording identical "
          f"({len(lines)} topics)")
