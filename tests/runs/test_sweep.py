"""`diffbot sweep`: the grid, the table, failures retried, Ctrl-C, resume (local engine)."""
from __future__ import annotations

import csv
import os
import signal
import time

import pytest

from diffbot.runner import procs as dprocs
from diffbot.sweep.grid import parse_axis, parse_seeds, points, split_values
from diffbot.sweep.table import flatten

from ..conftest import check_real_time_factor, wait_for
from ..network.test_exposure import cmdline as _cmdline

NOISE = "robots.robot1.motion.command_noise_std_radps"
#: one xdist group with tests/runs/test_sweep_ray.py, whose reference is this file's sweep
#: (conftest.local_sweep)
pytestmark = pytest.mark.xdist_group("ray")


def read_rows(out: str) -> list[dict]:
    with open(os.path.join(out, "sweep.csv"), newline="") as f:
        return list(csv.DictReader(f))


# ------------------------------------------------------------------ the grid (no processes)
def test_values_split_on_top_level_commas_only():
    assert split_values("0, 10,20") == ["0", "10", "20"]
    assert split_values('{std = 1.0, clip = true},"a,b",[1, 2]') == \
        ["{std = 1.0, clip = true}", '"a,b"', "[1, 2]"]


def test_grids_multiply_and_become_run_options_or_world_overrides():
    axes = [parse_axis(f"{NOISE}=0,0.1"), parse_axis("coupling=sequential,pipelined")]
    pts = points(axes, parse_seeds("3-5"))
    assert len(pts) == 2 * 2 * 3
    assert pts[0].values == (0, "sequential") and pts[0].seed == 3
    assert pts[-1].run_args(axes) == ["--seed", "5", "--set", f"{NOISE}=0.1",
                                      "--coupling", "pipelined"]
    assert len({p.run_id(axes) for p in pts}) == len(pts)


@pytest.mark.parametrize("bad", ["noise", "x.y=", "=1,2", "nonsense=1,2", "a.b=1,1"])
def test_a_bad_grid_is_a_clear_error(bad):
    with pytest.raises(ValueError, match="--grid"):
        parse_axis(bad)


def test_seeds():
    assert parse_seeds("0-3") == [0, 1, 2, 3]
    assert parse_seeds("7") == [7]
    assert parse_seeds("1,4,2-3") == [1, 4, 2, 3]
    for bad in ("3-1", "-1", "a"):
        with pytest.raises(ValueError, match="--seeds"):
            parse_seeds(bad)


def test_every_scalar_metric_is_a_column_and_an_unmeasured_one_an_empty_cell():
    m = {"a": 1.5, "r": {"b": 2, "ok": True, "why": "text"}, "none": None, "l": [1, 2]}
    assert flatten(m) == {"a": 1.5, "r.b": 2, "r.ok": 1, "none": None}


@pytest.mark.slow
def test_a_wrong_world_key_exits_2_before_any_run(procs, tmp_path):
    p = procs.diffbot("sweep", "drive-test", "--grid", "robots.robot1.motoin.x=1,2",
                      "--out", str(tmp_path / "s"))
    assert p.wait(60) == 2
    assert "motoin" in procs.log(p)
    assert not os.path.exists(tmp_path / "s" / "runs")


# ------------------------------------------------------------------ real runs
@pytest.mark.slow
def test_sweep_table_plots_and_resume(procs, local_sweep):
    out, args = local_sweep["out"], local_sweep["args"]      # (conftest.LOCAL_SWEEP)
    assert f"{NOISE}=0,0.3" in args
    rows = read_rows(out)
    assert [(r[NOISE], r["seed"]) for r in rows] == [("0", "0"), ("0", "1"), ("0.3", "0"),
                                                      ("0.3", "1")]
    assert all(r["status"] == "ok" and r["exit_code"] == "0" for r in rows)
    assert all(r["node"] for r in rows)
    for r in rows:
        check_real_time_factor(r)
    v = [float(r["steady_angular_velocity_radps"]) for r in rows]
    assert v[0] == v[1]                      # no noise: the seed changes nothing
    assert v[2] != v[3] and v[0] != v[2]     # motion noise: it does
    for r in rows:
        assert os.path.isfile(os.path.join(out, r["out"], "summary.json"))
    png = os.path.join(out, "plots", f"steady_angular_velocity_radps_vs_{NOISE}.png")
    with open(png, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    # the same command again: every run finished, nothing runs, the table is the same
    before = os.path.getmtime(os.path.join(out, rows[0]["out"], "summary.json"))
    p = procs.diffbot(*args)
    assert p.wait(60) == 0, procs.log(p)
    assert "4 already done" in procs.log(p)
    assert read_rows(out) == rows
    assert os.path.getmtime(os.path.join(out, rows[0]["out"], "summary.json")) == before


@pytest.mark.slow
def test_a_failed_run_is_a_row_with_its_log_tail_and_is_retried(procs, tmp_path):
    out = str(tmp_path / "sweep")
    # 1 s of wall clock cannot hold 30 s of simulated time paced to the wall clock (in
    # lockstep a composed drive-test ran its schedule within 1 s): `diffbot run` fails
    p = procs.diffbot("sweep", "drive-test", "--grid", f"{NOISE}=0", "--grid", "mode=realtime",
                      "--duration", "30", "--timeout", "1", "--retries", "1", "--out", out)
    assert p.wait(100) == 1, procs.log(p)
    (row,) = read_rows(out)
    assert row["status"] == "failed" and row["exit_code"] not in ("", "0")
    assert row["attempts"] == "2"
    assert "timeout" in row["log_tail"].lower()


@pytest.mark.slow
def test_ctrl_c_cancels_queued_runs_and_stops_running_ones(procs, tmp_path):
    out = str(tmp_path / "sweep")
    p = procs.diffbot("sweep", "drive-test", "--grid", f"{NOISE}=0,0.1", "--seeds", "0-3",
                      "--duration", "60", "--max-parallel", "2", "--out", out)
    tree: set[int] = set()

    def plants_running() -> bool:
        tree.update(dprocs.descendants(p.pid))
        return sum("plant" in _cmdline(pid) for pid in tree) >= 2
    wait_for(plants_running, 60, 0.1, "two runs' plants")
    time.sleep(0.5)
    tree.update(dprocs.descendants(p.pid))
    p.send_signal(signal.SIGINT)
    assert p.wait(60) == 130, procs.log(p)
    left = [pid for pid in tree if dprocs.alive(pid)]
    assert not left, [(pid, _cmdline(pid)) for pid in left]
    rows = read_rows(out)
    status = sorted(r["status"] for r in rows)
    assert status.count("interrupted") == 2 and status.count("skipped") == 6, status



def test_a_run_folder_from_another_machine_arrives_whole(tmp_path):
    from diffbot.runner.task import pack, unpack
    src = tmp_path / "remote"
    (src / "logs").mkdir(parents=True)
    (src / "summary.json").write_text('{"metrics": {"x": 1.5}}')
    (src / "logs" / "plant.log").write_bytes(b"\x00\xffbinary")
    dest = tmp_path / "here"
    dest.mkdir()
    (dest / "stale.txt").write_text("from an earlier attempt")
    unpack(pack(str(src)), str(dest))
    assert sorted(p.relative_to(dest).as_posix() for p in dest.rglob("*")) == \
        ["logs", "logs/plant.log", "summary.json"]
    assert (dest / "logs" / "plant.log").read_bytes() == b"\x00\xffbinary"
