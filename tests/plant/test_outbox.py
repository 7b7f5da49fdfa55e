"""The plant's outbox: who reads a key (Zenoh's matching status through the plant's router
session), bytes out with their attachment, sequence numbers that count skipped messages."""
from __future__ import annotations

import queue

import zenoh

from bus import codec
from bus.session import open_session
from bus.keys import Keys
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
    """Plant._wanted_all answers a robot's topics from a dict kept while the outbox's readers
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
                               tick=SimpleNamespace(sensors={"r": None}), _wanted=(None, None))
        wanted = Plant._wanted_all(host)["r"]
        assert (wanted("gps"), wanted("odom"), wanted("gps")) == (False, True, False)
        assert Plant._wanted_all(host)["r"]("gps") is False and asked.count("r/gps") == 1
        client = bus()
        client.declare_subscriber("r/gps", lambda s: None)
        wait_for(lambda: Plant._wanted_all(host)["r"]("gps"), 5.0,
                 what="the answer asked again")
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


class _Pub:
    """A publisher that keeps what was put (the matching status: whether its key is read)."""

    def __init__(self, key: str, read: set[str], puts: list) -> None:
        self.key, self.read, self.puts = key, read, puts

    @property
    def matching_status(self):
        from types import SimpleNamespace
        return SimpleNamespace(matching=self.key in self.read)

    def put(self, data: bytes, attachment: bytes) -> None:
        self.puts.append((self.key, data, attachment))


class _KeptOutbox(Outbox):
    """The outbox's own numbering, its puts kept instead of sent; ``read``: the keys read."""

    def __init__(self, read: set[str]) -> None:
        super().__init__(None, zenoh.CongestionControl.BLOCK)
        self.read, self.puts = read, []

    def publisher(self, key: str, remote: bool = False):
        return _Pub(key, self.read, self.puts)


def _published(tmp_path, read: set[str], ticks: int = 12, composed=None,
               comes: tuple | None = None, members: frozenset = frozenset(),
               spec=None) -> list:
    """Every message the plant's publish_sensors puts over ``ticks`` ticks of a 4-robot
    kinematic swarm (or the world ``spec``) whose readers are ``read`` (keys), lidars due
    every few ticks.
    ``composed``: members hosted in the plant (given the outbox as ``outbox``);
    ``members``: the lockstep members present; ``comes``: (tick, keys, mid) keys a subscriber
    starts to read at that tick, before the tick's sensing or (``mid``) after it, before
    the puts (the matching listener's reset comes from Zenoh's thread at any time)."""
    from types import SimpleNamespace
    from bus.controller import Twist
    from bus.keys import Keys
    from plant.process import Plant
    from plant.swarm_world import write_swarm_world
    from plant.tick import Tick
    from plant.world import load_world
    if spec is None:
        spec = load_world(write_swarm_world(str(tmp_path / "w.toml"), 4, seed=1,
                                            mode="kinematic"))
    tick, out = Tick(spec), _KeptOutbox(read)
    host = SimpleNamespace(outbox=out, composed=composed, tick=tick, sim=tick.sim, epoch=0,
                           keys=Keys(""), _key=lambda robot, topic: f"{robot}/{topic}",
                           _wanted=(None, None), _handover=None, _emit_many=None,
                           strategy=SimpleNamespace(lockstep=True),
                           ledger=SimpleNamespace(members=set(members)))
    host._wanted_all = lambda: Plant._wanted_all(host)
    host._sensors_out = lambda: Plant._sensors_out(host)
    if composed is not None:
        composed.outbox = out
    sense = tick.messages_read

    def comes_now(*args):
        read.update(comes[1])
        out.changed()
        return args[0] if args else None
    for k in range(ticks):
        if comes is not None and k == comes[0]:
            tick.messages_read = (lambda w: comes_now(sense(w))) if comes[2] else sense
            if not comes[2]:
                comes_now()
        else:
            tick.messages_read = sense
        Plant.publish_sensors(host)
        for i, name in enumerate(tick.sensors):
            tick.drive(name, Twist(0.2, 0.3 * (i - 1.5)))
        tick.step()
    return out.puts


def test_a_message_s_sequence_number_is_the_same_whoever_listens(tmp_path):
    """docs/PROTOCOL.md: the plant's sequence numbers count every due message, put or not,
    so a message's attachment does not depend on who reads which topics: the clock's and a
    robot's GPS's are the same with nobody else reading, with the last robot's topics read,
    and with every topic read."""
    keys = Keys("")
    few = {keys.clock, "r0/gps"}
    tail = few | {f"r3/{t}" for t in ("joint_states", "gps", "ground_truth", "scan")}
    every = tail | {f"r{i}/{t}" for i in range(4)
                    for t in ("joint_states", "gps", "ground_truth", "scan")} | {keys.poses}
    runs = [_published(tmp_path, r) for r in (few, tail, every)]
    common = [[(k, d, a) for k, d, a in run if k in few] for run in runs]
    assert len(common[0]) == 2 * 12 and common[0] == common[1] == common[2]
    assert {k for k, _, _ in runs[2]} == every        # (the lidars came due)


class _Members:
    """Members composed into the plant as :class:`plant.process.Plant` asks them
    (:class:`bus.composed.Composed`'s methods it calls): one lockstep member ``NODE``,
    reading the keys :meth:`reads` says, each message by message (none takes its scans as
    one array). ``got``: the messages delivered to it, with what the plant handed."""

    NODE = ""
    takes_scans = False

    def __init__(self) -> None:
        self.got: list[tuple[str, bytes, object]] = []

    def reads(self, key: str) -> bool:
        raise NotImplementedError

    def delivers(self, key: str) -> bool:
        return self.reads(key)

    def hosts(self, nodes: set[str]) -> bool:
        return nodes <= {self.NODE}

    def deliver(self, key: str, data: bytes, att, msg=None) -> None:
        self.got.append((key, data, msg))

    def clock(self, *args) -> None:
        pass

    def run(self, emit) -> None:
        pass


class _ScanMembers(_Members):
    """Members that read every robot's scan and nothing else: one lockstep member,
    ``scans``. ``at_run``: how many messages the outbox had put when the members ran, each
    tick."""

    NODE = "scans"

    def __init__(self) -> None:
        super().__init__()
        self.at_run: list[int] = []

    def reads(self, key: str) -> bool:
        return key.endswith("/scan")

    def run(self, emit) -> None:
        self.at_run.append(len(self.outbox.puts))


def test_a_scan_only_composed_members_read_is_not_encoded_until_a_subscriber_comes(
        tmp_path, monkeypatch):
    """A LaserScan read only by members composed into the plant (they take the tick's values,
    plant.handover) is not encoded; once a subscriber reads it, from the next tick's
    sensing or from the very tick whose sensing went without it, its bytes are those of a run
    read all along, attachments included, and the members get the same message."""
    from bus.packed import Rows
    keys = Keys("")
    scans = {f"r{i}/scan" for i in range(4)}
    packed_rows: list[int] = []
    pack = Rows.pack

    def counted(self, t_ns, values, rows=None):
        packed_rows.append(len(self.lengths) if rows is None else len(rows))
        return pack(self, t_ns, values, rows)
    monkeypatch.setattr(Rows, "pack", counted)
    ref_members = _ScanMembers()
    ref = [p for p in _published(tmp_path, {keys.clock} | scans, composed=ref_members)
           if p[0] in scans]
    assert len(ref) >= 8 and sum(packed_rows) == len(ref)
    ref_msgs = [(k, codec.encode(m)) for k, _, m in ref_members.got]
    assert ref_msgs == [(k, d) for k, d, _ in ref]

    packed_rows.clear()
    members = _ScanMembers()
    assert not [p for p in _published(tmp_path, {keys.clock}, composed=members)
                if p[0] in scans]
    assert sum(packed_rows) == 0                     # no scan's bytes made
    assert [(k, codec.encode(m)) for k, _, m in members.got] == ref_msgs

    for mid in (False, True):
        at = ref[len(ref) // 2][2]                   # (a tick whose scans are due)
        tick = next(k for k in range(12) if codec.parse_attachment(at).t_ns
                    == k * 20_000_000)
        got = [p for p in _published(tmp_path, {keys.clock}, composed=_ScanMembers(),
                                     comes=(tick, scans, mid)) if p[0] in scans]
        assert got and got == [p for p in ref if codec.parse_attachment(p[2]).t_ns
                               >= tick * 20_000_000], mid


def test_a_plant_hosting_members_puts_sim_clock_only_for_a_reader(tmp_path):
    """Members composed into the plant are told the tick in its process: ``sim/clock`` goes
    on the bus only while someone there reads it, and the other messages' attachments do
    not depend on whether it did."""
    clock = Keys("").clock
    alone, read = (_published(tmp_path, keys, composed=_ScanMembers())
                   for keys in ({"r0/gps"}, {"r0/gps", clock}))
    assert not [p for p in alone if p[0] == clock]
    assert len([p for p in read if p[0] == clock]) == 12
    assert [p for p in alone if p[0] == "r0/gps"] == [p for p in read if p[0] == "r0/gps"]


def test_held_puts_go_out_at_the_flush_as_they_would_have_gone_at_once():
    """Puts held back (:meth:`Outbox.hold`) reach the bus at the flush, in their order, with
    the bytes and attachments they would have had put at once; the numbering and what is
    kept to re-publish do not change, a re-publish sends what was held first, and after
    the flush puts go out at once again."""
    def run(held: bool):
        out = _KeptOutbox({"r/gps", "r/odom", "r/cmd_vel"})
        out.keep = True
        if held:
            out.hold()
        out.put("r/gps", b"g", 20_000_000, 0)
        out.skip()
        out.relay("r/odom", b"o", 20_000_000, b"odom-att")
        out.relay("r/scan", b"s", 20_000_000, b"scan-att")     # nobody reads it
        out.put("r/cmd_vel", b"c", 20_000_000, 0)
        before = list(out.puts)
        out.flush()
        out.put("r/gps", b"g2", 40_000_000, 0)
        after = len(out.puts)
        if held:
            out.hold()
        out.put("r/gps", b"g3", 60_000_000, 0)
        out.republish(20_000_000, 0)
        return before, out.puts, after, out.recent, out.seq
    at_once, held = run(False), run(True)
    assert held[0] == [] and len(at_once[0]) == 3
    assert held[1:] == at_once[1:]
    assert [k for k, _, _ in at_once[1]] == ["r/gps", "r/odom", "r/cmd_vel", "r/gps", "r/gps",
                                             "r/gps", "r/odom", "r/scan", "r/cmd_vel"]


def test_what_is_kept_to_re_publish_is_every_message_of_the_last_ticks():
    """With ``keep``, the messages of the last REPUBLISH_TICKS ticks stay, each tick's in
    their order (the plant's and a member's relayed one), the oldest tick going as a new
    one comes."""
    from bus.protocol import REPUBLISH_TICKS
    tick = 20_000_000
    out = _KeptOutbox({"r/gps"})
    out.keep = True
    ticks = [k * tick for k in range(REPUBLISH_TICKS + 4)]
    for t in ticks:
        out.put("r/gps", b"g%d" % t, t, 0)
        out.relay("r/odom", b"o%d" % t, t, b"att")
        out.put("r/gps", b"h%d" % t, t, 0)
    assert list(out.recent) == ticks[-REPUBLISH_TICKS:]
    for t in ticks[-REPUBLISH_TICKS:]:
        assert [(k, d) for k, d, _ in out.recent[t]] == [
            ("r/gps", b"g%d" % t), ("r/odom", b"o%d" % t), ("r/gps", b"h%d" % t)], t


def test_a_tick_s_puts_wait_for_its_members_only_where_they_are_its_only_lockstep_ones(
        tmp_path):
    """Where every lockstep member is composed into the plant, a tick's messages go on the
    bus after its members ran (together); with a process member in lockstep beside them they
    go before, as they come. The bytes, attachments and order are the same either way."""
    read = {"r0/gps", "r1/joint_states", Keys("").clock}
    alone, beside = _ScanMembers(), _ScanMembers()
    puts = [_published(tmp_path, set(read), composed=m, members=frozenset(nodes))
            for m, nodes in ((alone, {"scans"}), (beside, {"scans", "process"}))]
    assert puts[0] == puts[1]
    stamps = [codec.parse_attachment(a).t_ns for _, _, a in puts[0]]
    ticks = range(len(alone.at_run))
    assert len(ticks) == 12
    assert alone.at_run == [sum(s < k * 20_000_000 for s in stamps) for k in ticks]
    assert beside.at_run == [sum(s <= k * 20_000_000 for s in stamps) for k in ticks]
