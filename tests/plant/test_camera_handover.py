"""The camera messages a composed member takes from the tick's values
(plant.camera_handover) are, field for field, the objects decoding the plant's bytes gives:
the noisy picture's bytes, CameraInfo's matrices, the types, arrays read-only."""
from __future__ import annotations

from bus import codec
from bus.keys import TOPICS
from plant.camera_handover import CameraHandover
from plant.noise import NoiseConfig
from plant.tick import Tick

from .test_core import _drive, _wanted, _world
from .test_handover import _same

CAMERA = ("camera/image_raw", "camera/camera_info")
HANDED = ("scan", "joint_states", "gps", "ground_truth")   # (plant.handover's topics)


def test_handed_camera_messages_are_the_decoded_bytes(tmp_path):
    """The follow's world with a noisy camera, readers that come and go, a reset: every
    camera message due and read is handed, equal to its bytes decoded; the scans, joint
    states, GPS and ground truth as plant.handover hands them; nothing for a camera not
    due this tick nor for a topic handed by neither."""
    spec = _world("follow", tmp_path)
    spec.robot("follower").sensors.camera_noise = NoiseConfig(std=10.0)
    tick = Tick(spec)
    names = list(tick.sensors)
    handover, handed_count = None, {t: 0 for t in CAMERA}
    for k in range(12):
        want = _wanted(names, k)
        _, msgs = tick.messages_read(want or {n: (lambda t: True) for n in names})
        handover = CameraHandover.of(handover, tick.model, tick.data)
        handed = handover.at(tick.t_ns)
        sent = set()
        for _, robot, topic, data in msgs:
            msg = handed(robot, topic)
            if topic in CAMERA or topic in HANDED:
                _same(msg, codec.decode(data, TOPICS[topic].msgtype), f"{k} {robot} {topic}")
                sent.add((robot, topic))
                handed_count[topic] = handed_count.get(topic, 0) + 1
            else:
                assert msg is None, (k, robot, topic)
        if ("follower", "camera/image_raw") not in sent:    # (not due, or not read)
            assert handed("follower", "camera/image_raw") is None, k
        _drive(tick, k)
        tick.step()
        if k == 6:
            tick.reset(seed=11)
    assert handed_count["camera/image_raw"] >= 3 and handed_count["camera/camera_info"] >= 3
    assert handed_count["scan"] >= 2
