"""An FMU node's messages are written straight from its output values (fmus/mapping.py
``MessageKind.pack``): the same bytes rosbags gives for the message ``build`` makes, and
read as a message they are that message."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bus import codec
from bus.encoded import Encoded
from bus.member import _wire
from fmus.mapping import MESSAGES

from ..plant.test_handover import _same as same_fields

_VALUES = [0.0, -0.0, 1.0, -2.5e-7, 3.141592653589793, -math.pi + 1e-12, 123456.789, 1e300]


@pytest.mark.parametrize("name", sorted(MESSAGES))
def test_packed_bytes_are_rosbags_bytes_of_the_built_message(name):
    kind = MESSAGES[name]
    rng = np.random.default_rng(7)
    options = {o: f"robot2/{o}_x" for o in kind.options}
    fields = kind.required + kind.optional
    for i in range(40):
        values = {f: float(rng.choice(_VALUES) if i % 2 else rng.normal(0, 10 ** (i % 5)))
                  for f in fields}
        if i % 3 == 0:                               # optional fields left out
            values = {f: values[f] for f in kind.required}
        t_ns = int(rng.integers(0, 4 * 10**12)) // 20_000_000 * 20_000_000
        want = bytes(codec.TYPESTORE.serialize_cdr(kind.build(t_ns, values, options),
                                                   kind.msgtype))
        got = kind.pack(t_ns, values, options)
        assert got == want, (name, values, t_ns)
        if kind.made is not None:                    # built from the values: as decoded
            same_fields(kind.made(t_ns, values, options), codec.decode(got, kind.msgtype))


def test_an_encoded_message_reads_as_its_message_and_sends_its_bytes():
    kind = MESSAGES["odometry"]
    values = {"x": 1.25, "y": -0.5, "yaw": 2.0, "linear": 0.2, "angular": -0.1}
    options = {"frame_id": "odom", "child_frame_id": "base_link"}
    msg = kind.build(1_020_000_000, values, options)
    enc = Encoded(kind.pack(1_020_000_000, values, options), kind.msgtype)
    assert _wire(enc) is enc.data
    assert enc.__msgtype__ == "nav_msgs/msg/Odometry" and enc.child_frame_id == "base_link"
    assert codec.pose_2d(enc) == codec.pose_2d(msg)
    assert codec.encode(enc) == enc.data
    with pytest.raises(TypeError):
        Encoded(b"\0\1\0\0").header
