"""A controller for many robots: Avoid.step_many over a swarm's scans gives, to the bit, the
commands one Avoid per robot gives (the per-robot step is the oracle), and the masked row
sums it is built on equal numpy's own sums."""
from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from bus import codec
from bus.controller import Observation
from controllers.avoid import Avoid
from controllers.rowsum import masked_row_sums, masked_row_sums_numpy


def _bits(x: float) -> bytes:
    return struct.pack("<d", x)


@pytest.mark.parametrize("masked_row_sums", [masked_row_sums, masked_row_sums_numpy],
                         ids=["kernel", "numpy"])
def test_masked_row_sums_equal_numpy_sums_of_each_row(masked_row_sums):
    """Every run length numpy sums differently (under 8, blocks of 8 up to 128, halves
    past it, past 256 twice), signed zeros and wide magnitudes: the kernel and its numpy
    formulation alike."""
    rng = np.random.default_rng(7)
    for trial in range(60):
        rows, width = int(rng.integers(1, 30)), int(rng.integers(1, 400))
        v = rng.normal(size=(rows, width)) * 10.0 ** rng.uniform(-4, 4, size=(rows, width))
        if trial % 4 == 0:
            v[rng.random((rows, width)) < 0.5] = -0.0
        mask = rng.random((rows, width)) < rng.random((rows, 1))
        got = masked_row_sums(v, mask)
        want = [np.sum(v[i][mask[i]]) for i in range(rows)]
        assert [_bits(g) for g in got] == [_bits(w) for w in want], trial
    # numpy starts from +0.0: a run of -0.0 values sums to +0.0, an empty one too
    zeros = np.full((4, 200), -0.0)
    mask = np.arange(200)[None, :] < np.array([[0], [3], [9], [200]])
    assert [_bits(g) for g in masked_row_sums(zeros, mask)] == [_bits(0.0)] * 4


def _scans(rng, robots: int, ticks: int, rays: int):
    """Noisy scans per tick: each robot's ranges a random walk through the stop and slow
    distances (so robots block, turn, clear), with dropouts (inf, nan) and returns under
    the minimum range, rounded to float32 as the wire carries them."""
    near = rng.uniform(0.4, 2.0, size=(robots, 1))       # each robot's nearest return
    shape = rng.uniform(0.0, 1.5, size=(robots, rays))    # its room around it
    for _ in range(ticks):
        near = np.clip(near + rng.normal(0.0, 0.06, size=near.shape), 0.3, 2.5)
        r = near + shape + rng.normal(0.0, 0.01, size=shape.shape)
        r[rng.random(shape.shape) < 0.02] = np.inf
        r[rng.random(shape.shape) < 0.005] = np.nan
        r[rng.random(shape.shape) < 0.01] = 0.01
        yield r


def test_step_many_gives_each_robot_s_step_command_to_the_bit():
    """48 robots (40 with the living room's 180 rays over 180 deg, 6 with 90 rays over
    270 deg, 2 without a scan yet at times) over 250 ticks: every Twist equals, bit for bit,
    the one a separate Avoid object's step gives that robot."""
    rng = np.random.default_rng(3)
    robots = [f"r{i}" for i in range(48)]
    singles = {r: Avoid() for r in robots}
    many = Avoid()
    wide = {r for r in robots[40:46]}
    blank = set(robots[46:])
    gens = {180: _scans(rng, 40, 250, 180), 90: _scans(rng, 6, 250, 90)}
    states, blocked, free = set(), 0, 0
    for k in range(250):
        t_ns = k * 20_000_000
        r180, r90 = next(gens[180]), next(gens[90])
        obs = {}
        for i, r in enumerate(robots):
            if r in blank and k % 3:
                obs[r] = Observation(t_ns, r, {})
                continue
            if r in wide:
                ranges, a0, n = r90[i - 40], -3 * math.pi / 4, 90
            else:
                ranges, a0, n = r180[i % 40], -math.pi / 2, 180
            inc = -2 * a0 / (n - 1)
            scan = codec.laser_scan(t_ns, a0, -a0, inc, 0.1, 0.12, 5.0, ranges)
            obs[r] = Observation(t_ns, r, {"scan": scan})
        got = many.step_many(obs)
        assert list(got) == robots
        for r in robots:
            want = singles[r].step(obs[r])
            assert (_bits(got[r].linear), _bits(got[r].angular)) == \
                (_bits(want.linear), _bits(want.angular)), (k, r, got[r], want)
            assert many.turning_of.get(r, 0.0) == singles[r].turning
            states.add(singles[r].turning)
            blocked += want.linear == 0.0
            free += want.linear > 0.0 and want.angular != 0.0
    # the scans drove every branch: free, blocked, turning either way
    assert states == {-1.0, 0.0, 1.0} and blocked > 500 and free > 500, (blocked, free)


def test_step_many_keeps_each_robot_s_side_as_robots_come_and_go():
    """The swarm's lidar (36 rays over 360 deg) for 10 robots, every tick a different subset
    in a different order (a robot left out, and back later; all in one group most ticks):
    every Twist and turning side equals a separate Avoid object's for that robot."""
    rng = np.random.default_rng(8)
    robots = [f"r{i}" for i in range(10)]
    singles = {r: Avoid() for r in robots}
    many = Avoid()
    gen = _scans(rng, 10, 200, 36)
    a0, inc = -math.pi, 2 * math.pi / 36
    turned = 0
    for k in range(200):
        t_ns = k * 20_000_000
        ranges = next(gen)
        ranges[rng.random(ranges.shape) < 0.01] = -np.inf
        shown = list(rng.permutation(robots)[:int(rng.integers(7, 11))]) if k % 4 else robots
        obs = {r: Observation(t_ns, r, {"scan": codec.laser_scan(
            t_ns, a0, a0 + 35 * inc, inc, 0.1, 0.12, 5.0, ranges[int(r[1:])])}) for r in shown}
        got = many.step_many(obs)
        assert list(got) == shown
        for r in shown:
            want = singles[r].step(obs[r])
            assert (_bits(got[r].linear), _bits(got[r].angular)) == \
                (_bits(want.linear), _bits(want.angular)), (k, r)
        assert many.turning_of == {r: singles[r].turning for r in many.turning_of}
        assert set(many.turning_of) >= set(shown)
        turned += sum(s.turning != 0.0 for s in singles.values())
    assert turned > 100, turned


def test_a_stale_kernels_library_is_refused_saying_how_to_build(monkeypatch):
    """A library built before a kernel's source changed (its ABI number differs, or the
    function is missing) is refused with the command that rebuilds it, never called."""
    from controllers import kernels

    class Stale:
        def controller_rowsum_abi(self):
            return 0

    monkeypatch.setattr(kernels, "library", lambda: Stale())
    kernels.function.cache_clear()
    try:
        with pytest.raises(kernels.KernelsMissing, match="out of date.*make setup"):
            kernels.function("controller_masked_row_sums", ("controller_rowsum_abi", 1), 6)
        with pytest.raises(kernels.KernelsMissing, match="controller_avoid_abi None"):
            kernels.function("controller_avoid_commands", ("controller_avoid_abi", 1), 12)
    finally:
        kernels.function.cache_clear()
