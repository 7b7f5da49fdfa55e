"""Noise models: statistics, Webots meanings, keys and stream independence (the draws
themselves: tests/test_noise_counter.py)."""
from __future__ import annotations

import numpy as np
import pytest

from plant.lidar import LidarConfig, apply_noise
from plant.noise import (NoiseConfig, NoiseModel, frame_seed, normals, parse_noise,
                         stream_key, webots_camera, webots_gps, webots_lidar, webots_position)

N = 10_000


def key(seed: int, name: str) -> int:
    """The key of stream ``name`` ("robot/stream", or a stream of robot1)."""
    robot, _, stream = name.rpartition("/")
    return stream_key(seed, robot or "robot1", stream)


def _rel_err(sample_std, want):
    return abs(sample_std - want) / want


def test_lidar_std_is_relative_to_max_range():
    cfg = LidarConfig()                       # max 80 m
    nc = webots_lidar(0.01, cfg.max_range_m)
    assert nc.std == pytest.approx(0.8)
    true = np.full(N, 40.0)
    out = apply_noise(cfg, true, NoiseModel(nc, key(3, "robot1/scan")))
    assert _rel_err(out.std(), 0.8) < 0.05
    assert abs(out.mean() - 40.0) < 4 * 0.8 / np.sqrt(N)


def test_encoder_std_absolute_rad():
    nc = webots_position(0.02)
    out = NoiseModel(nc, key(3, "robot1/left_wheel")).apply(np.full(N, 12.5), 0)
    assert _rel_err(out.std(), 0.02) < 0.05
    assert abs(out.mean() - 12.5) < 4 * 0.02 / np.sqrt(N)


def test_gps_std_absolute_m():
    nc = webots_gps(0.05)
    out = NoiseModel(nc, key(3, "robot1/gps")).apply(np.zeros((N, 2)) + [1.0, -2.0], 0)
    assert out.shape == (N, 2)
    assert _rel_err(out[:, 0].std(), 0.05) < 0.05 and _rel_err(out[:, 1].std(), 0.05) < 0.05


def test_camera_std_in_levels_keeps_uint8():
    nc = webots_camera(0.05)
    assert nc.std == pytest.approx(12.75)
    img = np.full((100, 100), 128, dtype=np.uint8)
    out = NoiseModel(nc, key(3, "robot1/camera")).apply(img, 0)
    assert out.dtype == np.uint8 and out.shape == img.shape
    assert _rel_err(out.astype(float).std(), 12.75) < 0.05
    # per channel: each channel gets its own draw
    rgb = np.full((20, 20, 3), 100, dtype=np.uint8)
    o = NoiseModel(webots_camera(0.1), key(1, "c")).apply(rgb, 0)
    assert not np.array_equal(o[..., 0], o[..., 1])


def test_camera_clips_to_0_255():
    img = np.array([0, 5, 250, 255] * 1000, dtype=np.uint8)
    out = NoiseModel(NoiseConfig(std=60.0), key(0, "c")).apply(img, 0)
    assert out.dtype == np.uint8
    assert out.min() == 0 and out.max() == 255


def test_mean_bias_and_resolution():
    nc = NoiseConfig(std=0.01, mean=0.1, bias=0.2, resolution=0.05)
    out = NoiseModel(nc, key(5, "x")).apply(np.full(N, 1.0), 0)
    assert abs(out.mean() - 1.3) < 0.005
    steps = out / 0.05
    assert np.allclose(steps, np.round(steps), atol=1e-9)


def test_inf_and_nan_pass_through():
    model = NoiseModel(NoiseConfig(std=0.1, resolution=0.01), key(0, "s"))
    out = model.apply(np.array([np.inf, 1.0, np.nan, -np.inf]), 0)
    assert out[0] == np.inf and np.isfinite(out[1]) and np.isnan(out[2]) and out[3] == -np.inf


def test_zero_noise_is_identity():
    x = np.array([1.0, np.inf, 2.5])
    out = NoiseModel(NoiseConfig(), key(0, "z")).apply(x, 0)
    assert np.array_equal(out, x)
    img = np.arange(256, dtype=np.uint8)
    assert np.array_equal(NoiseModel(NoiseConfig(), key(0, "z")).apply(img, 0), img)


def test_same_seed_same_noise_different_seed_different():
    nc = NoiseConfig(std=1.0)
    a = NoiseModel(nc, key(42, "robot1/scan")).apply(np.zeros(100), 0)
    b = NoiseModel(nc, key(42, "robot1/scan")).apply(np.zeros(100), 0)
    c = NoiseModel(nc, key(43, "robot1/scan")).apply(np.zeros(100), 0)
    d = NoiseModel(nc, key(42, "robot2/scan")).apply(np.zeros(100), 0)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert not np.array_equal(a, d)


def test_streams_are_independent():
    nc = NoiseConfig(std=1.0)
    # run 1: only the scan stream, every tick
    scan1 = NoiseModel(nc, key(7, "robot1/scan"))
    alone = [scan1.apply(np.zeros(180), t) for t in range(6)]
    # run 2: a GPS stream is added and interleaved, and ticks 1 and 4 go unread
    scan2 = NoiseModel(nc, key(7, "robot1/scan"))
    gps = NoiseModel(nc, key(7, "robot1/gps"))
    mixed = {}
    for t in (5, 3, 2, 0):
        gps.apply(np.zeros(3), t)
        mixed[t] = scan2.apply(np.zeros(180), t)
        gps.apply(np.zeros(3), t + 1)
    for t, y in mixed.items():
        assert np.array_equal(alone[t], y)
    # a reading is element i of its stream's normals at its tick, times the std
    np.testing.assert_array_equal(alone[3], normals([key(7, "robot1/scan")], 3, 180)[0])
    assert not np.array_equal(alone[0], alone[1])
    # and the two streams are uncorrelated
    a = NoiseModel(nc, key(7, "a")).apply(np.zeros(N), 0)
    b = NoiseModel(nc, key(7, "b")).apply(np.zeros(N), 0)
    assert abs(np.corrcoef(a, b)[0, 1]) < 0.05


@pytest.mark.slow
def test_noise_stable_across_processes():
    # sha256-based keys: Python's hash() would vary with PYTHONHASHSEED
    v = NoiseModel(NoiseConfig(std=1.0), stream_key(1, "robot1", "scan")).apply([0.0], 9)[0]
    import subprocess
    import sys
    code = ("from plant.noise import NoiseConfig, NoiseModel, stream_key; print(repr(NoiseModel("
            "NoiseConfig(std=1.0), stream_key(1, 'robot1', 'scan')).apply([0.0], 9)[0].item()))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONHASHSEED": "123", "PYTHONPATH": _repo_root()}, check=True)
    assert float(out.stdout) == v


def _repo_root() -> str:
    from pathlib import Path
    return str(Path(__file__).resolve().parents[1])


# ----------------------------------- parsing ----------------------------------------

def test_parse_plain_and_webots_forms():
    assert parse_noise(None, "gps") == NoiseConfig()
    assert parse_noise({}, "gps") == NoiseConfig()
    assert parse_noise({"std": 0.01, "bias": 0, "mean": 0, "resolution": 0}, "gps") == \
        NoiseConfig(std=0.01)
    assert parse_noise({"webots_noise": 0.01}, "lidar", max_range=80.0).std == pytest.approx(0.8)
    assert parse_noise({"webots_noise": 0.2}, "camera").std == pytest.approx(51.0)
    assert parse_noise({"webots_noise": 0.2}, "position").std == pytest.approx(0.2)
    assert parse_noise({"webots_noise": 0.2}, "encoder").std == pytest.approx(0.2)
    nc = parse_noise({"webots_noise": 0.1, "bias": 0.5, "resolution": 1}, "camera")
    assert nc == NoiseConfig(std=25.5, bias=0.5, resolution=1.0)


@pytest.mark.parametrize("table,sensor,kw,key", [
    ({"stdev": 0.1}, "gps", {}, "stdev"),
    ({"std": -0.1}, "gps", {}, "std"),
    ({"std": "0.1"}, "gps", {}, "std"),
    ({"std": float("nan")}, "gps", {}, "std"),
    ({"bias": True}, "gps", {}, "bias"),
    ({"resolution": -1}, "gps", {}, "resolution"),
    ({"webots_noise": 0.1, "std": 0.1}, "gps", {}, "webots_noise"),
    ({"webots_noise": 0.1}, "lidar", {}, "webots_noise"),
    ({"webots_noise": 0.1}, "thermometer", {}, "webots_noise"),
    ({"webots_noise": -1}, "camera", {}, "webots_noise"),
])
def test_parse_errors_name_the_key(table, sensor, kw, key):
    with pytest.raises(ValueError) as e:
        parse_noise(table, sensor, where="world.toml:robot1.gps.noise", **kw)
    assert f"world.toml:robot1.gps.noise.{key}" in str(e.value)


def test_parse_rejects_non_table():
    with pytest.raises(ValueError, match="expected a table"):
        parse_noise(0.1, "gps")


def test_config_validation():
    with pytest.raises(ValueError, match="std"):
        NoiseConfig(std=-1.0)
    with pytest.raises(ValueError, match="webots_noise"):
        webots_camera(-0.1)
    with pytest.raises(ValueError, match="seed"):
        key(-1, "x")
    for bad in (-1, 2 ** 64, 1.0, True):
        with pytest.raises(ValueError, match="key"):
            NoiseModel(NoiseConfig(std=1.0), bad)
    rows = NoiseModel(NoiseConfig(std=1.0), np.arange(3, dtype=np.uint64))
    with pytest.raises(ValueError, match="3 rows"):
        rows.apply(np.zeros((2, 5)), 0)
    with pytest.raises(ValueError, match="one key"):
        rows.apply(np.zeros((3, 4, 3), np.uint8), 0)


def test_rows_are_their_streams_alone():
    """A model of several keys (a batch's worlds) gives row r what the model of keys[r]
    alone gives, at its own tick."""
    cfg = NoiseConfig(std=0.3, bias=0.1, resolution=0.01)
    keys = np.array([key(s, "robot1/lidar") for s in range(4)], np.uint64)
    x = np.linspace(0.5, 4.0, 4 * 7).reshape(4, 7)
    ticks = np.array([3, 0, 8, 3])
    rows = NoiseModel(cfg, keys).apply(x, ticks)
    for r in range(4):
        np.testing.assert_array_equal(rows[r], NoiseModel(cfg, int(keys[r])).apply(x[r], ticks[r]))
    sub = NoiseModel(cfg, keys).select([2, 0]).apply(x[[2, 0]], ticks[[2, 0]])
    np.testing.assert_array_equal(sub, rows[[2, 0]])


def test_prefetched_image_noise_is_the_same():
    img = np.full((12, 16, 3), 100, np.uint8)
    cfg = NoiseConfig(std=20.0, resolution=2.0)                 # (drawn in numpy)
    a = NoiseModel(cfg, key(4, "robot1/camera"))
    b = NoiseModel(cfg, key(4, "robot1/camera"))
    out_a = [a.apply(img, t) for t in range(3)]
    out_b = []
    for t in range(3):
        b.prefetch_image(img.shape, t)
        b.prefetch_image(img.shape, t)       # a second prefetch changes nothing
        out_b.append(b.apply(img, t))
    b.prefetch_image(img.shape, 7)           # one for another tick is not used for tick 1
    out_b.append(b.apply(img, 1))
    assert all(np.array_equal(x, y) for x, y in zip(out_a + [out_a[1]], out_b))


@pytest.mark.parametrize("bias", [0.0, 3.5])
@pytest.mark.parametrize("resolution", [0.0, 4.0])
def test_image_noise_is_the_stated_sum_drawn_ahead_or_not(bias, resolution):
    """With quantisation: quantise(rint(clip((x + bias) + std * N(0, 1) float32))), the
    normals those of the stream's key at the frame's tick. Without: the C kernel's image
    (its numpy reference) for the frame seed of the key and the tick. Either way whether
    the draws are fetched ahead or not."""
    from plant.noise import image_noise_reference
    img = np.random.default_rng(1).integers(0, 256, (12, 16, 3), dtype=np.uint8)
    cfg = NoiseConfig(std=20.0, bias=bias, resolution=resolution)
    k = key(4, "robot1/camera")
    want = []
    for t in range(4):
        if not resolution:
            want.append(image_noise_reference(img, frame_seed(k, t), 20.0, bias))
            continue
        x = img.astype(np.float32) + np.float32(bias)
        z = normals([k], t, img.size)[0].reshape(img.shape).astype(np.float32)
        x = x + z * np.float32(20.0)
        x = np.round(x / np.float32(resolution)) * np.float32(resolution)
        want.append(np.clip(np.rint(x), 0, 255).astype(np.uint8))
    for how in ("none", "ahead"):
        m = NoiseModel(cfg, k)
        got = []
        for t in range(4):
            if how != "none":
                m.prefetch_image(img.shape, t)
            got.append(m.apply(img, t))
        assert all(np.array_equal(a, b) for a, b in zip(want, got)), how
        assert len({id(g) for g in got}) == 4 and not any(np.shares_memory(a, b) for a in got
                                                          for b in got if a is not b)


# ------------------------------------ the image noise's generator (plant/kernels/noise.c)

def _levels(std, offset=0.0, x=128, shape=(240, 320, 3), seed=9, frames=1):
    """Frames of a flat grey image through the kernel, as level differences (int)."""
    m = NoiseModel(NoiseConfig(std=std, bias=offset), key(seed, "robot1/camera"))
    img = np.full(shape, x, np.uint8)
    return np.stack([m.apply(img, t).astype(int) - x for t in range(frames)])


@pytest.mark.parametrize("std,offset", [(10.0, 0.0), (51.0, 0.0), (7.3, 2.25), (0.3, 0.4),
                                        (300.0, -1.5)])
def test_alias_table_holds_the_law_of_the_rounded_gaussian(std, offset):
    """Every value's probability in the table is the law's to 2**-32 (a whole number of
    the 32-bit uniform's values), and the law is rint(offset + N(0, std)) clamped to
    [-255, 255]: P(D = k) = Phi((k + 1/2 - offset) / std) - Phi((k - 1/2 - offset) / std)."""
    from math import erf, sqrt

    from plant.noise import alias_table, image_noise_law
    lo, p = image_noise_law(std, offset)
    assert abs(p.sum() - 1.0) < 1e-12 and lo >= -255 and lo + p.size - 1 <= 255
    phi = lambda z: 0.5 * (1.0 + erf(z / sqrt(2.0)))          # noqa: E731
    for k in range(max(lo + 1, int(offset) - 3), min(lo + p.size - 1, int(offset) + 4)):
        assert p[k - lo] == pytest.approx(phi((k + 0.5 - offset) / std)
                                          - phi((k - 0.5 - offset) / std), abs=1e-12)
    thr, vals = alias_table(std, offset)
    held = np.zeros(p.size)
    for j in range(thr.size):
        own = (int(thr[j]) + (thr[j] == 0xFFFFFFFF)) / 2.0 ** 32
        held[int(vals[j, 1]) - 255 - lo] += own / thr.size
        held[int(vals[j, 0]) - 255 - lo] += (1.0 - own) / thr.size
    assert np.abs(held - p).max() < 2 * 2.0 ** -32 * thr.size


@pytest.mark.parametrize("std,offset", [(10.0, 0.0), (4.0, 1.7), (0.6, -0.3)])
def test_image_noise_mean_and_std_are_the_models_within_the_standard_error(std, offset):
    """230 400 channels of a flat grey frame: mean and std of the level difference within
    5 standard errors of those of rint(offset + N(0, std)) (no clipping at level 128)."""
    from plant.noise import image_noise_law
    d = _levels(std, offset).ravel()
    lo, p = image_noise_law(std, offset)
    k = np.arange(lo, lo + p.size)
    mean = float((p * k).sum())
    sd = float(np.sqrt((p * (k - mean) ** 2).sum()))
    n = d.size
    assert abs(d.mean() - mean) < 5 * sd / np.sqrt(n)
    kurt = float((p * (k - mean) ** 4).sum()) / sd ** 4
    assert abs(d.std() - sd) < 5 * sd * np.sqrt((kurt - 1) / (4 * n))
    if std >= 4:                        # the rounding adds 1/12 level^2 to the variance
        assert sd == pytest.approx(np.sqrt(std ** 2 + 1 / 12), rel=1e-3)


def test_image_noise_histogram_is_the_law():
    """Pearson's chi-square of 230 400 draws against the law (std 2.5, offset 0.4), far
    below what one in a million samples of the law would exceed."""
    from plant.noise import image_noise_law
    d = _levels(2.5, 0.4).ravel()
    lo, p = image_noise_law(2.5, 0.4)
    counts = np.bincount(d - lo, minlength=p.size)
    expect = p * d.size
    keep = expect > 20
    stat = float((((counts[keep] - expect[keep]) ** 2) / expect[keep]).sum())
    df = int(keep.sum()) - 1
    assert stat < df + 7 * np.sqrt(2 * df)


def test_image_noise_has_no_correlation_between_neighbours_frames_or_seeds():
    """Correlations of the level differences within 5 / sqrt(n) of 0: channel to channel,
    pixel to its right and lower neighbours, the two halves of one 64-bit number (elements
    2m and 2m + 1), one frame to the next, and two seeds' frames."""
    f = _levels(10.0, frames=2)                 # (2, 240, 320, 3)
    g = _levels(10.0, seed=10)[0]
    a = f[0]

    def r(x, y):
        return abs(np.corrcoef(x.ravel().astype(float), y.ravel().astype(float))[0, 1])
    flat = a.ravel()
    pairs = {
        "next channel": (a[..., :-1], a[..., 1:]),
        "right pixel": (a[:, :-1], a[:, 1:]),
        "lower pixel": (a[:-1], a[1:]),
        "one number's halves": (flat[0::2], flat[1::2]),
        "next number": (flat[0:-2:2], flat[2::2]),
        "next frame": (a, f[1]),
        "another seed": (a, g),
    }
    for name, (x, y) in pairs.items():
        assert r(x, y) < 5 / np.sqrt(x.size), name
    assert not np.array_equal(a, f[1]) and not np.array_equal(a, g)


def test_image_noise_is_a_function_of_key_and_tick():
    assert np.array_equal(_levels(10.0, frames=3), _levels(10.0, frames=3))
    m = NoiseModel(NoiseConfig(std=10.0), key(9, "robot1/camera"))
    img = np.full((4, 5, 3), 100, np.uint8)
    later = m.apply(img, 7)
    m.apply(img, 3)
    assert np.array_equal(m.apply(img, 7), later)           # whatever came between
    assert not np.array_equal(m.apply(img, 8), later)


def test_image_noise_clips_like_the_model_at_both_ends():
    """Levels 0 and 255 under std 10: half the channels stay at the end they start at (the
    law's mass on the far side of 0), the rest spread by the rounded Gaussian."""
    for x, end in ((0, 0), (255, 255)):
        m = NoiseModel(NoiseConfig(std=10.0), key(2, "c"))
        out = m.apply(np.full((200, 300, 3), x, np.uint8), 0)
        frac = np.mean(out == end)
        assert abs(frac - (0.5 + 0.5 * 0.0398)) < 0.01     # P(rint(N) <= 0) = Phi(0.05)
