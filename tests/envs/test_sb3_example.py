"""examples/learn/ppo_avoid.py (PPO from Stable-Baselines3, the `sb3` extra) trains through
diffbot.envs.sb3, scores and saves a model with its env's spec, and the model drives the
robot over the bus as a hosted controller class, its actions scaled as in training.
Skipped, with the reason, where the extra is not installed (`make setup TORCH=`)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("gymnasium")
pytest.importorskip("torch", reason="the sb3 extra is not installed (make setup installs it)")
pytest.importorskip("stable_baselines3",
                    reason="the sb3 extra is not installed (make setup installs it)")

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

#: no wall-clock promise: runs beside the serial tests, at a low CPU priority (conftest.py)
pytestmark = pytest.mark.background


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
    dep = subprocess.run([sys.executable, "-m", "diffbot.launch.deploy", "--seed", "3",
                          "--controller", ctl, "--duration", "2", "--set", "world.mode=kinematic",
                          "--out", str(tmp_path / "run")],
                         cwd=ROOT, capture_output=True, text=True, timeout=180)
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert dep.returncode == 0, dep.stderr[-3000:]
    assert summary["sim_time_s"] > 1.0
    assert (out / "model.spec.json").exists()


@pytest.mark.parametrize("normalize", [False, True])
def test_sb3_policy_scales_actions_as_the_env_it_was_trained_in(tmp_path, normalize):
    # a model saved with its env's spec (as the example saves it), and one without: the
    # deployed controller commands what the env commands for the same action
    from stable_baselines3 import PPO
    from diffbot.envs.avoid import AvoidEnv
    from diffbot.envs.sb3 import AvoidVecEnv
    sys.path.insert(0, os.path.join(ROOT, "examples", "learn"))
    try:
        import ppo_avoid
    finally:
        sys.path.pop(0)
    venv = AvoidVecEnv(1, normalize_actions=normalize)
    try:
        model = PPO("MultiInputPolicy", venv, n_steps=8, batch_size=8, device="cpu")
    finally:
        venv.close()
    model.save(str(tmp_path / "model.zip"))
    (tmp_path / "model.spec.json").write_text(venv.spec.to_json())
    env = AvoidEnv(normalize_actions=normalize)
    try:
        want = env.unwrapped._task.drives["robot1"]
        for spec in (True, False):
            if not spec:
                (tmp_path / "model.spec.json").unlink()
            policy = ppo_avoid.SB3Policy(str(tmp_path / "model.zip"))
            drive = ppo_avoid.drive_of(policy.model.action_space, policy.env_kw, "robot1")
            for a in ([0.5, -0.5], [1.0, 1.0], [-0.2, 0.7]):
                assert drive.command(a) == want.command(a), (spec, a)
    finally:
        env.close()
    # a spec that says otherwise than the model's action space is refused
    (tmp_path / "model.spec.json").write_text(_spec_json(not normalize))
    with pytest.raises(ValueError, match="action space"):
        p = ppo_avoid.SB3Policy(str(tmp_path / "model.zip"))
        ppo_avoid.drive_of(p.model.action_space, p.env_kw, "robot1")


def _spec_json(normalize: bool) -> str:
    from diffbot.envs.sb3 import _spec
    return _spec({"normalize_actions": normalize}, 300).to_json()
