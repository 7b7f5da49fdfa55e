"""`diffbot experiment NAME`: each of the study's sensor experiments runs from the command
line with small sizes and writes a real PNG, its CSV and the summary keys."""
from __future__ import annotations

import csv
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from ..conftest import ROOT

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = [pytest.mark.slow, pytest.mark.background]

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def experiment(*args, timeout=150):
    return subprocess.run([sys.executable, "-m", "diffbot.cli", "experiment", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def run_ok(name, out, *args, timeout=150):
    r = experiment(name, "--out", str(out), *args, timeout=timeout)
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["experiment"] == name and "parameters" in s and "seed" in s
    return s, r


def assert_png(path, min_bytes=10_000):
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC, path
    assert len(data) > min_bytes, (path, len(data))


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def test_unknown_experiment_exits_2_and_lists_them(tmp_path):
    r = experiment("no-such-thing", "--out", str(tmp_path), timeout=60)
    assert r.returncode == 2
    for name in ("motion-noise", "lidar", "noisy-lidar", "noisy-odometry", "camera"):
        assert name in r.stderr


def test_motion_noise_spreads_with_noise(tmp_path):
    s, r = run_ok("motion-noise", tmp_path, "--runs", "5", "--seed", "3")
    assert "5/5 runs" in r.stderr                                  # the progress bar
    assert_png(tmp_path / "motion_noise.png")
    header, rows = read_csv(tmp_path / "endpoints.csv")
    assert header[:4] == ["run", "seed", "gps_x_m", "gps_y_m"]
    assert [int(row[1]) for row in rows] == [3, 4, 5, 6, 7]        # a new seed per run
    assert s["plant_process_starts"] == 1 and s["runs_done"] == 5
    assert s["parameters"]["command_noise_std_radps"] == 0.1
    assert s["parameters"]["wheel_floor_friction"] == 0.4
    std = s["endpoint_std_m"]
    assert std[0] > 1e-4 and std[1] > 1e-5
    mean = s["endpoint_mean_m"]
    assert mean[0] - (-1.0) == pytest.approx(0.3, abs=0.03)       # drove ~0.3 m along +x
    assert np.asarray(s["endpoint_cov_m2"]).shape == (2, 2)
    assert s["mean_slip_gap_m"] > 0                                # friction 0.4: some slip


def test_motion_noise_without_noise_is_deterministic(tmp_path):
    s, _ = run_ok("motion-noise", tmp_path, "--runs", "3", "--command-noise", "0",
                  "--friction", "1.0")
    assert max(s["endpoint_std_m"]) < 1e-9
    _, rows = read_csv(tmp_path / "endpoints.csv")
    assert len({(row[2], row[3]) for row in rows}) == 1            # identical to the digit


def test_lidar_scan_csv_and_figure(tmp_path):
    s, _ = run_ok("lidar", tmp_path)
    assert_png(tmp_path / "lidar.png")
    header, rows = read_csv(tmp_path / "scan.csv")
    assert header == ["angle_rad", "range_m"]
    a = np.array([[float(v) for v in row] for row in rows])
    assert a.shape == (180, 2)
    assert a[0, 0] == pytest.approx(-math.pi / 2, abs=1e-6)
    assert a[-1, 0] == pytest.approx(math.pi / 2, abs=1e-6)
    assert np.allclose(np.diff(a[:, 0]), math.pi / 179, atol=1e-6)
    assert np.all(np.isfinite(a[:, 1])) and a[:, 1].max() < 10.0 and a[:, 1].min() > 0.1
    assert s["rays"] == 180 and s["finite_rays"] == 180


def test_noisy_lidar_webots_value_in_metres(tmp_path):
    s, _ = run_ok("noisy-lidar", tmp_path)
    assert_png(tmp_path / "noisy_lidar.png")
    p = s["parameters"]
    assert p["lidar_noise_webots"] == 0.2 and p["lidar_noise_std_m"] == pytest.approx(16.0)
    assert "16 m" in s["noise_meaning"] and "relative to maxRange" in s["noise_meaning"]
    assert f"{100 * s['fraction_clipped_to_min_range']:.0f} % of the rays read the 0.01 m minimum" \
        in s["noise_meaning"]
    header, rows = read_csv(tmp_path / "scan_noisy.csv")
    assert header == ["angle_rad", "range_noiseless_m", "range_noisy_m"] and len(rows) == 180
    # clipping to [0.01, 80] m leaves less than 16 m of spread; measured matches the model
    assert s["measured_residual_std_m"] == pytest.approx(
        s["expected_residual_std_with_clipping_m"], rel=0.25)


def test_noisy_lidar_std_in_metres_option(tmp_path):
    s, _ = run_ok("noisy-lidar", tmp_path, "--lidar-noise-std", "0.05")
    assert s["parameters"]["lidar_noise_std_m"] == 0.05
    assert s["parameters"]["lidar_noise_webots"] is None
    assert s["fraction_clipped_to_min_range"] == 0.0 == s["fraction_clipped_to_max_range"]
    assert s["expected_residual_std_with_clipping_m"] == pytest.approx(0.05)   # none clipped
    # explained as given: an absolute std on every ray, not one relative to the max range
    assert s["noise_meaning"].startswith("std 0.05 m (given in metres): the same Gaussian std")
    assert "relative to maxRange" not in s["noise_meaning"] and "no ray was clipped" in s["noise_meaning"]
    # 180 rays of N(0, 0.05 m): the sample std within 4 standard errors of 0.05
    # (0.05 / sqrt(2 * 180) = 2.6 mm each), the mean within 4 of 0 (0.05 / sqrt(180))
    n = s["rays"]
    assert s["measured_residual_std_m"] == pytest.approx(0.05, abs=4 * 0.05 / math.sqrt(2 * n))
    assert abs(s["measured_residual_mean_m"]) < 4 * 0.05 / math.sqrt(n)


def test_noisy_odometry_square(tmp_path):
    s, _ = run_ok("noisy-odometry", tmp_path, "--side", "0.5", timeout=170)
    assert_png(tmp_path / "odometry_vs_gps.png")
    header, rows = read_csv(tmp_path / "trajectory.csv")
    assert header[:6] == ["t_s", "odom_x_m", "odom_y_m", "odom_theta_rad", "gps_x_m", "gps_y_m"]
    assert len(rows) > 100
    assert s["parameters"]["encoder_noise_std_rad"] == 0.2
    # What 0.2 rad of noise on each encoder reading (not accumulated) does to odometry that
    # integrates their differences: the distance telescopes to the last reading's noise
    # minus the first's, sigma_d = r * 0.2 = 24 mm; the heading to (r / d) * 0.2 * sqrt(2)
    # = 94 mm per m, the first reading's part turning the whole odometry path about the
    # start. So the error ends within 4 sigma_d (+ the turn times the closure) and peaks
    # within 4 sigma_d + 4 sigma_theta * 0.71 m (the far corner of the 0.5 m square); and
    # is not the noiseless run's few mm. (Seeds 0-3: end 8-75 mm, peak 75-147 mm.)
    r, d, noise, corner = 0.12, 0.36, 0.2, 0.5 * math.sqrt(2)
    sigma_d, sigma_theta = r * noise, r / d * noise * math.sqrt(2)
    closure = s["path_closure_m"]
    assert s["final_odom_error_m"] < 4 * sigma_d + 4 * sigma_theta * closure
    assert sigma_d / 2 < s["max_odom_error_m"] < 4 * sigma_d + 4 * sigma_theta * corner
    assert s["max_odom_error_m"] >= s["final_odom_error_m"]
    assert all(c == 0 for c in s["run"]["exit_codes"].values()), s["run"]["exit_codes"]


def test_camera_images_are_real_pngs_in_rgb_order(tmp_path):
    cv2 = pytest.importorskip("cv2")
    s, _ = run_ok("camera", tmp_path)
    assert_png(tmp_path / "camera_compare.png")
    clean = cv2.imread(str(tmp_path / "camera.png"))               # BGR
    noisy = cv2.imread(str(tmp_path / "camera_noisy.png"))
    assert clean.shape == noisy.shape == (120, 160, 3)
    sky = clean[:5].reshape(-1, 3).mean(axis=0)                    # the top rows see the sky
    assert sky[0] > sky[2] + 20                                     # blue > red: RGB saved right
    assert s["parameters"]["camera_noise_std_levels"] == pytest.approx(51.0)
    assert s["measured_residual_std_levels"] == pytest.approx(
        s["expected_residual_std_with_clipping_levels"], rel=0.05)
    resid = noisy.astype(float) - clean.astype(float)
    assert 35 < resid.std() < 55
