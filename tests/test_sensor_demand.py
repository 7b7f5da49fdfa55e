"""A topic nobody reads is not built, and that changes no value of any topic: whoever
listens, from whatever tick on, gets the bytes an always-listened run gets."""
from __future__ import annotations

import math

from bus import codec
from plant.raycast import Scene
from plant.sensors import RobotSensors, scan_all
from plant.sim import Simulation
from plant.world import load_world

NOISY = ["robots.leader.lidar.noise={std = 0.05}", "robots.follower.camera.noise={std = 10.0}",
         "robots.leader.encoders.noise={std = 0.01}", "robots.follower.gps.noise={std = 0.02}",
         "robots.follower.encoders.noise={std = 0.01}",
         "robots.follower.motion.command_noise_std_radps=0.1"]


def _run(ticks: int, wanted, encoded: bool = False, without: str = ""):
    """{(tick, robot, topic): CDR bytes} of a follow-world run, building only what
    ``wanted(tick, robot, topic)`` asks for (None: everything); ``without``: a sensor
    ("camera", "lidar") taken off every robot."""
    spec = load_world("living_room_follow", NOISY)
    for r in spec.robots:
        if without:
            setattr(r.sensors, without, None)
    sim = Simulation(spec)
    sensors = {r.name: RobotSensors(r, spec.control_tick_s, 3) for r in spec.robots}
    tick_ns = int(round(spec.control_tick_s * 1e9))
    out, built = {}, {"scan": 0, "camera/image_raw": 0}
    for k in range(ticks):
        t = sim.time_ns
        tick = t // tick_ns
        want = {n: (None if wanted is None else (lambda topic, n=n: wanted(tick, n, topic)))
                for n in sensors}
        due = [s.needs_scene(tick, want[n]) for n, s in sensors.items()]
        scene = Scene(sim.shapes()) if any(due) else None
        states = {n: sim.state(n) for n in sensors}
        scans = scan_all(sensors, states, tick, scene,
                         None if wanted is None else want) if scene is not None else {}
        for n, s in sensors.items():
            for topic, msg in s.messages(tick, t, states[n], scene, scans.get(n), want[n],
                                         encoded=encoded):
                out[(tick, n, topic)] = msg if encoded else codec.encode(msg)
                built[topic] = built.get(topic, 0) + 1
            s.prefetch(tick + 1)
        for i, n in enumerate(sim.robots):
            sim.command_twist(n, 0.2, 0.8 * math.sin(0.1 * k + i))
        sim.step_tick()
    return out, built


def test_unread_topics_are_not_built_and_change_no_value_of_the_others():
    full, _ = _run(40, None)

    def wanted(tick, robot, topic):
        if topic in ("gps", "camera/camera_info"):
            return False                                  # nobody, ever
        if topic in ("scan", "camera/image_raw"):
            return tick >= 17                             # a reader that joins late
        return tick % 3 != 0                              # one that comes and goes
    part, built = _run(40, wanted)
    assert part and set(part) < set(full)
    assert all(full[k] == v for k, v in part.items())
    assert not any(topic in ("gps", "camera/camera_info") for _, _, topic in part)
    assert min(tick for tick, _, topic in part if topic == "scan") >= 17
    assert built["scan"] == sum(1 for tick, _, topic in full if topic == "scan" and tick >= 17)
    assert built["camera/image_raw"] == sum(1 for tick, _, topic in full
                                            if topic == "camera/image_raw" and tick >= 17)


def test_a_sensor_taken_off_changes_no_value_of_the_others():
    """Noise is drawn per (seed, robot, stream, tick): without the follower's camera, every
    other topic (its encoders, GPS, the motion its noisy commands make) has the same
    bytes."""
    full, _ = _run(30, None)
    part, _ = _run(30, None, without="camera")
    assert not any(topic.startswith("camera/") for _, _, topic in part)
    assert set(part) == {k for k in full if not k[2].startswith("camera/")}
    assert all(full[k] == v for k, v in part.items())


def test_encoded_messages_are_the_bytes_of_the_messages():
    """messages(encoded=True), packed straight from the values, gives codec.encode of
    every message, tick after tick (noise, lidar, camera, ground truth included)."""
    want, _ = _run(25, None)
    got, _ = _run(25, None, encoded=True)
    assert got == want
    assert {topic for _, _, topic in got} >= {"joint_states", "gps", "ground_truth", "scan",
                                               "camera/image_raw", "camera/camera_info"}


def test_tick_messages_gives_every_due_topic_and_none_for_the_unread():
    """plant.tick.tick_messages, what the plant and the in-process envs share: with
    ``wanted`` every due topic still comes, in order, the unread ones as None, and the
    read ones are the bytes of the messages an everything-built tick gives."""
    from plant.tick import build_world, tick_messages
    spec = load_world("living_room_follow", NOISY)
    tick_ns = int(round(spec.control_tick_s * 1e9))

    def ticks(wanted, encoded):
        sim, sensors = build_world(spec, 3)
        out = []
        for k in range(12):
            out.append(list(tick_messages(sim.time_ns, tick_ns, sensors, sim.state, sim.shapes,
                                          wanted and {n: wanted for n in sensors}, encoded)))
            for n in sim.robots:
                sim.command_twist(n, 0.2, 0.5)
            sim.step_tick()
        return out
    full = ticks(None, False)
    part = ticks(lambda topic: topic in ("scan", "camera/camera_info", "ground_truth"), True)
    assert [[(r, t) for r, t, _ in tick] for tick in part] == \
        [[(r, t) for r, t, _ in tick] for tick in full]
    read = [(r, t, codec.encode(m)) for tick in full for r, t, m in tick
            if t in ("scan", "camera/camera_info", "ground_truth")]
    assert [x for tick in part for x in tick if x[2] is not None] == read
    assert {t for tick in part for _, t, m in tick if m is None} == {
        "joint_states", "gps", "camera/image_raw"}


def test_a_reader_that_comes_during_a_tick_changes_nothing_of_that_tick():
    """The plant's ``wanted`` is Zenoh's matching status, which a reader coming up (a ROS 2
    bridge, ``diffbot echo``) changes at any moment, on Zenoh's thread. Asked when the
    scene was decided, "is the scan read?" said no; asked again when the scan was built, yes:
    the plant cast rays into no scene and died (TypeError). Now each answer holds for the
    whole tick, and the reader gets the topic from the next tick on, the same bytes."""
    from plant.tick import build_world, tick_messages
    spec = load_world("living_room_follow", NOISY)
    tick_ns = int(round(spec.control_tick_s * 1e9))
    asked: dict[str, int] = {}

    def arriving(topic: str) -> bool:
        """A reader of the scan and the image that comes just after the first question."""
        if topic in ("scan", "camera/image_raw"):
            asked[topic] = asked.get(topic, 0) + 1
            return asked[topic] > 1
        return True

    def ticks(wanted) -> list:
        sim, sensors = build_world(spec, 3)
        out = []
        for _ in range(6):
            out.append(list(tick_messages(sim.time_ns, tick_ns, sensors, sim.state, sim.shapes,
                                          wanted and {n: wanted for n in sensors}, True)))
            sim.step_tick()
        return out
    full, part = ticks(None), ticks(arriving)
    first = {t for _, t, m in part[0] if m is None}
    assert first == {"scan", "camera/image_raw"}, first      # not built at the tick it came
    assert [x for tick in part[1:] for x in tick] == \
        [x for tick in full[1:] for x in tick]
