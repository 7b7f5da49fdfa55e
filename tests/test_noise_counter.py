"""The counter-based draws (plant/noise.py, plant/kernels/noise.c): a pure function of
(key, tick, index), the kernel equal to the Python reference to the bit, normal and
independent across neighbouring keys, ticks and indices."""
from __future__ import annotations

import math

import numpy as np
import pytest

from plant.noise import frame_seed, normals, normals_reference, stream_key

M64 = (1 << 64) - 1


def _bits(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64).view(np.uint64)


def test_kernel_equals_the_python_reference_to_the_bit():
    rng = np.random.default_rng(5)
    keys = [0, 1, 2, M64, M64 - 1, 1 << 63, *map(int, rng.integers(0, 2 ** 64, 90, np.uint64))]
    ticks = [0, 1, -1, 2 ** 63 - 1, -2 ** 63, 7, *map(int, rng.integers(-2 ** 40, 2 ** 40, 90))]
    n = 23                                          # odd: the last element is a cos alone
    got = normals(np.array(keys, dtype=np.uint64), np.array(ticks, dtype=np.int64), n)
    want = [normals_reference(k, t, n) for k, t in zip(keys, ticks)]
    assert got.shape == (len(keys), n)
    np.testing.assert_array_equal(_bits(got), _bits(want))


def test_values_do_not_depend_on_grouping_order_or_length():
    keys = np.array([stream_key(3, f"robot{i}", s) for i in range(4)
                     for s in ("scan", "gps", "motion")], dtype=np.uint64)
    ticks = np.arange(len(keys), dtype=np.int64) * 5 + 100
    together = normals(keys, ticks, 40)
    for r in reversed(range(len(keys))):               # one row at a time, backwards
        np.testing.assert_array_equal(normals(keys[r:r + 1], ticks[r], 40)[0], together[r])
    np.testing.assert_array_equal(normals(keys[::-1], ticks[::-1], 40), together[::-1])
    np.testing.assert_array_equal(normals(keys, ticks, 7), together[:, :7])   # a prefix
    one_tick = normals(keys, 100, 40)                       # one tick for every row
    np.testing.assert_array_equal(one_tick[0], together[0])
    np.testing.assert_array_equal(one_tick, normals(keys, np.full(len(keys), 100), 40))
    out = np.full((len(keys), 40), np.nan)
    assert normals(keys, ticks, 40, out=out) is out
    np.testing.assert_array_equal(out, together)
    assert normals(keys, ticks, 0).shape == (len(keys), 0)
    assert normals(keys[:0], 0, 5).shape == (0, 5)
    # keys as Python ints (past 2**63 too) and numpy integers
    big = [int(k) for k in keys[:3]] + [2 ** 64 - 1]
    np.testing.assert_array_equal(normals(big, 4, 3), normals(np.array(big, np.uint64), 4, 3))
    np.testing.assert_array_equal(normals([5], np.int32(4), 3),
                                  normals(np.array([5], np.int16), [4], 3))


def _phi(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.vectorize(math.erf)(x / math.sqrt(2.0)))


def test_draws_are_standard_normal():
    # 4000 rows (consecutive keys, the least favourable, at consecutive ticks) of 250
    z = normals(np.arange(4000, dtype=np.uint64), np.arange(4000), 250).ravel()
    n = z.size
    se = 1.0 / math.sqrt(n)
    assert abs(z.mean()) < 5 * se
    assert abs(z.std() - 1.0) < 5 * se * math.sqrt(0.5)
    skew = np.mean(z ** 3)
    kurt = np.mean(z ** 4) - 3.0
    assert abs(skew) < 5 * math.sqrt(6.0 / n) and abs(kurt) < 5 * math.sqrt(24.0 / n)
    # Kolmogorov-Smirnov against the normal's CDF on a subsample (the 1 % critical value)
    s = np.sort(z[::50])
    cdf = _phi(s)
    i = np.arange(s.size)
    d = max(np.max((i + 1) / s.size - cdf), np.max(cdf - i / s.size))
    assert d < 1.63 / math.sqrt(s.size)
    assert np.isfinite(z).all() and np.abs(z).max() < 8.0


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])


@pytest.mark.parametrize("what", ["keys", "ticks", "indices"])
def test_neighbouring_keys_ticks_and_indices_are_uncorrelated(what):
    k = 3000
    base = np.arange(k, dtype=np.uint64) * np.uint64(2)     # neighbours: key + 1, tick + 1
    if what == "keys":
        a, b = normals(base, 9, 64), normals(base + np.uint64(1), 9, 64)
    elif what == "ticks":
        t = base.astype(np.int64)
        a, b = normals(base, t, 64), normals(base, t + 1, 64)
    else:                                   # index i and i + 1, both parities of the pair
        z = normals(base, 9, 65)
        a, b = z[:, :-1], z[:, 1:]
    bound = 5.0 / math.sqrt(a.size)
    assert abs(_corr(a, b)) < bound
    # and their squares (a pair sharing its radius, or a reused uniform, shows here)
    assert abs(_corr(a ** 2, b ** 2)) < bound * 1.5
    assert abs(_corr(np.abs(a), np.abs(b))) < bound * 1.5


def test_stream_keys_are_stable_and_distinct():
    # The key of a name is part of every recorded run's noise: it must not drift.
    assert stream_key(0, "robot1", "scan") == stream_key(0, "robot1", "scan")
    assert stream_key(7, "robot1", "scan") == 0x37314856f9c4fdf0
    keys = {stream_key(seed, robot, s) for seed in (0, 1, 2, 2 ** 64, 2 ** 64 + 1)
            for robot in ("robot1", "robot2", "r") for s in ("scan", "gps", "left_wheel",
                                                                 "motion", "camera")}
    assert len(keys) == 5 * 3 * 5
    assert all(0 <= k <= M64 for k in keys)
    assert stream_key(np.int64(7), "robot1", "scan") == stream_key(7, "robot1", "scan")
    for bad in (-1, 1.5, True, "7", None):
        with pytest.raises(ValueError, match="seed"):
            stream_key(bad, "robot1", "scan")


def test_frame_seed_is_a_function_of_key_and_tick():
    key = stream_key(1, "robot1", "camera")
    seeds = {frame_seed(key, t) for t in range(1000)}
    assert len(seeds) == 1000 and all(0 <= s <= M64 for s in seeds)
    assert frame_seed(key, 12) == frame_seed(key, 12) != frame_seed(key + 1, 12)
    assert frame_seed(key, -1) == frame_seed(key, M64)     # a tick is taken mod 2**64


@pytest.mark.parametrize("call, match", [
    (lambda: normals(np.zeros((2, 2), np.uint64), 0, 3), "one-dimensional"),
    (lambda: normals(np.zeros(3, np.uint64), np.zeros(2, np.int64), 3), "one per key"),
    (lambda: normals(np.zeros(3, np.uint64), 0, -1), "n must"),
    (lambda: normals(np.zeros(3, np.uint64), 0, 2.0), "n must"),
    (lambda: normals(np.zeros(3, np.uint64), 0, 4, out=np.empty((3, 5))), "out must"),
    (lambda: normals(np.zeros(3, np.uint64), 0, 4, out=np.empty((3, 4), np.float32)), "out must"),
    (lambda: normals([-1], 0, 2), "keys must fit"),
    (lambda: normals([2 ** 64], 0, 2), "keys must fit"),
    (lambda: normals([1.5], 0, 2), "keys must be integers"),
    (lambda: normals(np.array([-1, 2]), 0, 2), "keys must be integers within"),
    (lambda: normals(np.array([0.5]), 0, 2), "keys must be integers within"),
    (lambda: normals([1], 2 ** 63, 2), "ticks must fit"),
    (lambda: normals([1], 0.5, 2), "ticks must be integers"),
])
def test_bad_arguments_are_clear_errors(call, match):
    with pytest.raises(ValueError, match=match):
        call()
