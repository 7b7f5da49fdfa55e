"""The messages a composed member takes from the tick's values (plant.handover) are, field
for field, the objects decoding the plant's bytes gives: the same types, float32 fields
rounded as the wire rounds them, the ranges' and encoders' bits, arrays read-only as a
decoded view is."""
from __future__ import annotations

import dataclasses

import numpy as np

from bus import codec
from plant.handover import Handover
from plant.tick import Tick

from .test_core import _drive, _wanted, _world


def _same(got, want, where: str = "") -> None:
    assert type(got) is type(want), where
    if dataclasses.is_dataclass(want):
        for f in dataclasses.fields(want):
            _same(getattr(got, f.name), getattr(want, f.name), f"{where}.{f.name}")
    elif isinstance(want, np.ndarray):
        assert got.dtype == want.dtype and got.shape == want.shape, where
        assert got.tobytes() == want.tobytes(), where
        assert not got.flags.writeable, where
    elif isinstance(want, float):
        assert np.float64(got).tobytes() == np.float64(want).tobytes(), where
    else:
        assert got == want, where


_TYPES = {"scan": "sensor_msgs/msg/LaserScan", "joint_states": "sensor_msgs/msg/JointState",
          "gps": "geometry_msgs/msg/PointStamped", "ground_truth": "nav_msgs/msg/Odometry"}


def test_handed_messages_are_the_decoded_bytes(tmp_path):
    """A kinematic swarm with noisy lidars (one quantised: two lidar models), noisy
    encoders and GPS, readers that come and go, a reset: every scan, joint_states, gps and
    ground_truth due and read is handed, equal to its bytes decoded; other topics, and messages of a
    tick not due or not read, are not (the member decodes those)."""
    tick = Tick(_world("kinematic", tmp_path))
    names = list(tick.sensors)
    handover, counts = None, dict.fromkeys(_TYPES, 0)
    for k in range(24):
        want = _wanted(names, k)
        _, msgs = tick.messages_read(want or {n: (lambda t: True) for n in names})
        handover = Handover.of(handover, tick.model, tick.data)
        handed = handover.at(tick.t_ns)
        sent = set()
        for _, robot, topic, data in msgs:
            msg = handed(robot, topic)
            if topic not in _TYPES:
                assert msg is None, (k, robot, topic)
                continue
            decoded = codec.decode(data, _TYPES[topic])
            _same(msg, decoded, f"{k} {robot} {topic}")
            sent.add((robot, topic))
            counts[topic] += 1
        for robot in names:                      # not due or not read: nothing handed
            for topic in set(_TYPES) - {t for r, t in sent if r == robot}:
                assert handed(robot, topic) is None, (k, robot, topic)
        _drive(tick, k)
        tick.step()
        if k == 8:
            tick.reset(seed=11)
    assert min(counts.values()) >= 2 * len(names), counts
