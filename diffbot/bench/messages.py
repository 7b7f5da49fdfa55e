"""Suite ``codec``: CDR encode / decode of every bus message type."""
from __future__ import annotations

import math

from .harness import Case, Context, suite

def codec_messages() -> dict:
    """One message of each type the bus carries: type name -> message."""
    import numpy as np
    from bus import codec
    t = 12_345_678_901
    T = codec.TYPESTORE.types
    rng = np.random.default_rng(0)
    image = T["sensor_msgs/msg/Image"](
        header=codec.header(t, "camera"), height=120, width=160, encoding="rgb8",
        is_bigendian=0, step=160 * 3, data=rng.integers(0, 256, 160 * 120 * 3, dtype=np.uint8))
    scan = T["sensor_msgs/msg/LaserScan"](
        header=codec.header(t, "lidar"), angle_min=-math.pi / 2, angle_max=math.pi / 2,
        angle_increment=math.pi / 179, time_increment=0.0, scan_time=0.02, range_min=0.05,
        range_max=80.0, ranges=rng.uniform(0.5, 8.0, 180).astype(np.float32),
        intensities=np.zeros(0, dtype=np.float32))
    return {
        "JointState": codec.joint_state(t, ["left_wheel_joint", "right_wheel_joint"],
                                        [1.5, -2.5], [1.0, -1.0]),
        "TwistStamped": codec.twist_stamped(t, 0.3, 0.5),
        "Odometry": codec.odometry(t, 1.0, 2.0, 0.3, 0.2, 0.1),
        "PointStamped": codec.point_stamped(t, 1.0, 2.0, 0.0),
        "Clock": codec.clock(t),
        "Image 160x120 rgb8": image,
        "LaserScan 180 rays": scan,
    }


@suite("codec", "CDR encode / decode of every bus message type (bus.codec)")
def codec_suite(ctx: Context):
    from bus import codec
    fast = getattr(codec, "_FAST", {})  # types with hand-written encoders (same bytes as rosbags)
    ts = codec.TYPESTORE
    cases = []
    for label, msg in codec_messages().items():
        data = codec.encode(msg)
        mt = msg.__msgtype__
        size = f"{len(data)} B"
        cases.append(Case(f"encode {label}", lambda m=msg: codec.encode(m),
                          notes=f"{size}, hand-written CDR" if mt in fast else size))
        if mt in fast:
            cases.append(Case(f"encode {label} (rosbags)",
                              lambda m=msg, mt=mt: bytes(ts.serialize_cdr(m, mt)),
                              notes=f"{size}, for comparison: what codec.encode replaced"))
        cases.append(Case(f"decode {label}", lambda d=data, mt=mt: codec.decode(d, mt), notes=size))
    return cases
