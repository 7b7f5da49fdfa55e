"""A launcher that stops reading for a while (suspended, swapped out) pauses a lockstep run,
and the run then ends as it would have, its outputs whole.

The launcher's observer says what it has taken in (``sim/seen/observer``), so the plant
does not run ahead of it and fill its router's queue towards it: a reliable put into a
full queue blocks the router's receiving threads, and a lockstep member's link left
unread for longer than its lease was dropped (the members exited 3, the run 1). The
launcher's session announces a longer lease than the members', so the router keeps it
while it is stopped and the paced plant waits for it.
"""
from __future__ import annotations

import csv
import json
import os
import signal
import time

import pytest

from ..conftest import ROOT, require_built_fmus
from .test_faults import finish, launch, wait_running

pytestmark = [pytest.mark.slow, pytest.mark.serial]

#: how long the launcher is stopped: twice the members' 1 s lease
STOP_S = 2.0


def test_a_launcher_stopped_for_2_s_pauses_the_run_which_ends_whole(tmp_path):
    require_built_fmus()
    square = open(os.path.join(ROOT, "diffbot/launch/scenarios/square.toml")).read()
    assert '"--side", "1.5"' in square
    # a short square (~17 s of simulated time): the stop comes at its start
    run = launch(tmp_path, square.replace('"--side", "1.5"', '"--side", "0.4"'), "stalled",
                 "--no-plots")
    try:
        wait_running(run)
        time.sleep(0.2)
        os.kill(run.pid, signal.SIGSTOP)
        time.sleep(STOP_S)
    finally:
        os.kill(run.pid, signal.SIGCONT)
    code, err = finish(run)
    assert code == 0, err
    summary = json.load(open(run.out / "summary.json"))
    assert set(summary["exit_codes"].values()) == {0}, summary["exit_codes"]
    plant_log = (run.out / "logs" / "plant.log").read_text()
    assert "lost" not in plant_log, plant_log
    # the plant waited for the stopped launcher (the stop came while the run was going)
    assert json.load(open(run.out / "logs" / "plant.json"))["paced_s"] > STOP_S / 2
    # the trajectory is whole: a row every 20 ms tick from t=0 to the square's end
    with open(run.out / "trajectory.csv") as f:
        t = [float(row["t_s"]) for row in csv.DictReader(f)]
    assert t[0] == 0.0 and t[-1] > 10.0, t[-1]
    gaps = [b - a for a, b in zip(t, t[1:])]
    assert max(gaps) < 0.021 and min(gaps) > 0.019, (min(gaps), max(gaps))
