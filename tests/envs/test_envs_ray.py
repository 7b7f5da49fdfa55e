"""The batched Avoid env's chunks on a real two-node Ray cluster (tests/support/ray_cluster.py,
conftest's session cluster): ``workers=2, engine="ray"`` puts one chunk on each node, and
every env is the same env, to the bit, as in one process (observations, rewards, flags,
the episodes of ``info["plant"]``, through autoresets)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("gymnasium")
pytest.importorskip("ray", reason="the [cluster] extra (make setup installs it)")

#: xdist_group: one worker starts the session's Ray cluster (conftest.ray_cluster)
pytestmark = [pytest.mark.slow, pytest.mark.timeout(300), pytest.mark.xdist_group("ray")]
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

#: a driver of its own (Ray's connection stays out of the test process)
DRIVER = r'''
import json, sys
import numpy as np
import gymnasium as gym
import diffbot.envs
kw = dict(num_envs=4, vectorization_mode="vector_entry_point", max_episode_steps=8,
          overrides=("world.mode=kinematic", "robots.robot1.lidar.noise={std = 0.01}"))
remote = gym.make_vec("diffbot/Avoid-v0", workers=2, engine="ray", address=sys.argv[1], **kw)
local = gym.make_vec("diffbot/Avoid-v0", **kw)
diffs, resets = [], 0
a, b = remote.reset(seed=5), local.reset(seed=5)
diffs += [k for k in a[0] if a[0][k].tobytes() != b[0][k].tobytes()]
rng = np.random.default_rng(0)
for step in range(12):
    act = (rng.uniform(-1, 1, (4, 2)) * remote.single_action_space.high).astype(np.float32)
    a, b = remote.step(act), local.step(act)
    diffs += [f"{k} at {step}" for k in a[0] if a[0][k].tobytes() != b[0][k].tobytes()]
    if a[1].tobytes() != b[1].tobytes() or list(a[2]) != list(b[2]) \
            or list(a[3]) != list(b[3]) or list(a[4]["plant"]) != list(b[4]["plant"]):
        diffs.append(f"step {step}")
    resets += int((a[2] | a[3]).sum())
nodes = sorted({c.node() for c in remote.unwrapped.chunks})
remote.close()
local.close()
print(json.dumps({"diffs": diffs, "nodes": nodes, "resets": resets}))
'''


@pytest.fixture
def cluster(ray_cluster):
    """The session's two-node cluster (conftest), both nodes alive."""
    ray_cluster.revive()
    return ray_cluster


def test_chunks_on_two_nodes_step_the_same_envs_to_the_bit(cluster):
    env = {**os.environ, **{k: v for k, v in cluster.env.items() if k.startswith("RAY_")},
           "PYTHONPATH": ROOT}
    out = subprocess.run([sys.executable, "-c", DRIVER, cluster.address], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["diffs"] == [], got
    assert len(got["nodes"]) == 2, f"the chunks ran on {got['nodes']}, not on both nodes"
    assert got["resets"] >= 2, "no autoreset was crossed"
