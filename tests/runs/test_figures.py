"""`diffbot figures`: the study's figures from real runs, with index.html, REPORT.md and
figures.json; the renders show the robot; bad figure numbers are refused."""
from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from diffbot.study import figures, figures_cli
from diffbot.study.figures_render import colour_fraction

from ..conftest import ROOT, check_real_time_factor

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run_figures(*args, timeout=80):
    return subprocess.run([sys.executable, "-m", "diffbot.cli", "figures", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def test_only_parses_lists_and_ranges():
    assert figures_cli.parse_only("4,12") == [4, 12]
    assert figures_cli.parse_only("1-3, 7") == [1, 2, 3, 7]
    assert figures_cli.parse_only(None) == list(range(1, 13))
    for bad in ("13", "0", "x", "3-1", "", "4,13"):
        with pytest.raises(ValueError):
            figures_cli.parse_only(bad)


def test_every_figure_names_existing_jobs():
    assert sorted(figures.FIGURES) == list(range(1, 13))
    for f in figures.FIGURES.values():
        assert f.file.startswith(f"fig{f.number:02d}_") and f.file.endswith(".png")
        assert f.jobs and all(j in figures.JOBS for j in f.jobs)


@pytest.mark.slow
def test_bad_only_exits_2_and_runs_nothing(tmp_path):
    r = run_figures("--out", str(tmp_path / "figs"), "--only", "13", timeout=30)
    assert r.returncode == 2, r.stderr
    assert "no figure 13" in r.stderr
    assert not (tmp_path / "figs").exists()


@pytest.mark.slow
def test_figures_1_to_3_render_and_drive_test(tmp_path):
    out = tmp_path / "figs"
    r = run_figures("--out", str(out), "--only", "1,2,3")
    assert r.returncode == 0, r.stderr
    assert "start drive-test" in r.stderr and "done  render" in r.stderr      # progress
    names = ["fig01_robot.png", "fig02_linear_velocity.png", "fig03_angular_velocity.png"]
    for name in names:
        data = (out / name).read_bytes()
        assert data[:8] == PNG_MAGIC and len(data) > 10_000, (name, len(data))
    assert not (out / "fig04_motion_noise.png").exists()                    # only what was asked
    runs = sorted(p.name for p in (out / "runs").iterdir() if p.is_dir())
    assert runs == ["drive-test", "render"]

    # the renders are pictures of the robot, not a blank frame
    import matplotlib.image as mpimg
    for name in ("robot.png",):
        img = (mpimg.imread(out / "runs" / "render" / name)[..., :3] * 255).astype(np.uint8)
        assert img.std() > 20
        assert colour_fraction(img, (0.15, 0.35, 0.80)) > 0.05      # robot1's blue chassis
    fig1 = (mpimg.imread(out / "fig01_robot.png")[..., :3] * 255).astype(np.uint8)
    assert fig1.std() > 20 and colour_fraction(fig1, (0.15, 0.35, 0.80)) > 0.05
    render = json.loads((out / "runs" / "render" / "summary.json").read_text())
    assert all(f > 0.02 for f in render["robot_colour_fraction"])   # every view shows it

    report = json.loads((out / "figures.json").read_text())
    figs = {f["number"]: f for f in report["figures"]}
    assert sorted(figs) == [1, 2, 3] and all(f["status"] == "ok" for f in figs.values())
    v = figs[2]["numbers"]["steady_linear_velocity_mps"]
    w = figs[3]["numbers"]["steady_angular_velocity_radps"]
    assert v == pytest.approx(0.12, abs=0.003)
    assert w == pytest.approx(-0.12 * 2 / 0.36, abs=0.01)           # counter-clockwise positive
    assert report["runs"]["drive-test"]["exit_code"] == 0
    check_real_time_factor(report["runs"]["drive-test"])

    page = (out / "index.html").read_text()
    for n, name in enumerate(names, 1):
        assert f'src="{name}"' in page                                       # relative links
        assert f"Figure {n}: {figures.FIGURES[n].study_caption}" in page
        assert figs[n]["caption"][:40] in page.replace("&quot;", '"').replace("&#x27;", "'")
    assert not re.search(r'src="(/|[a-z]+:)', page)                          # self-contained
    assert "steady_linear_velocity_mps" in page and f"{v:.5g}" in page
    md = (out / "REPORT.md").read_text()
    for n, name in enumerate(names, 1):
        assert f"]({name})" in md and f"Figure {n}:" in md
    assert "steady_angular_velocity_radps" in md


@pytest.mark.slow
def test_a_failed_job_is_reported_and_the_rest_still_written(tmp_path, monkeypatch):
    """A job that fails (here: the drive-test pointed at a scenario that does not exist)
    gives exit code 1 and its log tail; the render's figure is still written."""
    out = tmp_path / "figs"
    spec = figures.JOBS["drive-test"]
    monkeypatch.setitem(figures.JOBS, "drive-test",
                        figures.JobSpec(spec.name, ("run", "no-such-scenario"), spec.est_s,
                                        spec.what))
    code = figures_cli.main(["--out", str(out), "--only", "1,2"])
    assert code == 1
    report = json.loads((out / "figures.json").read_text())
    figs = {f["number"]: f for f in report["figures"]}
    assert figs[1]["status"] == "ok" and (out / "fig01_robot.png").exists()
    assert figs[2]["status"] != "ok" and not (out / "fig02_linear_velocity.png").exists()
    assert report["runs"]["drive-test"]["status"] == "failed"
    assert "no-such-scenario" in report["runs"]["drive-test"]["log_tail"]
    assert "Not made" in (out / "index.html").read_text()
