"""The peers suite's MuJoCo room (diffbot/bench/peers.py) is the living room: every static
object of the world file, the walls, a robot that stands on its wheels and spins in place
as the physics suite's does. MuJoCo is no dependency: without it this skips."""
from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="mujoco is not installed (an optional peer, "
                                              "not in make setup: pip install mujoco)")


def test_the_mujoco_room_is_the_world_file_s_and_its_robot_spins_in_place():
    from diffbot.bench.peers import room_mjcf
    from plant.world import load_world
    spec = load_world("living_room")
    model = mujoco.MjModel.from_xml_string(room_mjcf(spec))
    statics = sum(o.static for o in spec.objects)
    assert model.ngeom == 1 + 4 + statics + 4          # floor, walls, furniture, robot
    data = mujoco.MjData(model)
    data.ctrl[:] = (1.0, -1.0)
    body = model.body("robot").id
    mujoco.mj_forward(model, data)
    start = data.xpos[body].copy()
    for _ in range(500):                               # 1 s
        mujoco.mj_step(model, data)
    moved = np.hypot(*(data.xpos[body][:2] - start[:2]))
    assert moved < 0.05, moved                         # in place ...
    assert abs(data.qvel[5]) > 0.3                     # ... turning (wheels -/+1 rad/s)
    assert abs(data.xpos[body][2] - start[2]) < 0.02   # on its wheels
