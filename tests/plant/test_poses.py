"""``sim/poses`` as the launcher reads it: the paths' tracks (diffbot.analysis.paths, the
swarm's analysis) from the one message a tick equal those from every robot's ground truth,
which the analyses read before, to the bit."""
from __future__ import annotations

from bus import codec
from bus.controller import Twist
from bus.keys import POSES_TYPE, Keys
from diffbot.analysis.paths import ground_truth_tracks, keys as path_keys
from plant import core
from plant.swarm_world import write_swarm_world
from plant.tick import Tick
from plant.world import load_world


class _Observed:
    """The observer's reading side: decoded messages by key, in stamp order."""

    def __init__(self) -> None:
        self.kept: dict[str, list] = {}
        self.keep: dict[str, str] = {}

    def add(self, key: str, data: bytes, msgtype: str) -> None:
        self.keep[key] = msgtype
        self.kept.setdefault(key, []).append(codec.decode(data, msgtype))

    def messages(self, key: str) -> list:
        return list(self.kept.get(key, ()))


def test_tracks_from_sim_poses_are_the_ground_truth_s(tmp_path):
    keys = Keys("ns")
    tick = Tick(load_world(write_swarm_world(str(tmp_path / "w.toml"), 6, seed=4,
                                             mode="kinematic")))
    names = list(tick.sensors)
    seen, truths = _Observed(), _Observed()
    truth: dict[str, dict[int, tuple]] = {r: {} for r in names}
    for k in range(15):
        for robot, topic, data in tick.messages(encoded=True):
            if topic == "ground_truth":
                truths.add(keys.topic(robot, topic), data, "nav_msgs/msg/Odometry")
                m = codec.decode(data, "nav_msgs/msg/Odometry")
                p = m.pose.pose
                truth[robot][codec.msg_stamp_ns(m)] = (
                    p.position.x, p.position.y, codec.quaternion_to_yaw(p.orientation))
        seen.add(keys.poses, core.poses(tick.model, tick.data, 0, tick.t_ns), POSES_TYPE)
        for i, r in enumerate(names):
            tick.drive(r, Twist(0.3, 0.5 * (i - 2)))
        tick.step()
    got = ground_truth_tracks(seen, keys, names)
    assert list(got) == names and got == truth
    assert len({rows[14 * 20_000_000] for rows in got.values()}) == len(names)
    assert got[names[0]][0] != got[names[0]][14 * 20_000_000]      # (they moved)
    # a run whose analysis keeps every robot's ground_truth reads the paths from those
    # (sim/poses would be one more message a tick), with the same tracks
    assert path_keys(keys, tick.spec, truths.keep) == {}
    assert ground_truth_tracks(truths, keys, names) == truth
    fewer = dict(list(truths.keep.items())[1:])                  # (one robot's missing)
    assert path_keys(keys, tick.spec, fewer) == {keys.poses: POSES_TYPE}
    assert path_keys(keys, tick.spec) == {keys.poses: POSES_TYPE}


def test_sim_poses_bytes_are_the_typestores_of_each_robots_stamp_and_pose():
    """The message written from the arrays is the CDR of its own decoded message, the
    tick's stamp on every transform and each robot's true pose, its ground truth's."""
    tick = Tick(load_world("living_room_follow"), ("camera", "lidar"))
    for r in tick.sensors:
        tick.drive(r, Twist(0.3, 0.8))
    for _ in range(3):
        tick.step()
    truth = {r: codec.decode(m, "nav_msgs/msg/Odometry").pose.pose
             for r, topic, m in tick.messages(encoded=True) if topic == "ground_truth"}
    for t_ns in (3_250_000_123, 2 * 10**9, 7):
        data = core.poses(tick.model, tick.data, 0, t_ns)
        msg = codec.decode(data, POSES_TYPE)
        assert bytes(codec.TYPESTORE.serialize_cdr(msg, POSES_TYPE)) == data
        assert [codec.msg_stamp_ns(tf) for tf in msg.transforms] == [t_ns] * len(truth)
        for tf, (robot, pose) in zip(msg.transforms, truth.items()):
            assert tf.child_frame_id.startswith(robot)
            t, q = tf.transform.translation, tf.transform.rotation
            p, o = pose.position, pose.orientation
            assert (t.x, t.y, t.z, q.x, q.y, q.z, q.w) == (p.x, p.y, p.z, o.x, o.y, o.z, o.w)


def test_an_observer_keeping_sim_poses_takes_the_run_s_clock_from_their_stamps(endpoint, bus):
    """The launcher's observer answers the plant's ``sim/seen`` get with the latest tick it
    has: kept ``sim/poses`` (put every tick before the clock) stand for the clock, so it
    does not subscribe to ``sim/clock``; one without them does, and answers from it."""
    from bus.protocol import decode_seen
    from bus.session import open_session
    from diffbot.launch.observer import OBSERVER, Observer
    from ..conftest import wait_for
    keys = Keys("")
    plant = open_session("plant", endpoint)
    tick = 20_000_000
    try:
        clock, poses = (plant.declare_publisher(k) for k in (keys.clock, keys.poses))
        for keep, pub in (({keys.poses: POSES_TYPE}, poses), ({}, clock)):
            obs = Observer(bus(), keys, keep)
            try:
                # (its token, declared last, says every subscription is in the tables)
                wait_for(lambda: list(plant.liveliness().get(keys.alive(OBSERVER))), 5.0,
                         what="the observer's token")
                assert pub.matching_status.matching
                assert clock.matching_status.matching == (pub is clock)
                for k in range(1, 4):
                    pub.put(b"\0" * 8, attachment=codec.attachment(k, k * tick, epoch=0))

                def seen():
                    replies = list(plant.get(keys.seen(OBSERVER), timeout=5.0))
                    return [decode_seen(r.ok.payload.to_bytes()) for r in replies if r.ok]
                wait_for(lambda: seen() == [3 * tick], 5.0, what="the latest tick seen")
            finally:
                obs.close()
    finally:
        plant.close()
