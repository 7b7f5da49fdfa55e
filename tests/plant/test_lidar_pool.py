"""The lidar kernel's kept workers (plant/kernels/lidar.c): casts on several threads, call
after call, with thread counts changing between calls and from two Python threads at once,
are the bits of one thread; the workers are started once, not per call; a forked child
casts on threads of its own."""
from __future__ import annotations

import math
import os
import threading
from pathlib import Path

import numpy as np
import pytest

from plant.lidar import Fans, LidarConfig, scan_many
from plant.raycast import Scene
from plant.shapes import pose_matrix
from plant.sim import Simulation
from plant.world import load_world


@pytest.fixture(scope="module")
def room():
    spec = load_world("living_room")
    cfg = spec.robot("robot1").sensors.lidar or LidarConfig()
    return cfg, Scene(Simulation(spec).shapes())


def _batches(seed: int, count: int, g: int = 40) -> list[list[np.ndarray]]:
    """``count`` batches of g robots' poses, each batch different."""
    rng = np.random.default_rng(seed)
    return [[pose_matrix(rng.uniform(-2.5, 2.5), rng.uniform(-2.0, 2.0), 0.0,
                         yaw=rng.uniform(-math.pi, math.pi)) for _ in range(g)]
            for _ in range(count)]


def _workers() -> int:
    """This process's kept lidar workers (the kernel names them)."""
    return sum(Path(t, "comm").read_text().strip() == "lidar-cast"
               for t in Path("/proc/self/task").iterdir())


def test_casts_call_after_call_on_kept_workers_are_one_threads_bits(room):
    """Every call hands each worker its own part of that call's fans (not a stale part of
    an earlier call): 60 different batches, 1-5 threads in turn, each the one-thread bits.
    The workers are started by the first call that needs them and kept: at least 4 after a
    5-thread call (more if an earlier call in this process wanted more), as many after the
    calls that follow."""
    cfg, scene = room
    batches = _batches(11, 60)
    owners = ["robot1", None] * 20
    want = [scan_many(cfg, b, scene, owners, 1).tobytes() for b in batches]
    before = _workers()
    scan_many(cfg, batches[0], scene, owners, 5)
    kept = _workers()
    assert kept == max(before, 4)
    for i, b in enumerate(batches):
        threads = 1 + i % 5
        assert scan_many(cfg, b, scene, owners, threads).tobytes() == want[i], (i, threads)
    assert _workers() == kept


def test_two_python_threads_casting_at_once_each_get_their_own_bits(room):
    """Two Python threads casting at the same time, call after call (the kernel runs
    without the GIL): one call at a time owns the workers, another casts on its own
    thread; every cast of both is one thread's bits."""
    cfg, scene = room
    sets = [np.array(_batches(seed, 12, g=64)) for seed in (21, 22)]
    want = [[scan_many(cfg, b, scene, [None] * 64, 1).tobytes() for b in s] for s in sets]
    bad: list[tuple[int, int]] = []
    start = threading.Barrier(2)

    def cast(k: int) -> None:
        fans = Fans(cfg, scene, 64, 4)
        start.wait()
        for i in range(120):
            if fans.scan(sets[k][i % 12]).tobytes() != want[k][i % 12]:
                bad.append((k, i))

    runners = [threading.Thread(target=cast, args=(k,), daemon=True) for k in range(2)]
    for t in runners:
        t.start()
    for t in runners:
        t.join(timeout=30)
    assert not any(t.is_alive() for t in runners), "a cast never returned"
    assert bad == []


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork")
def test_a_forked_child_casts_on_threads_of_its_own(room):
    """A child forked after the parent's workers started has none of them: its casts on
    several threads start its own and give the parent's bits (not wait for workers that
    do not exist there)."""
    cfg, scene = room
    owners = [None] * 40
    batch = _batches(31, 1)[0]
    want = scan_many(cfg, batch, scene, owners, 1).tobytes()
    scan_many(cfg, batch, scene, owners, 3)          # the parent's workers started
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:                                     # the child: report and leave
        code = 1
        try:
            ok = scan_many(cfg, batch, scene, owners, 3).tobytes() == want
            code = 0 if ok and _workers() == 2 else 3
        finally:
            os.write(write, bytes([code]))
            os._exit(code)
    os.close(write)
    try:
        import select
        ready, _, _ = select.select([read], [], [], 30.0)
        answer = os.read(read, 1) if ready else b""
    finally:
        os.close(read)
        if not answer:
            os.kill(pid, 9)
        os.waitpid(pid, 0)
    assert answer == bytes([0]), "the child hung" if not answer else answer
