"""The plant's outbox: who reads a key (Zenoh's matching status through the plant's router
session), bytes out with their attachment, sequence numbers that count skipped messages."""
from __future__ import annotations

import queue

import zenoh

from bus import codec
from bus.session import open_session
from plant.outbox import Outbox

from ..conftest import wait_for


def test_a_key_is_read_while_a_client_subscribes_and_its_puts_carry_seq_and_stamp(endpoint,
                                                                                 bus):
    plant = open_session("plant", endpoint)
    try:
        out = Outbox(plant, zenoh.CongestionControl.BLOCK)
        assert not out.reads("r/scan") and not out.reads("r/gps")
        got: queue.Queue = queue.Queue()
        client = bus()
        sub = client.declare_subscriber("r/scan", lambda s: got.put(
            (s.payload.to_bytes(), codec.parse_attachment(s.attachment.to_bytes()))))
        wait_for(lambda: out.reads("r/scan"), 5.0, what="the subscriber to be seen")
        assert not out.reads("r/gps")                      # another key: nobody
        out.put("r/scan", b"one", 20_000_000, 0)
        out.skip(2)                                        # two due messages nobody reads
        out.put("r/scan", b"two", 40_000_000, 1)           # a reset: the world's epoch
        assert got.get(timeout=5) == (b"one", codec.Attachment(1, 20_000_000, epoch=0))
        assert got.get(timeout=5) == (b"two", codec.Attachment(4, 40_000_000, epoch=1))
        assert out.published == {"r/scan": 2}
        out.undeclare()
    finally:
        plant.close()


def test_without_skip_unread_every_key_counts_as_read(endpoint):
    plant = open_session("plant", endpoint)
    try:
        out = Outbox(plant, zenoh.CongestionControl.BLOCK, skip_unread=False)
        assert out.reads("r/scan")
        out.undeclare()
    finally:
        plant.close()


def test_what_is_read_is_asked_again_after_a_change_and_when_a_subscriber_comes(endpoint, bus):
    plant = open_session("plant", endpoint)
    try:
        out = Outbox(plant, zenoh.CongestionControl.BLOCK)
        assert not out.reads("r/gps") and not out.reads("r/odom")
        client = bus()
        sub = client.declare_subscriber("r/gps", lambda s: None)
        # a subscriber that is no lockstep member: its matching listener says so, soon
        wait_for(lambda: out.reads("r/gps"), 5.0, what="the listener to forget the answer")
        # a node joining: declared, then the plant is told (as on its liveliness token)
        client.declare_subscriber("r/odom", lambda s: None)
        wait_for(lambda: bool(plant.declare_publisher("r/odom").matching_status.matching), 5.0,
                 what="the tables to have it")
        out.changed()
        assert out.reads("r/odom")
        # a reader that goes (a blip, a member lost): its keys are still built, so a
        # re-publish after it comes back has every tick it missed
        sub.undeclare()
        probe = plant.declare_publisher("r/gps")
        wait_for(lambda: not probe.matching_status.matching, 5.0, what="the reader to be gone")
        out.changed()
        assert out.reads("r/gps") and not out.reads("r/scan")
        out.undeclare()
    finally:
        plant.close()


def test_the_plant_s_wanted_keeps_each_answer_until_the_subscribers_change(endpoint, bus):
    """Plant._wanted answers a robot's topics from a dict kept while the outbox's readers
    stay the same, asks the bus again once they change (a subscriber came), and counts a
    composed member's keys as read."""
    from types import SimpleNamespace
    from plant.process import Plant
    plant = open_session("plant", endpoint)
    try:
        out = Outbox(plant, zenoh.CongestionControl.BLOCK)
        asked: list[str] = []

        def reads(key):
            asked.append(key)
            return Outbox.reads(out, key)
        host = SimpleNamespace(outbox=SimpleNamespace(reads=reads, readers=out.readers),
                               composed=SimpleNamespace(reads=lambda key: key == "r/odom"),
                               _key=lambda robot, topic: f"{robot}/{topic}",
                               _wanted_by=None, _wanted_of=None)
        wanted = Plant._wanted(host, "r")
        assert (wanted("gps"), wanted("odom"), wanted("gps")) == (False, True, False)
        assert Plant._wanted(host, "r")("gps") is False and asked.count("r/gps") == 1
        client = bus()
        client.declare_subscriber("r/gps", lambda s: None)
        wait_for(lambda: Plant._wanted(host, "r")("gps"), 5.0, what="the answer asked again")
        assert asked.count("r/gps") >= 2
        out.undeclare()
    finally:
        plant.close()


def test_a_plant_hosting_members_subscribes_to_their_inputs_but_none_of_its_own_sensors():
    """A composed member's sensor inputs reach it from the plant's tick: a subscription of
    the plant's own on them would count on the bus as a reader (Zenoh's matching status sees
    the plant's session), and every scan or image a composed member reads would be put for
    nobody. Another node's output a composed member reads is still subscribed to."""
    from types import SimpleNamespace
    from bus.composed import Composed
    from bus.keys import Keys
    from bus.node import MemberSpec
    from plant.process import Plant

    class Reads:
        inputs = ["scan", "joint_states", "follower/debug"]

        def step(self, obs):
            return None
    keys = Keys("ns")
    composed = Composed([MemberSpec(Reads(), ["r1", "r2"], "reader")], keys, session=None)
    subs: list[tuple[str, str]] = []
    none = lambda *a: None        # noqa: E731
    host = SimpleNamespace(
        keys=keys, composed=composed, _robot_of_key={},
        inbox=SimpleNamespace(subscribe=lambda key, tag, remote_only=False: subs.append(
            (key, tag)), watch_liveliness=none, serve=none),
        strategy=SimpleNamespace(lockstep=True), sim=SimpleNamespace(robots={"r1": 0, "r2": 0}))
    Plant._listen(host)
    assert {k for k, tag in subs if tag == "input"} == {"ns/r1/follower/debug",
                                                        "ns/r2/follower/debug"}
    assert not [k for k, _ in subs if k.endswith(("/scan", "/joint_states"))], subs


def test_a_relayed_member_output_goes_on_the_bus_only_for_another_session(endpoint, bus):
    """A composed member's message is relayed only if a subscriber outside the plant's
    session reads it: the plant's own subscription to members' outputs (there for process
    members' commands) is no reader of it, so a command nobody else reads is not put at all;
    a recorder subscribing then gets every one with the member's attachment, and it is kept
    to re-publish either way."""
    plant = open_session("plant", endpoint)
    try:
        own: queue.Queue = queue.Queue()
        plant.declare_subscriber("r/cmd_vel", lambda s: own.put(s.payload.to_bytes()),
                                 allowed_origin=zenoh.Locality.REMOTE)
        out = Outbox(plant, zenoh.CongestionControl.BLOCK, keep=True)
        att = codec.attachment(7, 20_000_000, node="m")
        out.relay("r/cmd_vel", b"one", 20_000_000, att)
        assert not out.reads("r/cmd_vel", remote=True)   # the plant's own: not a reader
        got: queue.Queue = queue.Queue()
        client = bus()
        client.declare_subscriber("r/cmd_vel", lambda s: got.put(
            (s.payload.to_bytes(), s.attachment.to_bytes())))
        wait_for(lambda: out.reads("r/cmd_vel", remote=True), 5.0,
                 what="the recorder to be seen")
        out.relay("r/cmd_vel", b"two", 40_000_000, att)
        assert got.get(timeout=5) == (b"two", att)
        assert got.empty() and own.empty()
        assert [m for t in sorted(out.recent) for m in out.recent[t]] == [
            ("r/cmd_vel", b"one", att), ("r/cmd_vel", b"two", att)]
        out.undeclare()
    finally:
        plant.close()
