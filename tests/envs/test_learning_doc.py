"""docs/learning.md's Python snippets run as written (each in a fresh interpreter): the
conventions, the batched env with masked resets, a recorded video, deployment by seed, the
swarm; and its deployment check, ``python -m diffbot.launch.deploy ... --compare``, runs as
written. Blocks that start worker processes (async make_vec) or train with
Stable-Baselines3 (torch's import alone is seconds of CPU) are left to their own tests:
tests/envs/test_envs_sb3.py trains PPO through the adapter as the page does."""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys

import pytest

pytest.importorskip("gymnasium")

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DOC = os.path.join(ROOT, "docs", "learning.md")
SKIP = ("vectorization_mode=\"async\"", "stable_baselines3")

#: no wall-clock promise: runs beside the serial tests, at a low CPU priority (conftest.py)
pytestmark = pytest.mark.background


def _blocks() -> list[tuple[int, str]]:
    text = open(DOC, encoding="utf-8").read()
    out = []
    for m in re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M):
        line = text[:m.start()].count("\n") + 1
        out.append((line, m.group(1)))
    return out


BLOCKS = [(line, code) for line, code in _blocks() if not any(s in code for s in SKIP)]


def test_the_page_has_the_snippets():
    joined = "\n".join(code for _, code in BLOCKS)
    for what in ("normalize_actions=True", "vector_entry_point", "render_mode=\"rgb_array\"",
                 "plant_args()", "reset_mask", "RecordVideo", "swarm_v0", "vector_env("):
        assert what in joined, f"no runnable snippet shows {what}"


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("line,code", BLOCKS, ids=[f"line{line}" for line, _ in BLOCKS])
def test_snippet_runs(line, code):
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=280)
    assert out.returncode == 0, f"docs/learning.md:{line}:\n{out.stderr[-3000:]}"


def _hand_set_policy(path: str) -> None:
    """A linear policy set by hand (tests/envs/test_envs_deploy.py's): ahead when the goal is
    ahead, turn toward it."""
    import numpy as np
    from controllers.learned import N_FEATURES, MLPPolicy
    W = np.zeros((N_FEATURES, 2))
    W[13, 0], W[12, 0] = 1.5, 1.0
    W[14, 1] = 3.0
    MLPPolicy([(W, np.array([-0.5, 0.0]))], v_max=0.5, w_max=2.0, action_repeat=5,
              v_min=-0.1).save(path)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_deployment_check_runs_as_written(tmp_path):
    # the page's `--compare` command, in a folder where its policy file is a hand-set policy
    text = open(DOC, encoding="utf-8").read()
    cmd = next(line.strip() for line in text.splitlines()
               if "diffbot.launch.deploy" in line and line.rstrip().endswith("--compare"))
    argv = shlex.split(cmd)
    assert argv[0] == ".venv/bin/python"
    policy = argv[argv.index("--policy") + 1]
    os.makedirs(tmp_path / os.path.dirname(policy))
    _hand_set_policy(str(tmp_path / policy))
    env = {**os.environ, "PYTHONPATH": ROOT}
    out = subprocess.run([sys.executable, *argv[1:]], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    assert "identical: all" in out.stdout
    seed = argv[argv.index("--seed") + 1]
    assert (tmp_path / "out" / f"episode_{seed}" / "compare.json").exists()
