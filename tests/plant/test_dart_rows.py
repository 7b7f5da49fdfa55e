"""A dynamic world's state rows read from DART with only what the tick needs: the body
velocities left out where no ground_truth is made, read later into the same rows with the
bits a whole read gives."""
from __future__ import annotations

import numpy as np
import pytest

from bus.controller import Twist, WheelSpeeds
from plant.swarm_world import write_swarm_world
from plant.tick import Tick
from plant.world import load_world


def _world(kind: str, tmp_path):
    if kind == "follow":                         # two robots: read robot by robot
        return load_world("living_room_follow")
    return load_world(write_swarm_world(str(tmp_path / "w.toml"), 4, seed=2, mode="dynamic"))


def _drive(tick: Tick, k: int) -> None:
    for i, name in enumerate(tick.sensors):
        tick.drive(name, Twist(0.3, 0.8 * ((i + k // 5) % 3 - 1)) if (i + k) % 3 else
                   WheelSpeeds(2.0, 2.5 + 0.1 * k))


@pytest.mark.parametrize("kind", ["follow", "swarm"])
def test_rows_without_velocities_are_a_whole_read_once_filled(kind, tmp_path):
    tick = Tick(_world(kind, tmp_path), ("lidar", "camera"))
    sim = tick.sim
    for k in range(12):
        _drive(tick, k)
        assert tick.step()
        whole, ok = sim.read_state()
        part, ok_part = sim.read_state(velocities=False)
        assert ok and ok_part
        assert np.isnan(part[:, 16:22]).all()
        assert part[:, :16].tobytes() == whole[:, :16].tobytes()
        assert part[:, 22:].tobytes() == whole[:, 22:].tobytes()
        sim.fill_velocities(part)
        assert part.tobytes() == whole.tobytes(), k


@pytest.mark.parametrize("kind", ["follow", "swarm"])
def test_the_plant_reads_velocities_only_for_a_tick_that_makes_a_ground_truth(kind, tmp_path):
    """The plant's sensing (``messages_read``) with no ground_truth reader leaves the
    velocities unread; on a tick someone reads it, its bytes are those of a tick that read
    everything."""
    plant, oracle = Tick(_world(kind, tmp_path)), Tick(_world(kind, tmp_path))
    names = list(plant.sensors)
    made = 0
    for k in range(10):
        truth = k % 3 == 1                       # ground_truth read every third tick
        wanted = {n: (lambda topic: topic != "ground_truth" or truth) for n in names}
        _, msgs = plant.messages_read(wanted)
        read = plant.stepper._read
        assert read[3] == truth and np.isnan(read[1][:, 16:22]).all() != truth, k
        expect = {(r, t): m for r, t, m in oracle.messages(None, encoded=True)}
        for _, robot, topic, data in msgs:
            assert data == expect[(robot, topic)], (k, robot, topic)
            made += topic == "ground_truth"
        for t in (plant, oracle):
            _drive(t, k)
            assert t.step()
    assert made == 3 * len(names)
