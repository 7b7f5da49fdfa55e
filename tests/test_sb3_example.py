"""examples/learn/ppo_avoid.py (PPO from Stable-Baselines3, the `sb3` extra, not in `make
setup`) trains, scores and saves a model, and the model drives the robot over the bus as a
hosted controller class. Skipped, with the reason, where the extra is not installed."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("gymnasium")
pytest.importorskip("torch", reason="the sb3 extra is not installed (pip install -e '.[sb3]')")
pytest.importorskip("stable_baselines3",
                    reason="the sb3 extra is not installed (pip install -e '.[sb3]')")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_ppo_example_trains_saves_and_deploys_as_a_node(tmp_path):
    out = tmp_path / "ppo"
    run = subprocess.run([sys.executable, "examples/learn/ppo_avoid.py", "--quick", "--out",
                          str(out)], cwd=ROOT, capture_output=True, text=True, timeout=400)
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads((out / "result.json").read_text())
    assert result["train_steps"] == 512 and 0.0 <= result["success_ppo"] <= 1.0
    assert (out / "model.zip").exists() and (out / "curve.png").exists()
    # the saved model as `diffbot controller PATH.py:CLASS`, on an episode over the bus
    ctl = f"examples/learn/ppo_avoid.py:SB3Policy --arg model={out / 'model.zip'}"
    dep = subprocess.run([sys.executable, "-m", "diffbot.envs.deploy", "--seed", "3",
                          "--controller", ctl, "--duration", "3", "--out", str(tmp_path / "run")],
                         cwd=ROOT, capture_output=True, text=True, timeout=180)
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert dep.returncode == 0, dep.stderr[-3000:]
    assert summary["sim_time_s"] > 1.0
